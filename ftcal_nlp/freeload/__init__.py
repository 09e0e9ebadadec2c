"""The free-load estimator (``DATA_FORMAT.md`` section 5, issue 22): one transducer's offsets, its load's
parameters and its mounting rotation from hanging recordings with gravity per sample.

API (the result object other modules build on):

* ``fit_free_loads(dataset, settings) -> FreeLoadResults``: every transducer whose load is not a hexapod leg
  (``Dataset.free_load_legs``), independently; ``fit_free_load(dataset, leg, settings) -> FreeLoadResult``.
* :class:`FreeLoadResult` (``result.py``): results protocol (``params``, ``bse``, ``cov_params()``,
  ``conf_int()``, ``summary()``), ``identifiability()`` (what the data leave undetermined, which
  combinations they determine), ``load_report()`` (the ``calibration.json`` keys of the load),
  ``predict(gravity_B, q)`` / ``predict_recording(rec, g)`` (model readings of any sample), ``offset``,
  ``theta``, ``rotation`` (``E``), ``sigma``, ``rms``, ``selection`` (kept / dropped per recording, thresholds),
  ``used`` (recording -> boolean mask of the samples the fit used).

Modules: ``quasistatic`` (sample selection), ``problem`` (data, exact compression), ``nlp`` (CasADi/IPOPT),
``estimate`` (the fit), ``result`` (results protocol).

Model (``loads.base``): ``f = M E^T b + f_o``, ``t = (K theta) x (E^T b) + t_o``, ``b = R_nom^T g_B`` the
nominal gravity in ft for each sample (``R_nom`` from ``robot.toml`` or from the URDF for the sample's joint
angles), ``E`` the mounting rotation (``R_true = R_nom E``, exact SO(3)), ``theta`` the load's parameters
(mass and first moment per rigid group: linear in the readings). Steps:

1. quasi-static samples of each recording in which the load hangs free (``quasistatic.py``; counts logged);
2. the exact compression of the samples into channel moments (``problem.py``: no loop over samples);
3. a start by linear least squares with ``E = I``; then the NLP with exact SO(3) (``nlp.py``), weighted by
   the readings' noise (first differences), re-weighted once by the residual sd per channel; what the data
   leave undetermined stays at the load's prior (the URDF's values; ``E = I``), nothing else does;
4. Gauss-Newton information ``J^T Q_W J`` in local coordinates (``E = E* (I + [delta]x)``), the weights
   shrunk where the residuals are serially correlated (AR(1) variance inflation, at most the samples per
   hold: ``problem.serial_inflation``; white noise leaves them), its scaled
   eigen-analysis (``solver.identifiability``): covariance on the determined subspace, ``bse`` inf for
   parameters in undetermined directions, those directions named, and the determined combinations of the
   parameters they touch given with se (reduced row echelon form: for ``shared/sample_urdf`` the total mass,
   the sum of the three bodies' y first moments, ...).

World tilt (``FreeLoadSettings.gravity_tilt``, off by default): a tilt ``R_t = R_y(ty) R_x(tx)`` of the orientation
stream's world (a turn about vertical is unobservable) gives gravity in ft ``E^T R_nom^T R_WB^T u``,
``u = R_t (0, 0, -1)``: it sits on the world side of the varying ``R_WB``, so it is NOT a mounting rotation, and is
separable from ``E`` whenever the orientations are not all about one axis (else ``identifiability()`` names
``tilt.rx``/``tilt.ry``). With ``b_n = A_n u`` (``A_n = g R_nom^T R_WB^T``) every feature is linear in ``u``: the
lifted vector ``[w_o; u (x) z_r]`` (``problem.compress_tilted``) keeps the compression exact for any tilt. It is
estimated (parameters ``{leg}.tilt.rx, .ry`` in rad, between the load's and the mount's) when every recording gives
the orientation per sample (quaternions); a 1 deg / 0.5 deg tilt left out biases the fit beyond 4 se
(``tests/test_freeload_tilt.py``). Off by default until the modules that take the parameter vector (diagnosis
faces, uncertainty, correct) accept the two columns. Recordings that give gravity by ``gravity_body`` only (the
hexapod model has a tilt per such recording) are taken as exact; a note says so.
"""

from __future__ import annotations

from .estimate import fit_free_load, fit_free_loads, free_load_calibration, free_load_data
from .problem import FreeLoadData
from .result import FreeLoadResult, FreeLoadResults

__all__ = ["fit_free_loads", "fit_free_load", "free_load_data", "free_load_calibration", "FreeLoadResult", "FreeLoadResults",
           "FreeLoadData"]
