"""Contact wrench of a transducer carrying a calibrated free load (``DATA_FORMAT.md`` section 5, issue 22): a
rigid payload on a wrist, or the URDF links below a sensor.

``python -m ftcal_nlp.correct calibration.json recording.csv -o out.csv`` dispatches here when the calibration's
transducers carry free loads (``load_kind`` ``"rigid_payload"`` or ``"urdf_subtree"`` in ``calibration.json``).

Per sample, in the estimated (true) ft frame about its origin (``R_B,ft`` = ``rotation_to_body``, the nominal
rotation times the estimated mounting rotation):

    g_ft = R_B,ft^T g_B,        w_load = [m g_ft ; c x (m g_ft)],        w_contact = w_m - w_o - w_load

``g_B`` gravity in B (m/s^2): ``R_WB^T [0, 0, -g]`` from ``qw..qz`` (``g R_WB^T u(tilt)`` when the calibration
estimated a world tilt of the orientation stream, ``gravity_tilt_rad``: ``u = R_y(ty) R_x(tx) (0, 0, -1)``,
``freeload``), or ``g`` times the unit direction ``gx..gz`` (an accelerometer's gravity: no world to tilt). The contact wrench is what the environment adds to the tool's weight: zero (within noise) while the
tool touches nothing.

Standard error per sample and component (delta method, first order):

    Var(w_contact) = J C J^T + diag(sigma^2),

``J`` the derivative of ``w_o + w_load`` with respect to the parameters ``(w_o, m, c or h = m c[, tilt], delta)``
(``delta`` a rotation of ft in its own axes: ``d g_ft = [g_ft]x delta``, so ``d w_load / d delta =
[m [g_ft]x ; [h]x [g_ft]x]``; the tilt ``d g_ft / d tilt = R_B,ft^T g R_WB^T du/dtilt``, ``d w_load / d tilt =
[m dg_ft ; h x dg_ft]``, zero for ``gx..gz`` rows), ``C`` their covariance and ``sigma`` the readings' noise sd (``noise_sd`` of
the calibration). In process (:func:`payload_from_fit`) ``C`` is the fit's full covariance; from
``calibration.json`` it is the full covariance of the run's covariance file (``meta.covariance_file``,
``calibration_cov.npz`` beside it: parameters ``{X}.offset.*``, ``{X}.mass_kg``, ``{X}.h_*``[, ``{X}.tilt.r*``],
``{X}.mount.r*``)
when that file is there, else the diagonal of the stored standard errors (correlations between offsets and
mass then left out: said in the log). A component that depends on an undetermined parameter (se inf) gets
se inf. Rows without an orientation or with NaN readings are dropped and counted in the log.

URDF loads (``load_kind = "urdf_subtree"``; the leg entry names the ``urdf`` file and the sensor ``link``): the
same with the load's first moment about the ft origin moving with the joints (``loads.urdf_subtree``), per sample

    R_B,ft = R_nom(q) E,   g_ft = R_B,ft^T g_B,   s(q) = K(q) theta,   w_load = [(mu . theta) g_ft ; s(q) x g_ft]

(``R_nom(q)`` the URDF's sensor pose for the joints above it, ``K(q)`` the groups' poses below it, both from the
vectorised kinematics of ``kinematics.py``; ``q`` from the ``q_{joint}`` columns, a joint without a column held
at 0 and named in a warning). Its derivative with respect to ``(w_o, theta, delta)``:
``[I | g_ft mu^T ; 0 | -[g_ft]x K(q) | ...]``, ``d w_load / d delta = [(mu . theta) [g_ft]x ; [s]x [g_ft]x]``.
The parameters ``theta = [M_G, H_G]`` per group come from ``urdf_groups`` (mass, first moment in the group frame).
With the covariance file, an output is undetermined (se inf) only where its derivative has a component along an
undetermined direction (``null``): a joint that never moved at calibration leaves the split of the links it
carries undetermined, but not the wrench at the angles it held.

A payload on an arm whose URDF leaves the tool out (``load_kind = "rigid_payload"`` with ``urdf`` and ``link``):
the rigid payload's wrench with its orientation moving with the joints, ``R_B,ft = R_nom(q) E`` (``rotation_to_body``
per sample; ``E`` = ``mount_rotation``), the lever constant (``K = [0 | I]``: :class:`~ftcal_nlp.loads.RigidPayload`
built on the URDF, served as a URDF load above).

Gravity of a recording without orientation columns (joints only: an arm on its fixed base): ``g`` times the
calibration's ``gravity_body`` (per transducer, the direction its fit used for the base: the manifest's
``gravity_body`` with the recording's estimated tilt, ``recording_tilt_rad``, applied, written by the run where every
recording it used gave gravity by ``gravity_body`` alone and they agree, ``freeload.estimate.fixed_base_gravity``),
or ``correct --gravity-body X Y Z`` (B axes, normalised; it wins over the calibration's and is said in the log).
The tilt's uncertainty (tens of microradians on the shared arm) is left out of the se. A recording with orientation
columns uses them; with neither, the error names both ways.

A ``calibration_with_effect.json`` of a free-load run (``meta.effect.kind = "free_load"``) names effects per
transducer: the readings are corrected for them first and the se carry their parameters' joint covariance
(``freeload/effects_correction.py``: what the file holds, the correction, what the se leave out); a calibration
without ``meta.effect`` is corrected as above.

Checks, before anything is corrected: the calibration as read (``calibration.read_calibration_json``, the one reader
of ``calibration.json``: finite numbers, proper rotations, one mounting rotation, a positive load mass); the
recording as a run reads its own (:func:`clean_rows`: the transducers match the calibration's, no empty table, no
column without a number, ``t`` strictly increasing, unit quaternions) and against the calibration
(:func:`check_against_calibration`: the forces' unit from the load's predicted weight, the orientation columns'
convention from its direction). A recording mostly in contact cannot test the convention: a warning, not an error.
"""

from __future__ import annotations

