"""Cramer-Rao bounds of the calibration: one entry for every load (bench and plan import from here).

The generic bound (:mod:`.bound`): ``F = sum J^T Sigma^-1 J`` at the truth, ``Cov(theta_hat) >= F^-1`` on the
directions ``F`` determines (those below ``solver.REL_EIG_TOL`` of the largest scaled eigenvalue dropped and named).
What differs by load is its Fisher information, one module each:

* :mod:`.hexapod`   -- hexapod legs: the hanging model (a CoM curve over the shaft angle, report eqs. 4-7) and the
  standing balance (exact balance (E), errors in variables), the total CoM, one simulated dataset's bounds;
* :mod:`.free_load` -- free loads (``DATA_FORMAT.md`` section 5): a rigid payload and a URDF subtree grouped by the
  joints that move it, with offsets, mounting rotation and world tilt, and a simulated free load's bound.
"""

from __future__ import annotations

from .bound import (Bound, LoadBound, crb, describe_dropped, dropped_directions, fisher_information, marginal,
                    named_bound)
from .free_load import (OFFSET_NAMES, ROT_NAMES, TILT_NAMES, WRENCH, JointGroup, free_load_bound, group_poses,
                        group_truth, joint_groups, payload_bound, payload_jacobian, payload_names, reading_covariance,
                        tilt_directions, urdf_bound, urdf_first_moment, urdf_gravity_in_ft, urdf_jacobian, urdf_names)
from .hexapod import (MEDIAN_EFFICIENCY, DatasetBounds, HangingBound, HangingLayout, StandingBound, ad, dataset_bounds,
                      hanging_bound, hanging_derivatives, hanging_leg_fisher, interp_cross, interp_gram,
                      interpolation_bias, ls_covariance, pose_noise_cov, pose_orientation_sd, pose_sample_counts,
                      sensor_sigma, sinusoid_map, standing_bound, standing_bound_at, standing_jacobians, tangent_plane,
                      total_com_cov, total_com_jacobian, true_gravity_directions)

__all__ = [
    "Bound", "LoadBound", "crb", "describe_dropped", "dropped_directions", "fisher_information", "marginal", "named_bound",
    "OFFSET_NAMES", "ROT_NAMES", "TILT_NAMES", "WRENCH", "JointGroup", "free_load_bound", "group_poses", "group_truth",
    "joint_groups", "payload_bound", "payload_jacobian", "payload_names", "reading_covariance", "tilt_directions",
    "urdf_bound", "urdf_first_moment", "urdf_gravity_in_ft", "urdf_jacobian", "urdf_names",
    "MEDIAN_EFFICIENCY", "DatasetBounds", "HangingBound", "HangingLayout", "StandingBound", "ad", "dataset_bounds",
    "hanging_bound", "hanging_derivatives", "hanging_leg_fisher", "interp_cross", "interp_gram", "interpolation_bias",
    "ls_covariance", "pose_noise_cov", "pose_orientation_sd", "pose_sample_counts", "sensor_sigma", "sinusoid_map",
    "standing_bound", "standing_bound_at", "standing_jacobians", "tangent_plane", "total_com_cov", "total_com_jacobian",
    "true_gravity_directions",
]