import argparse
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .calibration import Calibration, is_free_load, read_calibration_json
from .checks import MAX_SAMPLE_INTERVAL_S, reread_quaternion, same_pose_share, with_fault_columns
from .data import GRAVITY_COLUMNS, JOINT_PREFIX, QUAT_COLUMNS, WRENCH_COMPONENTS, read_table
from .errors import ConfigError, DataFormatError
from .geometry import quat_to_rotation, skew
from .loads.base import calibration_variance

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PayloadCalibration:
    """One transducer's payload calibration: offsets ``offset`` (6,), ``mass_kg``, first moment ``h`` (3,) kg m
    in ft, ``R_B_ft`` (3, 3) the estimated ft orientation in B, ``cov`` (13, 13) over ``(w_o, m, h, delta)`` (15: ``(w_o, m, h, tilt, delta)``),
    ``sigma`` (6,) the readings' noise sd, ``g`` m/s^2, ``full_cov`` whether ``cov`` holds the correlations,
    ``undetermined`` (13,) the parameters the data leave undetermined (None: none)."""

    leg: str
    offset: np.ndarray
    mass_kg: float
    h: np.ndarray
    R_B_ft: np.ndarray
    cov: np.ndarray
    sigma: np.ndarray
    g: float
    full_cov: bool = True
    undetermined: np.ndarray | None = None
    null: np.ndarray | None = None
    tilt: np.ndarray | None = None    # world tilt of the orientation stream (rad); None: not estimated
    effects: object = None            # the named effects (freeload/effects_correction.FreeEffects); None: none
    gravity_body: np.ndarray | None = None   # the fixed base's gravity direction at calibration (unit, B); None: not kept

    joints: tuple[str, ...] = ()

    def predict(self, g_B: np.ndarray, q: dict[str, np.ndarray], R_WB: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``w_o + w_load`` (N, 6) and its derivative (N, 6, 13 [+ 2]) (:func:`predicted_load`; ``q`` unused)."""
        g_B, dg = tilted_gravity(self, g_B, R_WB)
        return predicted_load(self, g_B, dg)


@dataclass(frozen=True)
class UrdfLoadCalibration:
    """One transducer's calibrated URDF load: ``load`` the :class:`~ftcal_nlp.loads.UrdfSubtree` (from the URDF),
    ``offset`` (6,), ``theta`` (p,) ``[M_G, H_G]`` per group, ``E`` (3, 3) the mounting rotation (true ft relative
    to the URDF's), ``cov`` (6 + p + 3)^2 over ``(w_o, theta, delta)``, ``sigma``, ``g``, ``full_cov``,
    ``undetermined``, ``null`` as :class:`PayloadCalibration`."""

    leg: str
    load: object
    offset: np.ndarray
    theta: np.ndarray
    E: np.ndarray
    cov: np.ndarray
    sigma: np.ndarray
    g: float
    full_cov: bool = True
    undetermined: np.ndarray | None = None
    null: np.ndarray | None = None
    tilt: np.ndarray | None = None    # world tilt of the orientation stream (rad); None: not estimated
    effects: object = None            # the named effects (freeload/effects_correction.FreeEffects); None: none
    gravity_body: np.ndarray | None = None   # the fixed base's gravity direction at calibration (unit, B); None: not kept

    @property
    def joints(self) -> tuple[str, ...]:
        return tuple(self.load.base_joints) + tuple(self.load.load_joints)

    def predict(self, g_B: np.ndarray, q: dict[str, np.ndarray], R_WB: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``w_o + w_load`` (N, 6) and its derivative (N, 6, 6 + p [+ 2] + 3) (module docstring), vectorised over
        samples; ``R_WB`` (N, 3, 3) the orientations ``g_B`` came from (the world tilt acts through them)."""
        g_B, dgB = tilted_gravity(self, g_B, R_WB)
        n, p = len(g_B), len(self.theta)
        R = self.load.nominal_rotation(q, n) @ self.E
        g = np.einsum("nji,nj->ni", R, g_B)
        K = self.load.lever(q, n)
        s = np.einsum("nij,j->ni", K, self.theta)
        mu = self.load.mass_row
        M = float(mu @ self.theta)
        model = np.concatenate([M * g, np.cross(s, g)], axis=1) + self.offset
        G = skew(g)
        J = np.zeros((n, 6, 6 + p + 3))
        J[:, :, :6] = np.eye(6)
        J[:, :3, 6: 6 + p] = g[:, :, None] * mu[None, None, :]
        J[:, 3:, 6: 6 + p] = -G @ K                                 # d(s x g)/d theta = -[g]x K
        J[:, :3, 6 + p:] = M * G
        J[:, 3:, 6 + p:] = skew(s) @ G
        return model, _with_tilt(J, 6 + p, self.tilt, dgB, R, M, s)


def param_names(leg: str, load_params: tuple[str, ...] | list[str] = ("mass_kg", "h_x", "h_y", "h_z"),
                tilt: bool = False) -> list[str]:
    """The labels of ``(w_o, theta[, tilt], delta)`` in the results protocol and the covariance file."""
    return ([f"{leg}.offset.{c}" for c in WRENCH_COMPONENTS] + [f"{leg}.{n}" for n in load_params]
            + ([f"{leg}.tilt.r{c}" for c in "xy"] if tilt else []) + [f"{leg}.mount.r{c}" for c in "xyz"])


def payload_param_names(leg: str, tilt: bool = False) -> list[str]:
    """The labels of ``(w_o, m, h[, tilt], delta)`` of a payload."""
    return param_names(leg, tilt=tilt)


def _tilt_of(d: dict) -> tuple[np.ndarray | None, np.ndarray]:
    """The world tilt ``gravity_tilt_rad`` of a leg entry (None: not estimated) and its variance (0 or 2 values)."""
    if "gravity_tilt_rad" not in d:
        return None, np.zeros(0)
    se = np.asarray([np.inf if v is None else v for v in d.get("gravity_tilt_se_rad", [np.inf, np.inf])], float)
    return np.asarray(d["gravity_tilt_rad"], float), se**2


def tilted_gravity(p, g_B: np.ndarray, R_WB: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    """Gravity in B of a calibration ``p`` with a world tilt and its derivative ``d g_B / d tilt`` (N, 3, 2):
    ``g R_WB^T u(tilt)`` where the orientations ``R_WB`` are known; else ``g_B`` as given and a zero derivative
    (``gx..gz``: an accelerometer's gravity). Without a tilt: ``(g_B, None)``."""
    if p.tilt is None:
        return g_B, None
    if R_WB is None:
        return g_B, np.zeros((len(g_B), 3, 2))
    from .freeload.problem import tilt_derivative, tilt_gravity

    return (p.g * np.einsum("nkj,k->nj", R_WB, tilt_gravity(p.tilt)),
            p.g * np.einsum("nkj,kt->njt", R_WB, tilt_derivative(p.tilt)))


def _with_tilt(J: np.ndarray, at: int, tilt, dgB: np.ndarray | None, R_B_ft: np.ndarray, M: float, s: np.ndarray) -> np.ndarray:
    """``J`` with the tilt's two columns inserted at ``at`` (before the mount's): ``[M dg_ft ; s x dg_ft]``,
    ``dg_ft = R_B,ft^T dg_B``; ``J`` itself without a tilt."""
    if tilt is None:
        return J
    if dgB is None:   # gravity given as such (gx..gz): the tilt does not act
        dgB = np.zeros((len(J), 3, 2))
    R = np.broadcast_to(R_B_ft, (len(J), 3, 3))
    dg = np.einsum("nji,njt->nit", R, dgB)
    s = np.broadcast_to(s, (len(J), 3))
    T = np.concatenate([M * dg, np.cross(s[:, :, None], dg, axis=1)], axis=1)
    return np.concatenate([J[:, :, :at], T, J[:, :, at:]], axis=2)


def payload_from_json(d: dict, leg: str, g: float, where: str = "calibration.json",
                      cov: tuple[np.ndarray, np.ndarray, np.ndarray | None] | None = None) -> PayloadCalibration:
    """A :class:`PayloadCalibration` from a leg entry of ``calibration.json``. ``cov``: ``(C, undetermined, null)``
    over :func:`payload_param_names` from the covariance file; None: the diagonal of the se (the CoM's se turned
    into the first moment's: ``Var(h_i) = m^2 Var(c_i) + c_i^2 Var(m)``), parameters with se inf undetermined."""
    try:
        if d.get("load_kind") != "rigid_payload":
            raise DataFormatError(f"{where}: transducer {leg}: load_kind = {d.get('load_kind')!r}; the contact wrench is "
                                  "computed for 'rigid_payload' and 'urdf_subtree' loads", path=where)
        m, c = float(d["load_mass_kg"]), np.asarray(d["load_com_m"], float)
        m_se, c_se = float(d["load_mass_se_kg"]), np.asarray(d["load_com_se_m"], float)
        tilt, var_t = _tilt_of(d)
        var = np.concatenate([np.asarray(d["offset_se"], float) ** 2, [m_se**2], m**2 * c_se**2 + c**2 * m_se**2, var_t,
                              np.asarray(d["mount_rotvec_se"], float) ** 2])
        R = np.asarray(d["rotation_to_body"], float)
        sigma = np.asarray(d.get("noise_sd", d.get("residual_rms")), float)
        off = np.asarray(d["offset"], float)
    except KeyError as exc:
        raise DataFormatError(f"{where}: transducer {leg}: missing key {exc.args[0]!r} of a payload calibration", path=where,
                              column=str(exc.args[0])) from None
    gb = _base_gravity(d)
    if cov is not None:
        C, und, null = cov
        return PayloadCalibration(leg, off, m, m * c, R, np.where(np.isfinite(C), C, 0.0), sigma, g, full_cov=True,
                                  undetermined=np.asarray(und, bool), null=null, tilt=tilt, gravity_body=gb)
    return PayloadCalibration(leg, off, m, m * c, R, np.diag(np.where(np.isfinite(var), var, 0.0)), sigma, g, full_cov=False,
                              undetermined=np.isinf(var), tilt=tilt, gravity_body=gb)


def _base_gravity(d: dict) -> np.ndarray | None:
    """A leg entry's ``gravity_body`` (the fixed base's gravity direction the run kept), unit, or None."""
    gb = d.get("gravity_body")
    return None if gb is None else np.asarray(gb, float) / np.linalg.norm(gb)


def payload_from_fit(fit, R_nominal: np.ndarray, g: float) -> PayloadCalibration:
    """A :class:`PayloadCalibration` from an in-process ``freeload.FreeLoadResult`` of a rigid payload (its full
    covariance over ``(w_o, m, h, delta)``)."""
    if fit.load.kind != "rigid_payload":
        raise DataFormatError(f"transducer {fit.leg}: a {fit.load.kind} load; the contact wrench is computed for rigid payloads")
    # the fit's parameters the load wrench depends on (a gravity_body recording's own tilt does not act on new data)
    idx = np.array([list(fit.names).index(n) for n in payload_param_names(fit.leg, fit.tilt is not None)])
    cov = np.where(np.isfinite(fit.cov), fit.cov, 0.0)[np.ix_(idx, idx)]
    return PayloadCalibration(fit.leg, fit.offset.copy(), float(fit.theta[0]), fit.theta[1:4].copy(),
                              np.asarray(R_nominal, float) @ fit.rotation, cov, fit.sigma.copy(), g, full_cov=True,
                              undetermined=np.isinf(np.asarray(fit.se, float))[idx], null=None if fit.null is None else fit.null[idx],
                              tilt=None if fit.tilt is None else np.asarray(fit.tilt, float).copy())


def urdf_from_json(d: dict, leg: str, g: float, cal_path: Path, cc=None) -> UrdfLoadCalibration:
    """A :class:`UrdfLoadCalibration` from a leg entry of ``calibration.json`` (keys ``urdf``, ``link``,
    ``urdf_groups``): the URDF parsed again (a path relative to ``calibration.json``'s folder, or absolute; a file
    of its name beside ``calibration.json`` when that path is gone), its groups checked against the stored ones. ``cc``: the run's :class:`~ftcal_nlp.uncertainty.CalibrationCovariance`
    (its block of this transducer); None, or the transducer not in it: the diagonal of the stored se."""
    from .loads import UrdfSubtree

    where = str(cal_path)
    try:
        urdf, link, groups = str(d["urdf"]), str(d["link"]), d["urdf_groups"]
        off = np.asarray(d["offset"], float)
        E = np.asarray(d.get("mount_rotation", np.eye(3)), float)
        sigma = np.asarray(d.get("noise_sd", d.get("residual_rms")), float)
        var_tail = np.asarray(d["mount_rotvec_se"], float) ** 2
        var_off = np.asarray(d["offset_se"], float) ** 2
        tilt, var_t = _tilt_of(d)
    except KeyError as exc:
        raise DataFormatError(f"{where}: transducer {leg}: missing key {exc.args[0]!r} of a URDF-load calibration (the "
                              "contact wrench needs the URDF, the sensor link and the groups' parameters)", path=where,
                              column=str(exc.args[0])) from None
    path, tree = _urdf_tree(urdf, leg, cal_path)
    check_urdf_unchanged(d, leg, path, tree, cal_path)
    try:
        load = UrdfSubtree(tree, link)
    except (KeyError, ValueError) as exc:
        raise DataFormatError(f"{where}: transducer {leg}: link {link!r} of {path}: {exc}", path=where, column="link") from None
    names = [gr.name for gr in load.groups]
    if sorted(names) != sorted(groups):
        raise DataFormatError(f"{where}: transducer {leg}: the URDF {path} below '{link}' has groups {names}, the calibration "
                              f"{sorted(groups)}; expected the URDF the calibration was made with", path=where)
    theta = np.concatenate([[groups[n]["mass_kg"], *groups[n]["first_moment_kgm"]] for n in names]).astype(float)
    cov = None if cc is None else cc.block(param_names(leg, load.param_names, tilt is not None))
    if cov is not None:
        C, und, null = cov
        return UrdfLoadCalibration(leg, load, off, theta, E, np.where(np.isfinite(C), C, 0.0), sigma, g, True,
                                   np.asarray(und, bool), null, tilt, gravity_body=_base_gravity(d))
    var_th = np.concatenate([[groups[n]["mass_se_kg"], *groups[n]["first_moment_se_kgm"]] for n in names]).astype(float) ** 2
    var = np.concatenate([var_off, var_th, var_t, var_tail])
    return UrdfLoadCalibration(leg, load, off, theta, E, np.diag(np.where(np.isfinite(var), var, 0.0)), sigma, g, False,
                               np.isinf(var), None, tilt, gravity_body=_base_gravity(d))


def _urdf_tree(urdf: str, leg: str, cal_path: Path):
    """``(path, KinematicTree)`` of a leg entry's ``urdf`` (relative to ``calibration.json``'s folder, or absolute; a
    file of its name beside ``calibration.json`` when that path is gone)."""
    from .data import read_urdf_tree

    path = Path(urdf) if Path(urdf).is_absolute() else cal_path.parent / urdf
    if not path.is_file() and (cal_path.parent / path.name).is_file():   # a calibration moved with its URDF beside it
        log.info("%s: legs.%s.urdf = %s is not there; using %s beside the calibration", cal_path, leg, urdf, path.name)
        path = cal_path.parent / path.name
    tree = read_urdf_tree(path, f"{cal_path} legs.{leg}.urdf")
    return path, tree


def check_urdf_unchanged(d: dict, leg: str, path: Path, tree, cal_path: Path) -> None:
    """The URDF as parsed now is the one calibrated with: its pose of the sensor link at zero joint angles against the
    calibration's ``rotation_nominal`` (written with it), within ``calibration.ROTATION_TOL``; an edited joint
    above the sensor (its ``rpy``) turns gravity in ft and would leave a phantom contact wrench. A calibration
    without the key (written before it was stored) is not checked."""
    from .calibration import ROTATION_TOL, urdf_rotation_at_zero

    if d.get("rotation_nominal") is None:
        return
    link = str(d["link"])
    try:
        now = urdf_rotation_at_zero(path, link, str(path), tree)
    except KeyError:
        return   # the link is gone: the load's reader names it
    diff = float(np.abs(now - np.asarray(d["rotation_nominal"], float)).max())
    if diff > ROTATION_TOL:
        ang = float(np.degrees(np.arccos(np.clip((np.trace(now.T @ np.asarray(d["rotation_nominal"], float)) - 1) / 2, -1, 1))))
        chain = [j.name for j in tree.path_to_root(link)]
        raise DataFormatError(
            f"{cal_path}: legs.{leg}.rotation_nominal: the URDF {path} puts sensor link '{link}' {ang:.3g} deg from the pose "
            f"the calibration was made with (largest element {diff:.3g}, beyond {ROTATION_TOL:g}); the joints above it "
            f"(one of {', '.join(chain)}, the sensor's own joint first) changed since: expected "
            "the URDF the calibration was made with (restore it, or re-run the calibration)", path=cal_path,
            column=f"legs.{leg}.rotation_nominal")


def arm_payload_from_json(d: dict, leg: str, g: float, cal_path: Path, cc=None) -> UrdfLoadCalibration:
    """A rigid payload oriented by the joints (keys ``urdf``, ``link`` beside the payload's): a
    :class:`UrdfLoadCalibration` whose load is :class:`~ftcal_nlp.loads.RigidPayload` on the URDF (``R_B,ft =
    R_nom(q) E``, ``theta = [m, m c]``); ``cc`` as :func:`urdf_from_json` (without it the stored se's diagonal, the
    CoM's turned into the first moment's as :func:`payload_from_json`)."""
    from .loads import RigidPayload

    where = str(cal_path)
    base = payload_from_json({**d, "rotation_to_body": d.get("mount_rotation", np.eye(3))}, leg, g, where)
    path, tree = _urdf_tree(str(d["urdf"]), leg, cal_path)
    check_urdf_unchanged(d, leg, path, tree, cal_path)
    try:
        load = RigidPayload(tree=tree, ft_link=str(d["link"]))
    except KeyError as exc:
        raise DataFormatError(f"{where}: transducer {leg}: link {d['link']!r} of {path}: {exc}", path=where, column="link") from None
    theta = np.r_[base.mass_kg, base.h]
    E = np.asarray(d["mount_rotation"], float)
    block = None if cc is None else cc.block(param_names(leg, load.param_names, base.tilt is not None))
    if block is not None:
        C, und, null = block
        return UrdfLoadCalibration(leg, load, base.offset, theta, E, np.where(np.isfinite(C), C, 0.0), base.sigma, g, True,
                                   np.asarray(und, bool), null, base.tilt, gravity_body=base.gravity_body)
    return UrdfLoadCalibration(leg, load, base.offset, theta, E, base.cov, base.sigma, g, False, base.undetermined, None,
                               base.tilt, gravity_body=base.gravity_body)


def orientation_of_frame(df: pd.DataFrame) -> np.ndarray | None:
    """``R_WB`` (N, 3, 3) from ``qw..qz`` (normalised; NaN rows where missing), or None without those columns."""
    if not set(QUAT_COLUMNS) <= set(map(str, df.columns)):
        return None
    q = df[list(QUAT_COLUMNS)].to_numpy(float)
    ok = np.all(np.isfinite(q), axis=1)
    out = np.full((len(q), 3, 3), np.nan)
    out[ok] = quat_to_rotation(q[ok] / np.linalg.norm(q[ok], axis=1, keepdims=True))
    return out


def gravity_of_frame(df: pd.DataFrame, g: float, where: str, base: np.ndarray | None = None) -> np.ndarray:
    """Gravity in B (N, 3), m/s^2, from ``qw..qz`` (``R_WB^T [0, 0, -g]``) or ``gx..gz`` (normalised, times g);
    NaN rows where the orientation is missing. Without those columns, ``g base`` for every row (``base`` the fixed
    base's unit gravity direction in B, :func:`base_gravity`); without a base either, an error."""
    cols = set(map(str, df.columns))
    if set(QUAT_COLUMNS) <= cols:
        q = df[list(QUAT_COLUMNS)].to_numpy(float)
        ok = np.all(np.isfinite(q), axis=1)
        out = np.full((len(q), 3), np.nan)
        out[ok] = -g * quat_to_rotation(q[ok] / np.linalg.norm(q[ok], axis=1, keepdims=True))[:, 2, :]
        return out
    if set(GRAVITY_COLUMNS) <= cols:
        v = df[list(GRAVITY_COLUMNS)].to_numpy(float)
        return g * v / np.linalg.norm(v, axis=1, keepdims=True)
    if base is not None:
        return np.broadcast_to(g * np.asarray(base, float), (len(df), 3)).copy()
    raise DataFormatError(f"{where}: the contact wrench needs gravity: columns qw, qx, qy, qz or gx, gy, gz, or for a fixed "
                          "base its direction (the calibration's gravity_body, or correct --gravity-body X Y Z)", path=where)


def base_gravity(cal_legs: dict, df: pd.DataFrame, where: str, option=None) -> dict[str, np.ndarray | None]:
    """Per transducer the fixed base's unit gravity direction in B for a recording without ``qw..qz`` / ``gx..gz``
    (None with them: they give it per sample): ``option`` (``--gravity-body``) where given, else the calibration's
    ``gravity_body``; neither is an error naming both ways. Said in the log."""
    cols = set(map(str, df.columns))
    if set(QUAT_COLUMNS) <= cols or set(GRAVITY_COLUMNS) <= cols:
        if option is not None:
            log.warning("%s: --gravity-body ignored: the recording gives gravity per sample (its orientation columns)", where)
        return {k: None for k in cal_legs}
    if option is not None:
        v = np.asarray(option, float)
        if v.shape != (3,) or not np.all(np.isfinite(v)) or np.linalg.norm(v) == 0:
            raise ConfigError(f"--gravity-body {option}: expected three finite numbers, not all zero (gravity's direction "
                              "in B, pointing down)", key="--gravity-body")
        log.info("%s: no orientation columns: gravity along --gravity-body %s (B, normalised) for every sample", where,
                 np.round(v / np.linalg.norm(v), 6).tolist())
        return {k: v / np.linalg.norm(v) for k in cal_legs}
    missing = [k for k, p in cal_legs.items() if getattr(p, "gravity_body", None) is None]
    if missing:
        raise DataFormatError(f"{where}: no orientation columns (qw, qx, qy, qz or gx, gy, gz) and the calibration of {missing} "
                              "keeps no fixed base's gravity_body (it was made with gravity per sample or several held "
                              "orientations); expected orientation columns, or the base's gravity direction in B: correct "
                              "--gravity-body X Y Z (e.g. 0 0 -1 for a level base)", path=where)
    for k, p in cal_legs.items():
        log.info("%s: no orientation columns: transducer %s's gravity along the calibration's gravity_body %s (the fixed "
                 "base at calibration, its estimated tilt applied) for every sample", where, k,
                 np.round(p.gravity_body, 6).tolist())
    return {k: np.asarray(p.gravity_body, float) for k, p in cal_legs.items()}


def predicted_load(p: PayloadCalibration, g_B: np.ndarray, dgB: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``w_o + w_load`` (N, 6) for gravity ``g_B`` (N, 3) and its derivative ``J`` (N, 6, 13) with respect to
    ``(w_o, m, h, delta)`` (module docstring); with a tilt (``p.tilt``, ``dgB = d g_B / d tilt`` (N, 3, 2)) (N, 6, 15)
    over ``(w_o, m, h, tilt, delta)``."""
    g = np.einsum("ji,nj->ni", p.R_B_ft, g_B)                     # R_B,ft^T g_B
    model = np.concatenate([p.mass_kg * g, np.cross(p.h, g)], axis=1) + p.offset
    G = skew(g)
    J = np.zeros((len(g), 6, 13))
    J[:, :, :6] = np.eye(6)
    J[:, :3, 6] = g
    J[:, 3:, 7:10] = -G                                            # d(h x g)/dh
    J[:, :3, 10:13] = p.mass_kg * G                                # d g_ft / d delta = [g_ft]x
    J[:, 3:, 10:13] = skew(p.h) @ G
    return model, _with_tilt(J, 10, p.tilt, dgB, p.R_B_ft, p.mass_kg, p.h)


def contact_wrench(p: PayloadCalibration | UrdfLoadCalibration, w_m: np.ndarray, g_B: np.ndarray,
                   q: dict[str, np.ndarray] | None = None, R_WB: np.ndarray | None = None, *, t: np.ndarray | None = None,
                   quat: np.ndarray | None = None, temperature: np.ndarray | None = None,
                   where: str = "recording") -> tuple[np.ndarray, np.ndarray]:
    """Contact wrench (N, 6) and its se (N, 6) (module docstring) for readings ``w_m`` (N, 6), gravity ``g_B``,
    joint angles ``q`` (joint -> (N,); URDF loads) and the orientations ``R_WB`` (N, 3, 3) ``g_B`` came from
    (None: ``gx..gz``; a calibration's world tilt acts through them). A calibration with named effects
    (``p.effects``, ``calibration_with_effect.json``) corrects the readings for them first
    (``freeload/effects_correction.py``: needs the samples' times ``t``, and where the effects ask for them the
    orientation ``quat`` (N, 4) and the ``temperature`` (N,)); the se then carry the effects' parameters."""
    q = {} if q is None else q
    model, J = p.predict(g_B, q, R_WB)
    if p.effects is None:
        var = calibration_variance(p, J) + p.sigma**2
        return w_m - model, np.sqrt(np.clip(var, 0.0, None))
    from .freeload import effects_correction as fe

    if t is None:
        raise ValueError("contact_wrench: a calibration with effects needs the samples' times t")
    g_t = tilted_gravity(p, g_B, R_WB)[0]
    ctx = fe.context(p, p.effects, np.asarray(t, float), w_m, model, g_t, quat, q, temperature)
    yc, parts = fe.correct_readings(p, p.effects, ctx, where)
    var = fe.joint_variance(J, p.effects, parts) + p.sigma**2
    return yc - model, np.sqrt(np.clip(var, 0.0, None))


def joint_angles(df: pd.DataFrame, joints: tuple[str, ...], tree, where: str) -> dict[str, np.ndarray]:
    """``q_{joint}`` columns of ``df`` for ``joints`` (rad; checked against the URDF limits: degrees are an error),
    a joint without a column held at 0 and named in a warning."""
    from types import SimpleNamespace

    from .data import _check_joint_units

    missing = [j for j in joints if f"{JOINT_PREFIX}{j}" not in df.columns]
    if missing:
        log.warning("%s: joints %s have no column (%s): held at 0", where, missing, [f"{JOINT_PREFIX}{j}" for j in missing])
    q = {j: pd.to_numeric(df[f"{JOINT_PREFIX}{j}"], errors="coerce").to_numpy(float) for j in joints if j not in missing}
    fin = {j: v[np.isfinite(v)] for j, v in q.items()}
    _check_joint_units({j: v for j, v in fin.items() if v.size}, SimpleNamespace(tree=tree), where)
    return q


#: readings whose median force norm is this many times above or below what the calibration predicts (offset plus
#: the load's weight) are in another unit: kN or mN are 1000x off; a tool pressing on something for most of a
#: recording stays well within (a 0.1 kg probe held at 50 N: ~50x)
UNIT_FACTOR = 100.0
#: the load's weight must stand this many noise sd above the readings' noise for its direction to test the
#: orientation columns (a light load in a noisy sensor says nothing about them)
DIRECTION_SNR = 10.0
#: rows of a long recording the checks against the calibration look at (a regular subsample)
CHECK_ROWS = 5000


def recorded_transducers(df: pd.DataFrame) -> tuple[str, ...]:
    """Names ``X`` for which the table holds every wrench column ``X_fx`` .. ``X_tz`` (a free load has no ``X_phi``)."""
    names = [str(c)[: -len("_fx")] for c in df.columns if str(c).endswith("_fx")]
    return tuple(k for k in names if all(f"{k}_{c}" in df.columns for c in WRENCH_COMPONENTS))


def check_transducers(cal_legs: dict, df: pd.DataFrame, where: str) -> None:
    """The recording carries exactly the calibration's transducers: one it lacks (columns ``X_fx..X_tz`` the
    calibration has no entry for) or one of the calibration's missing from it is an error naming the columns."""
    legs = list(cal_legs)
    extra = [k for k in recorded_transducers(df) if k not in cal_legs]
    if extra:
        raise DataFormatError(f"{where}: columns {extra[0]}_fx..{extra[0]}_tz of transducer(s) {extra} but the calibration "
                              f"covers only {legs}; expected a calibration of every transducer of the recording (or drop "
                              "those columns)", path=where, column=f"{extra[0]}_fx")
    missing = [f"{k}_{c}" for k in legs for c in WRENCH_COMPONENTS if f"{k}_{c}" not in df.columns]
    if missing:
        raise DataFormatError(f"{where}: missing column(s) {missing} of the calibrated transducer(s) {legs}; expected the "
                              "readings of every transducer of the calibration", path=where, column=missing[0])


def check_joint_columns(cal_legs: dict, df: pd.DataFrame, where: str) -> None:
    """Every ``q_{joint}`` column names a joint of the calibration's URDF (as ``run`` reads its recordings): a
    misspelt joint would otherwise be held at 0 in silence. A calibration without a URDF reads no joint column."""
    trees = [c.load.tree for c in cal_legs.values() if isinstance(c, UrdfLoadCalibration) and c.load.tree is not None]
    if not trees:
        return
    names = list(dict.fromkeys(j.name for tr in trees for j in tr.joints.values()))
    for c in map(str, df.columns):
        if c.startswith(JOINT_PREFIX) and c[len(JOINT_PREFIX):] not in names:
            raise DataFormatError(f"{where}: column '{c}': the calibration's URDF has no joint '{c[len(JOINT_PREFIX):]}' "
                                  f"(joints: {names}); expected q_{{joint}} columns of its joints (a misspelt name?)",
                                  path=where, column=c)


def _orientation_columns(df: pd.DataFrame, where: str) -> list[str]:
    """``qw..qz`` or ``gx..gz`` (complete), the gravity per sample; [] without either (a fixed base)."""
    from .data import _complete_group

    cols = [str(c) for c in df.columns]
    q, gcols = _complete_group(cols, QUAT_COLUMNS, where), _complete_group(cols, GRAVITY_COLUMNS, where)
    return q or gcols   # neither: a fixed base's gravity (base_gravity)


def clean_rows(cal_legs: dict, df: pd.DataFrame, where: str) -> tuple[pd.DataFrame, np.ndarray]:
    """The recording's columns ``correct`` reads as numbers, checked as a run reads its recordings (``data.py``): a
    cell that is not a number or a column without one is an error naming it; rows with a NaN time, reading or joint
    angle, and rows without an orientation, are dropped (counted in the log); fewer than two rows left, ``t`` not
    strictly increasing or not in seconds where the correction uses the clock (:func:`_check_clock`), quaternions not
    of norm 1 within 0.01 are
    errors naming the file and the column. Returns the numeric table of the kept rows and the kept-row mask."""
    from .data import TEMP_COMMON, TEMP_SUFFIX, _numeric

    if "t" not in df.columns:
        raise DataFormatError(f"{where}: missing column 't'", path=where, column="t")
    check_transducers(cal_legs, df, where)
    if len(df) == 0:
        raise DataFormatError(f"{where}: no rows (only the header); expected a recording to correct", path=where)
    orient = _orientation_columns(df, where)
    check_joint_columns(cal_legs, df, where)
    joints = [f"{JOINT_PREFIX}{j}" for c in cal_legs.values() for j in c.joints if f"{JOINT_PREFIX}{j}" in df.columns]
    joints = list(dict.fromkeys(joints))
    read = ["t"] + [f"{k}_{c}" for k in cal_legs for c in WRENCH_COMPONENTS] + joints
    known = set(read) | set(QUAT_COLUMNS) | set(GRAVITY_COLUMNS) | {TEMP_COMMON} | {f"{k}{TEMP_SUFFIX}" for k in cal_legs}
    extra = [str(c) for c in df.columns if str(c) not in known and not str(c).startswith(JOINT_PREFIX)]
    if extra:
        log.warning("%s: extra column(s) ignored: %s", where, extra)
    values = _numeric(df, read + orient, where)
    n = len(df)
    ok_read = np.all(np.isfinite(values[:, :len(read)]), axis=1)
    ok_o = np.all(np.isfinite(values[:, len(read):]), axis=1)
    if orient == list(GRAVITY_COLUMNS):
        ok_o &= np.linalg.norm(values[:, len(read):], axis=1) > 0
    if (~ok_read).any():
        log.warning("%s: dropped %d of %d rows with NaN or infinite readings%s", where, int((~ok_read).sum()), n,
                    " or joint angles" if joints else "")
    if (ok_read & ~ok_o).any():
        log.warning("%s: dropped %d of %d rows without an orientation (%s)", where, int((ok_read & ~ok_o).sum()), n,
                    ", ".join(orient))
    keep = ok_read & ok_o
    if keep.sum() < 2:
        raise DataFormatError(f"{where}: fewer than 2 rows with finite readings and an orientation ({int(keep.sum())} of {n}); "
                              "expected a recording", path=where)
    clean = pd.DataFrame(values[keep], columns=read + orient)
    t = clean["t"].to_numpy()
    dt = np.diff(t)
    if np.any(dt <= 0):
        i = int(np.argmax(dt <= 0))
        row = int(np.flatnonzero(keep)[i + 1]) + 2   # the file's line (header is line 1)
        raise DataFormatError(f"{where}: column 't' is not strictly increasing (line {row}: {float(t[i])!r} -> {float(t[i + 1])!r}); expected "
                              "one row per sample in time order", path=where, column="t")
    _check_clock(cal_legs, t, where)
    check_holds_clock(t, clean, orient, joints, where)
    if orient == list(QUAT_COLUMNS):
        norms = np.linalg.norm(clean[list(QUAT_COLUMNS)].to_numpy(), axis=1)
        if np.any(np.abs(norms - 1.0) > 1e-2):
            raise DataFormatError(f"{where}: columns qw, qx, qy, qz are not unit quaternions (norms {norms.min():.3g}.."
                                  f"{norms.max():.3g}); expected norm 1 within 0.01", path=where, column="qw")
    return clean, keep


def _check_clock(cal_legs: dict, t: np.ndarray, where: str) -> None:
    """Column ``t`` in seconds where the correction uses the clock: a calibration with effects that follow the
    readings' own clock (``effects_correction.STREAM_EFFECTS``: re-sampling, relaxation) needs a stream, and a
    median sampling interval above ``checks.MAX_SAMPLE_INTERVAL_S`` is a clock in ms or a list of single-row poses.
    Otherwise ``t`` is copied as it is (a list of poses 9 s apart is a fine recording of a payload)."""
    from .freeload.effects_correction import STREAM_EFFECTS

    need = {k: [m.name for m in p.effects.members if m.name in STREAM_EFFECTS] for k, p in cal_legs.items()
            if p.effects is not None}
    need = {k: v for k, v in need.items() if v}
    dt = float(np.median(np.diff(t)))
    if need and dt > MAX_SAMPLE_INTERVAL_S:
        leg, names = next(iter(need.items()))
        raise DataFormatError(
            f"{where}: column t: median sampling interval {dt:.4g} (units of t); {leg}'s calibration corrects for "
            f"{', '.join(names)}, which follow the readings' own clock: expected seconds, at most {MAX_SAMPLE_INTERVAL_S:g} s "
            "between the samples of a stream: is t in milliseconds, or is this a list of single-row poses (correct "
            "those with calibration.json)?", path=where, column="t")


#: a median interval of ``t`` above this (units of t) between rows that mostly share their pose is milliseconds:
#: a stream of holds at 100 Hz in ms has 10 units between samples; single-row poses seconds apart differ row to row
HOLD_CLOCK_DT = MAX_SAMPLE_INTERVAL_S
#: consecutive rows closer than this (deg of orientation, rad of each joint) share a pose
SAME_POSE_DEG = 0.5
SAME_JOINT_RAD = 0.01


def same_pose_fraction(clean: pd.DataFrame, orient: list[str], joints: list[str]) -> float:
    """The fraction of consecutive rows that share their pose: orientation (``qw..qz`` or ``gx..gz``) within
    ``SAME_POSE_DEG`` and every joint column within ``SAME_JOINT_RAD``; nan without either."""
    if len(clean) < 2:
        return float("nan")
    ang = None
    if orient:
        v = clean[orient].to_numpy(float)
        v = v / np.linalg.norm(v, axis=1, keepdims=True)
        dot = np.abs(np.einsum("ni,ni->n", v[1:], v[:-1])) if orient == list(QUAT_COLUMNS) else np.einsum("ni,ni->n", v[1:], v[:-1])
        ang = np.degrees(np.arccos(np.clip(dot, -1, 1))) * (2 if orient == list(QUAT_COLUMNS) else 1)
    steps = np.diff(clean[joints].to_numpy(float), axis=0) if joints else None
    return same_pose_share(ang, steps, SAME_POSE_DEG, SAME_JOINT_RAD)


def check_holds_clock(t: np.ndarray, clean: pd.DataFrame, orient: list[str], joints: list[str], where: str) -> None:
    """Column ``t`` in seconds, as ``run`` reads a stream of holds: a median interval above ``HOLD_CLOCK_DT`` units
    of t where most consecutive rows share their pose (:func:`same_pose_fraction`) is a clock in milliseconds; a
    list of single-row poses (each row another pose) is left as it is."""
    if len(t) < 3:
        return
    dt = float(np.median(np.diff(t)))
    if dt <= HOLD_CLOCK_DT:
        return
    same = same_pose_fraction(clean, orient, joints)
    if same > 0.5:
        raise DataFormatError(
            f"{where}: column t: median sampling interval {dt:.4g} (units of t) while {100 * same:.0f} % of consecutive rows "
            f"share their pose ({', '.join((orient or []) + joints)} within {SAME_POSE_DEG:g} deg / {SAME_JOINT_RAD:g} rad): "
            f"a stream of holds, not a list of poses; expected seconds, at most {HOLD_CLOCK_DT:g} s between the samples of "
            "a hold: is t in milliseconds?", path=where, column="t")


def _alternatives(df: pd.DataFrame) -> dict[str, pd.DataFrame]:
    """The same rows read with the usual convention slips of the orientation columns: the quaternion's other
    orders and its conjugate (``checks._quaternion_readings``, the run's list), or gravity ``gx..gz`` negated."""
    if set(QUAT_COLUMNS) <= set(df.columns):
        from .checks import _quaternion_readings

        q = df[list(QUAT_COLUMNS)].to_numpy()
        out = {}
        for what, v in _quaternion_readings().items():
            alt = df.copy()
            alt[list(QUAT_COLUMNS)] = reread_quaternion(q, v)
            out[what] = alt
        return out
    alt = df.copy()
    alt[list(GRAVITY_COLUMNS)] = -df[list(GRAVITY_COLUMNS)].to_numpy()
    return {"columns gx, gy, gz point up (a raw accelerometer reads +g when still: negate them)": alt}


def _load_angles(p, df: pd.DataFrame, w: np.ndarray, q: dict, where: str,
                 base: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per row the angle (deg) between the reading's force less the offset and the calibration's load force,
    and the calibration's full predicted wrench (offset and load) (N, 6); ``base`` as :func:`gravity_of_frame`."""
    from .checks import _angle_deg

    g_B = gravity_of_frame(df, p.g, where, base)
    model, _ = p.predict(g_B, q, orientation_of_frame(df))
    return _angle_deg(w[:, :3] - p.offset[:3], model[:, :3] - p.offset[:3]), model


def check_against_calibration(cal_legs: dict, clean: pd.DataFrame, where: str, base: dict | None = None,
                              base_source: str = "", faulty: dict[str, np.ndarray] | None = None) -> None:
    """The readings against what the calibration predicts for them (every transducer, a regular subsample of
    ``CHECK_ROWS`` rows), as ``run`` checks its recordings against the robot: the forces' unit (median force norm
    within ``UNIT_FACTOR`` of the prediction's; torques within the run's lever-arm bound of the forces,
    ``data._check_units``), and, where the load's weight stands ``DIRECTION_SNR`` noise sd above the noise, the
    orientation columns' convention: the load force's direction from the columns as given must agree with the
    readings' best (median angle within ``checks.TILT_DEG``), else an error names the reading of the columns that
    agrees (x, y, z, w order; the conjugate; gravity negated). Without orientation columns, the fixed base's
    gravity (``base`` per transducer, :func:`base_gravity`; ``base_source`` where it came from, for the message) is
    tested the same way (negated: pointing up). Before the direction, the rows without contact test the frames
    (:func:`check_frames`; ``faulty`` per transducer the rows of a stuck or dead channel, left out)."""
    from .checks import QUAT_ORDER_RATIO, TILT_DEG
    from .data import check_torque_units

    step = max(1, -(-len(clean) // CHECK_ROWS))
    every = clean.iloc[::step].reset_index(drop=True)
    base = base or {}
    for k, p in cal_legs.items():
        ok = np.ones(len(every), bool) if not faulty or k not in faulty else ~np.asarray(faulty[k], bool)[::step]
        if not ok.any():
            continue   # every row of a stuck or dead channel: said by the fault's warning
        sub = every[ok].reset_index(drop=True)
        w = sub[[f"{k}_{c}" for c in WRENCH_COMPONENTS]].to_numpy()
        q = {j: sub[f"{JOINT_PREFIX}{j}"].to_numpy() for j in p.joints if f"{JOINT_PREFIX}{j}" in sub.columns}
        gb = base.get(k)
        ang, model = _load_angles(p, sub, w, q, where, gb)
        f_read = float(np.median(np.linalg.norm(w[:, :3], axis=1)))
        f_pred = float(np.median(np.linalg.norm(model[:, :3], axis=1)))
        noise_f = float(np.linalg.norm(np.nan_to_num(np.asarray(p.sigma, float)[:3])))
        if f_pred > DIRECTION_SNR * noise_f and not 1 / UNIT_FACTOR <= f_read / f_pred <= UNIT_FACTOR:
            raise DataFormatError(
                f"{where}: columns {k}_fx..{k}_fz: median force {f_read:.4g} where the calibration predicts {f_pred:.4g} N "
                f"(offset plus the load's weight), {f_read / f_pred:.3g}x; expected N, within a factor {UNIT_FACTOR:g}: are the "
                "forces in another unit (kN, mN)?", path=where, column=f"{k}_fx")
        check_torque_units(w, f_pred, where, k)
        pending = check_frames(p, k, sub, w, q, where, gb)   # an orientation reading's error: after the direction's
        weight = float(np.median(np.linalg.norm(model[:, :3] - p.offset[:3], axis=1)))
        given = float(np.median(ang))
        if weight <= DIRECTION_SNR * noise_f or given <= TILT_DEG:
            if pending is not None:
                raise pending
            continue
        if gb is not None:
            alt = {"the gravity direction is negated (it points down in B: e.g. 0 0 -1 for a level base)":
                   float(np.median(_load_angles(p, sub, w, q, where, -gb)[0]))}
        else:
            alt = {what: float(np.median(_load_angles(p, a, w, q, where)[0])) for what, a in _alternatives(sub).items()}
        best = min(alt, key=alt.get)
        cols = "qw, qx, qy, qz" if set(QUAT_COLUMNS) <= set(sub.columns) else "gx, gy, gz"
        if gb is not None and alt[best] <= TILT_DEG and alt[best] < QUAT_ORDER_RATIO * given:
            raise DataFormatError(
                f"{where}: no orientation columns; gravity along {base_source or 'the fixed base'} {np.round(gb, 4).tolist()}: "
                f"the load's weight along it is a median {given:.0f} deg from transducer {k}'s force readings less the "
                f"calibration's offset; expected within {TILT_DEG:.0f} deg: they agree within {alt[best]:.0f} deg if "
                f"{best}", path=where, column="gravity_body")
        if gb is not None:
            if pending is not None:
                raise pending
            log.warning("%s: the load's weight along %s is a median %.0f deg from transducer %s's force readings less the "
                        "offset: contact for most of the recording, another base orientation than the calibration's, or joint "
                        "angles off (a joint without its column, another zero)?",
                        where, base_source or "the fixed base's gravity", given, k)
            continue
        if alt[best] <= TILT_DEG and alt[best] < QUAT_ORDER_RATIO * given:
            raise DataFormatError(
                f"{where}: columns {cols}: the load's weight from them is a median {given:.0f} deg from transducer {k}'s force "
                f"readings less the calibration's offset; expected within {TILT_DEG:.0f} deg (DATA_FORMAT.md section 3: qw..qz "
                f"map B to the world, gx..gz point down): they agree within {alt[best]:.0f} deg if {best}",
                path=where, column=cols.split(",")[0])
        if pending is not None:
            raise pending
        log.warning("%s: columns %s: the load's weight from them is a median %.0f deg from transducer %s's force readings "
                    "less the offset and no other reading of the columns agrees: contact for most of the recording, or a "
                    "calibration of another mounting?", where, cols, given, k)


#: a row is at the noise (no contact) when its residual's norm, forces or torques, is within this many times the
#: norm of the readings' noise sd (3 components: a chi of 3 dof exceeds 5 sd with probability ~1e-5)
FREE_K = 5.0
#: the rows at the noise the frame checks need (of the regular subsample) before they test anything
MIN_FREE_ROWS = 20
#: a reading of the columns is named where it puts this many times more rows at the noise than the columns as
#: given, and at least MIN_FREE_ROWS of them (a recording mostly in contact leaves few rows to either)
FIX_RATIO = 5.0
#: the torques' other units tried (N*mm, kN*m)
TORQUE_SCALES = {"the torques are in N*mm (x0.001 turns them into N*m)": 1e-3,
                 "the torques are in kN*m (x1000 turns them into N*m)": 1e3}


def _describe_signed(P: np.ndarray, names: tuple[str, str, str]) -> str:
    """``fx <- -fy, ...`` for the rows of a signed permutation that differ from the identity."""
    out = []
    for i, n in enumerate(names):
        j = int(np.argmax(np.abs(P[i])))
        if j == i and P[i, j] < 0:
            out.append(f"{n} negated")
        elif j != i:
            out.append(f"{n} <- {'-' if P[i, j] < 0 else ''}{names[j]}")
    return ", ".join(out)


def _signed_fix_text(P: np.ndarray, cols: list[str]) -> str:
    names = tuple(c.rsplit("_", 1)[1] for c in cols)
    if np.allclose(P, -np.eye(3)):
        return f"the columns {', '.join(cols)} are negated (their sign convention reversed)"
    what = "a reflected (left-handed) frame: " if np.linalg.det(P) < 0 else "another order or sign: "
    return f"{what}{_describe_signed(P, names)} (columns {cols[0]}..{cols[-1]})"


def _at_noise(r: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Rows (N,) of residuals ``r`` (N, 3) within ``FREE_K`` times the noise's norm."""
    return np.linalg.norm(r, axis=1) <= FREE_K * float(np.linalg.norm(sigma))


def check_frames(p, k: str, sub: pd.DataFrame, w: np.ndarray, q: dict, where: str,
                 gb: np.ndarray | None) -> DataFormatError | None:
    """Transducer ``k``'s readings ``w`` (rows of ``sub``) against the calibration ``p`` on the rows without contact.

    Forces: the rows whose force residual (reading less offset and load) is at the noise (``FREE_K``) with the
    columns as given, against every signed permutation of the force columns, the other readings of the orientation
    columns (:func:`_alternatives`) and continuous joints' columns read as degrees: one that puts ``FIX_RATIO`` times
    more rows (and ``MIN_FREE_ROWS``) at the noise is an error naming it, the force frame's before the orientation's
    (a reflected frame cannot pass for another quaternion order); an orientation reading is returned (the error to
    raise) for the direction test that follows (:func:`check_against_calibration`) to name it first in its words. Torques: a contact has a force; on the rows whose force is
    at the noise the torque must be too (a couple without a force is no contact): where it is not on most of them,
    the torques' other units and every signed permutation are tried, and one that brings most to the noise is named;
    none is a warning. Fewer than ``MIN_FREE_ROWS`` rows at the noise (a recording mostly in contact, offsets
    drifted): a warning, nothing tested."""
    fc, tc = [f"{k}_{c}" for c in WRENCH_COMPONENTS[:3]], [f"{k}_{c}" for c in WRENCH_COMPONENTS[3:]]
    sf, st = np.nan_to_num(np.asarray(p.sigma, float)[:3]), np.nan_to_num(np.asarray(p.sigma, float)[3:])
    if not np.linalg.norm(sf) > 0 or not np.linalg.norm(st) > 0:
        return
    g_B = gravity_of_frame(sub, p.g, where, gb)
    model, _ = p.predict(g_B, q, orientation_of_frame(sub))
    free = _at_noise(w[:, :3] - model[:, :3], sf)
    n_given = int(free.sum())
    cand: dict[str, int] = {}
    from .checks import _signed_permutations

    for P in _signed_permutations():
        cand[_signed_fix_text(P, fc)] = int(_at_noise(w[:, :3] @ P.T - model[:, :3], sf).sum())
    for j in _continuous_joints(p, q):
        qq = {**q, j: q[j] * np.pi / 180}
        m2, _ = p.predict(g_B, qq, orientation_of_frame(sub))
        cand[f"column {JOINT_PREFIX}{j} holds degrees (continuous joint: no URDF limit to exceed; x pi/180 turns it into "
             "radians)"] = int(_at_noise(w[:, :3] - m2[:, :3], sf).sum())
    orient = {}
    if gb is None:
        for what, alt in _alternatives(sub).items():
            m2, _ = p.predict(gravity_of_frame(alt, p.g, where), q, orientation_of_frame(alt))
            orient[what] = int(_at_noise(w[:, :3] - m2[:, :3], sf).sum())
    best = max(cand, key=cand.get)
    best_o = max(orient.values(), default=0)
    if cand[best] >= MIN_FREE_ROWS and cand[best] >= FIX_RATIO * max(n_given, 1) and cand[best] > best_o:
        joint = best.split(" ")[1] if best.startswith("column ") else None
        at = (f"{n_given} of {len(w)} rows (a regular subsample) have transducer {k}'s force at the noise (within {FREE_K:g}x "
              f"its sd, {FREE_K * np.linalg.norm(sf):.3g} N, of the calibration's offset plus the load)")
        if joint:
            raise DataFormatError(f"{where}: column {joint}: {at} with the column as given, {cand[best]} if it {best.split(' ', 2)[2]}; "
                                  "expected joint angles in radians (DATA_FORMAT.md section 5)", path=where, column=joint)
        raise DataFormatError(
            f"{where}: columns {fc[0]}..{fc[-1]}: {at} with the columns as given, {cand[best]} if {best}; expected the columns "
            "as given to leave the rows without contact at the noise (DATA_FORMAT.md: forces in N in the ft frame, a "
            "right-handed frame)", path=where, column=fc[0])
    what_o = max(orient, key=orient.get) if orient else None
    pending = None
    if what_o is not None and orient[what_o] >= MIN_FREE_ROWS and orient[what_o] >= FIX_RATIO * max(n_given, 1):
        pending = DataFormatError(
            f"{where}: columns {', '.join(_orientation_names(sub))}: {n_given} of {len(w)} rows (a regular subsample) have "
            f"transducer {k}'s force at the noise (within {FREE_K:g}x its sd of the calibration's offset plus the load) with "
            f"the columns as given, {orient[what_o]} if {what_o}; expected the columns as given to agree best "
            "(DATA_FORMAT.md section 3: qw..qz map B to the world, gx..gz point down)", path=where,
            column=_orientation_names(sub)[0])
    if n_given < MIN_FREE_ROWS:
        if pending is not None:
            return pending
        log.warning("%s: transducer %s: %d of %d rows (a regular subsample) have a force at the noise of the calibration's "
                    "prediction; the readings' frame and the torques' unit are tested on %d or more such rows without "
                    "contact: not tested (a short recording, one mostly in contact, offsets drifted since the calibration, "
                    "or another load)", where, k, n_given, len(w), MIN_FREE_ROWS)
        return
    rt = w[free, 3:]
    mt = model[free, 3:]
    good = int(_at_noise(rt - mt, st).sum())
    if good >= 0.5 * n_given:
        return pending
    fixes = {what: int(_at_noise(rt * s - mt, st).sum()) for what, s in TORQUE_SCALES.items()}
    for P in _signed_permutations():
        fixes[_signed_fix_text(P, tc)] = int(_at_noise(rt @ P.T - mt, st).sum())
    fix = max(fixes, key=fixes.get)
    excess = float(np.median(np.linalg.norm(rt - mt, axis=1)))
    head = (f"{where}: columns {tc[0]}..{tc[-1]}: on the {n_given} rows (of {len(w)}, a regular subsample) whose force is at "
            f"the noise (no contact), the torque less the calibration's offset and load is a median {excess:.3g} N*m, "
            f"{excess / np.linalg.norm(st):.3g}x its noise sd; at the noise on {good} of them")
    if fixes[fix] >= 0.5 * n_given:
        raise DataFormatError(f"{head}, on {fixes[fix]} if {fix}; expected the torques as given at the noise where there "
                              "is no contact force (a couple without a force is no contact; torques in N*m, ft frame)",
                              path=where, column=tc[0])
    log.warning("%s; no other unit, order or sign of the torque columns brings them to the noise: torques in another "
                "frame or unit, or a calibration of another load?", head)
    return pending


def _orientation_names(df: pd.DataFrame) -> list[str]:
    return list(QUAT_COLUMNS) if set(QUAT_COLUMNS) <= set(map(str, df.columns)) else list(GRAVITY_COLUMNS)


def _continuous_joints(p, q: dict) -> list[str]:
    """Joints of ``q`` (with a column) that turn without URDF limits (continuous, or revolute without limits)."""
    tree = getattr(getattr(p, "load", None), "tree", None)
    if tree is None:
        return []
    out = []
    for j in q:
        try:
            jt = tree.joint(j)
        except KeyError:
            continue
        if jt.type == "continuous" or (jt.type == "revolute" and (jt.lower is None or jt.upper is None or jt.upper <= jt.lower)):
            out.append(j)
    return out


def contact_frame(cal_legs: dict[str, PayloadCalibration | UrdfLoadCalibration], df: pd.DataFrame, where: str,
                  gravity_body=None) -> pd.DataFrame:
    """The output table: ``t``, per transducer ``{X}_fx..tz`` (contact wrench, ft frame about its origin) and
    ``{X}_fx_se..tz_se``. The recording is checked first (:func:`clean_rows`, :func:`check_against_calibration`:
    what a run checks that applies to a recording to correct); rows without gravity or with NaN readings are
    dropped (counted in the log). Without orientation columns, gravity is the fixed base's (``gravity_body``: the
    ``--gravity-body`` option, else the calibration's; :func:`base_gravity`)."""
    legs = list(cal_legs)
    clean, keep = clean_rows(cal_legs, df, where)
    base = base_gravity(cal_legs, clean, where, gravity_body)
    q: dict[str, np.ndarray] = {}
    for c in cal_legs.values():
        if isinstance(c, UrdfLoadCalibration):
            q.update(joint_angles(clean, c.joints, c.load.tree, where))
    faults = channel_faults(cal_legs, df, where)
    check_against_calibration(cal_legs, clean, where, base,
                              "--gravity-body" if gravity_body is not None else "the calibration's gravity_body",
                              {f.leg: f.rows[keep] for f in faults})
    R_WB = orientation_of_frame(clean)
    out: dict[str, np.ndarray] = {"t": clean["t"].to_numpy(float)}
    ses: dict[str, np.ndarray] = {}
    quat = None
    if R_WB is not None:
        quat = clean[list(QUAT_COLUMNS)].to_numpy(float)
        quat = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    for k in legs:
        p = cal_legs[k]
        g_B = gravity_of_frame(clean, p.g, where, base[k])
        temp = _temperature(df, k, keep, out["t"], where) if p.effects is not None else None
        wc, se = contact_wrench(p, clean[[f"{k}_{c}" for c in WRENCH_COMPONENTS]].to_numpy(float), g_B, q, R_WB,
                                t=out["t"], quat=quat, temperature=temp, where=where)
        for j, c in enumerate(WRENCH_COMPONENTS):
            out[f"{k}_{c}"] = wc[:, j]
            ses[f"{k}_{c}_se"] = se[:, j]
    return with_fault_columns(pd.DataFrame({**out, **ses}), faults, keep)


def channel_faults(cal_legs: dict, df: pd.DataFrame, where: str) -> list:
    """The stuck, dead or clipped channels of each transducer over the recording's rows (``checks.sensor_faults``,
    the hexapod's screen; a cell that is no number never repeats)."""
    from types import SimpleNamespace

    from .checks import sensor_faults

    wrench = {k: df[[f"{k}_{c}" for c in WRENCH_COMPONENTS]].apply(pd.to_numeric, errors="coerce").to_numpy(float)
              for k in cal_legs}
    return sensor_faults(SimpleNamespace(path=where, name=where, wrench=wrench), tuple(cal_legs))


def _temperature(df: pd.DataFrame, leg: str, keep: np.ndarray, t: np.ndarray, where: str) -> np.ndarray | None:
    """Transducer ``leg``'s temperature (rows ``keep``) from ``{leg}_temp_C`` or ``temp_C`` (``data.py``'s reading:
    gaps interpolated in t, units checked), or None without either column."""
    from .data import TEMP_COMMON, TEMP_SUFFIX, _temperatures

    cols = [c for c in (f"{leg}{TEMP_SUFFIX}", TEMP_COMMON) if c in df.columns]
    return _temperatures(df, cols, keep, t, [leg], where, Path(where)).get(leg) if cols else None


def payload_calibrations(cal_path: str | Path) -> dict[str, PayloadCalibration | UrdfLoadCalibration] | None:
    """The free-load calibrations of ``calibration.json`` (payloads and URDF loads; read and checked by
    :func:`ftcal_nlp.calibration.read_calibration_json`), or None when it is not a free-load calibration."""
    d = read_calibration_json(cal_path)
    return free_loads_from_dict(d, Path(cal_path)) if is_free_load(d) else None


def read_calibration(path: str | Path, **kw) -> "Calibration | dict[str, PayloadCalibration | UrdfLoadCalibration]":
    """The calibration in ``path`` for ``correct`` and ``export``, read and checked by
    :func:`ftcal_nlp.calibration.read_calibration_json`: a :class:`~ftcal_nlp.calibration.Calibration` (hexapod legs;
    ``kw`` as :meth:`~ftcal_nlp.calibration.Calibration.from_json_dict`), or for free loads the per-transducer
    calibrations of :func:`free_loads_from_dict` (a dict by transducer). Here, above both kinds, so that
    ``calibration.py`` imports nothing of the free loads."""
    d = read_calibration_json(path)
    if is_free_load(d):
        return free_loads_from_dict(d, Path(path))
    return Calibration.from_checked_dict(d, path, **kw)


def free_loads_from_dict(d: dict, cal_path: Path) -> dict[str, PayloadCalibration | UrdfLoadCalibration]:
    """The per-transducer free-load calibrations of a calibration dict read and checked from ``cal_path``
    (:func:`read_calibration`)."""
    legs = d["legs"]
    cc = _covariance_file(cal_path, d.get("meta", {}))
    g = float(d.get("g", 9.81))
    out: dict[str, PayloadCalibration | UrdfLoadCalibration] = {}
    for k, l in legs.items():
        if l.get("load_kind") == "urdf_subtree":
            out[k] = urdf_from_json(l, k, g, cal_path, cc)
            x_names = param_names(k, out[k].load.param_names, out[k].tilt is not None)
        elif l.get("link") is not None:   # a payload oriented by the joints (an arm whose URDF leaves the tool out)
            out[k] = arm_payload_from_json(l, k, g, cal_path, cc)
            x_names = param_names(k, out[k].load.param_names, out[k].tilt is not None)
        else:
            x_names = payload_param_names(k, "gravity_tilt_rad" in l)
            block = None if cc is None else cc.block(x_names)
            out[k] = payload_from_json(l, k, g, str(cal_path), block)
        out[k] = _with_effects(out[k], d.get("meta", {}), l, x_names, cc, str(cal_path))
    _check_effect_legs(d.get("meta", {}), out, str(cal_path))
    diag = [k for k, c in out.items() if not c.full_cov]
    if diag:
        log.info("%s: se of %s from the stored standard errors (correlations between parameters not stored: left out)",
                 cal_path, diag)
    if len(diag) < len(out):
        log.info("%s: se of %s from the full covariance of %s", cal_path, [k for k in out if k not in diag],
                 d["meta"]["covariance_file"])
    return out


def _with_effects(p, meta: dict, entry: dict, x_names: list[str], cc, where: str):
    """``p`` with the named effects of ``meta.effect`` for its transducer (``calibration_with_effect.json`` of a
    free-load run, ``freeload/effects_correction.py``) and their joint covariance; ``p`` itself without any."""
    from dataclasses import replace

    from .freeload.effects_correction import free_effects_of, with_covariance

    fx = free_effects_of(meta, p.leg, where, entry)
    if fx is None:
        return p
    und = np.zeros(len(x_names), bool) if p.undetermined is None else np.asarray(p.undetermined, bool)
    return replace(p, effects=with_covariance(fx, p.cov, und, x_names, cc if p.full_cov else None))


def _check_effect_legs(meta: dict, cal_legs: dict, where: str) -> None:
    """Every transducer ``meta.effect.legs`` names is one of the calibration's."""
    eff = meta.get("effect") if isinstance(meta, dict) else None
    legs = eff.get("legs") if isinstance(eff, dict) and eff.get("kind") == "free_load" else None
    bad = [k for k in (legs or {}) if k not in cal_legs]
    if bad:
        raise DataFormatError(f"{where}: meta.effect.legs names {bad}, not transducers of the calibration {list(cal_legs)}",
                              path=where, column="meta.effect.legs")


def _covariance_file(cal_path: Path, meta: dict):
    """The run's covariance file named in ``meta.covariance_file`` (beside ``calibration.json``), or None when
    the calibration names none or it is not there (then the stored se serve, logged by the caller)."""
    from .uncertainty import CalibrationCovariance

    name = meta.get("covariance_file") if isinstance(meta, dict) else None
    if not name:
        return None
    path = cal_path.parent / str(name)
    if not path.is_file():
        log.warning("%s: meta.covariance_file = %r is not there (%s)", cal_path, name, path)
        return None
    return CalibrationCovariance.load(path)


def correct_free_load_file(cal: dict, args: argparse.Namespace, out: Path) -> int:
    """The ``correct`` command (``correct.py`` parses the line) for a free-load calibration ``cal``
    (:func:`payload_calibrations`): the contact wrench of each wrist transducer, written to ``out``."""
    from .csvout import write_csv

    for opt, name in ((args.bag, "--bag"), (args.track_offsets, "--track-offsets")):
        if opt:
            raise ConfigError(f"{name} applies to hexapod calibrations; {args.calibration} holds free loads", key=name)
    df = contact_frame(cal, read_table(Path(args.recording)), str(args.recording), getattr(args, "gravity_body", None))
    out.parent.mkdir(parents=True, exist_ok=True)
    write_csv(df, out)  # t and every value to the last bit (csvout.py)
    log.info("wrote %s (%d rows): contact wrench of %s in their ft frames", out, len(df), list(cal))
    return 0
