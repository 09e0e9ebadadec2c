"""A calibrated load as ``correct`` and ``export`` read it back from ``calibration.json``: the one reader
(:func:`read_calibration`) and the per-transducer models of free loads (``DATA_FORMAT.md`` section 5, issue 22).

:func:`read_calibration` reads and checks the file with :func:`ftcal_nlp.core.calibration.read_calibration_json` (the one
reader of ``calibration.json``: finite numbers, proper rotations, one mounting rotation, a positive load mass) and
gives a :class:`~ftcal_nlp.core.calibration.Calibration` (hexapod legs, the ``leg_com_curve`` load) or, per transducer
carrying a free load (``load_kind`` ``"rigid_payload"`` or ``"urdf_subtree"``), a :class:`PayloadCalibration` or a
:class:`UrdfLoadCalibration`. Here, beside the load plug-ins, so that ``calibration.py`` imports nothing of the free
loads. Each model predicts ``w_o + w_load`` and its derivative (:meth:`predict`, what ``correct`` subtracts), gives
the pose an effect's face needs (:meth:`face_pose`) and writes its load wrench symbolically (:meth:`symbolic_load`,
what ``export`` compiles).

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

A ``calibration_with_effect.json`` of a free-load run (``meta.effect.kind = "free_load"``) names effects per
transducer: each model carries them (``effects``, :class:`~ftcal_nlp.effects.correction.FreeEffects`) with their
parameters' joint covariance; ``correct`` corrects the readings for them first (``effects/correction.py``: what the
file holds, the correction, what the se leave out).

A transducer's ``sensor_matrix`` (``C``, refitted in situ: ``estimate/freeload/sensor_matrix.py``) is carried as
``sensor_matrix`` (None without one or for the identity); ``correct`` and ``export`` map the readings less the offset
through it. A stored se of null (the writer's inf: a parameter the data leave undetermined, e.g. ``load_mass_se_kg``
of a force matrix fitted without ``load_mass_kg``) is read as inf: the outputs that depend on it get se inf, and the
log says so.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.calibration import Calibration, is_free_load, read_calibration_json
from ..core.data import WRENCH_COMPONENTS
from ..core.errors import DataFormatError
from ..core.geometry import skew
from ..loads.base import joint_limits
from ..loads.rigid_payload import RigidPayload
from ..loads.urdf_subtree import UrdfSubtree

if TYPE_CHECKING:
    from ..effects.correction import FreeEffects

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
    effects: FreeEffects | None = None   # the named effects (effects.correction); None: none
    gravity_body: np.ndarray | None = None   # the fixed base's gravity direction at calibration (unit, B); None: not kept
    sensor_matrix: np.ndarray | None = None   # C (6, 6) of the in-situ matrix (module docstring); None: the factory's

    joints: tuple[str, ...] = ()

    def predict(self, g_B: np.ndarray, q: dict[str, np.ndarray], R_WB: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``w_o + w_load`` (N, 6) and its derivative (N, 6, 13 [+ 2]) (:func:`predicted_load`; ``q`` unused)."""
        g_B, dg = tilted_gravity(self, g_B, R_WB)
        return predicted_load(self, g_B, dg)

    def face_pose(self, q: dict[str, np.ndarray], n: int, mount: np.ndarray) -> tuple:
        """``(load, theta, joint limits, R_B,ft (n, 3, 3), E)`` for an effect's face on ``n`` samples
        (``effects.correction.context``): the payload as a :class:`~ftcal_nlp.loads.RigidPayload` on its nominal
        rotation ``R_B,ft mount^T`` (``mount`` = ``E``, the calibration's mounting rotation), no joints."""
        return (RigidPayload(self.R_B_ft @ mount.T), np.r_[self.mass_kg, self.h], {},
                np.broadcast_to(self.R_B_ft, (n, 3, 3)), mount)

    def symbolic_load(self, q: dict) -> tuple:
        """``(R_B,ft, s, M)`` as CasADi constants: the ft orientation in B, the first moment ``h`` and the mass, for
        ``export``'s ``w_load = [M g_ft ; s x g_ft]`` (``q`` unused)."""
        import casadi as ca

        return ca.DM(self.R_B_ft), ca.DM(self.h), float(self.mass_kg)

    def describe(self) -> str:
        return "rigid payload"

    @property
    def tree(self):
        """No URDF (the payload's orientation is the calibration's, constant)."""
        return None


@dataclass(frozen=True)
class UrdfLoadCalibration:
    """One transducer's calibrated URDF load: ``load`` the :class:`~ftcal_nlp.loads.UrdfSubtree` (from the URDF),
    ``offset`` (6,), ``theta`` (p,) ``[M_G, H_G]`` per group, ``E`` (3, 3) the mounting rotation (true ft relative
    to the URDF's), ``cov`` (6 + p + 3)^2 over ``(w_o, theta, delta)``, ``sigma``, ``g``, ``full_cov``,
    ``undetermined``, ``null`` as :class:`PayloadCalibration`."""

    leg: str
    load: UrdfSubtree | RigidPayload   # a RigidPayload built on the URDF: the same poses, lever and mass row
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
    effects: FreeEffects | None = None   # the named effects (effects.correction); None: none
    gravity_body: np.ndarray | None = None   # the fixed base's gravity direction at calibration (unit, B); None: not kept
    sensor_matrix: np.ndarray | None = None   # C (6, 6) of the in-situ matrix (module docstring); None: the factory's

    @property
    def joints(self) -> tuple[str, ...]:
        return tuple(self.load.base_joints) + tuple(self.load.load_joints)

    def face_pose(self, q: dict[str, np.ndarray], n: int, mount: np.ndarray) -> tuple:
        """``(load, theta, joint limits, R_B,ft (n, 3, 3), E)`` for an effect's face on ``n`` samples: the sensor's
        pose moves with the joints ``q`` (``mount`` unused: the calibration's own ``E``)."""
        return self.load, self.theta, joint_limits(self.load), self.load.nominal_rotation(q, n) @ self.E, self.E

    def symbolic_load(self, q: dict) -> tuple:
        """``(R_B,ft(q), s(q), M)`` for joint angles ``q`` (CasADi symbols by joint): ``R_nom(q) E`` from the URDF
        (``loads.urdf_subtree.symbolic_pose``), the load's first moment (its ``symbolic_lever``) and its mass, for
        ``export``'s ``w_load = [M g_ft ; s x g_ft]``."""
        import casadi as ca

        from ..loads.urdf_subtree import symbolic_pose

        load = self.load
        if load.ft_link is None:   # a RigidPayload built without its URDF: not a URDF load (read_calibration builds it with one)
            raise ValueError(f"transducer {self.leg}: the load has no sensor link in a URDF; expected a URDF load")
        R_nom, _ = symbolic_pose(load.tree, load.tree.root, load.ft_link, q)
        R = ca.mtimes(R_nom, ca.DM(self.E))
        return R, load.symbolic_lever(self.theta, q), float(load.mass_row @ self.theta)

    def describe(self) -> str:
        return self.load.description()

    @property
    def tree(self):
        """The URDF the load's joints are read against."""
        return self.load.tree

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
    from ..estimate.freeload.problem import tilt_derivative, tilt_gravity

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
        m_se, c_se = float(se_of(d["load_mass_se_kg"])), se_of(d["load_com_se_m"])
        tilt, var_t = _tilt_of(d)
        with np.errstate(invalid="ignore"):   # 0 * inf: a CoM component at 0 of an undetermined mass is undetermined too
            var_h = np.where(np.isfinite(c_se) & np.isfinite(m_se), m**2 * c_se**2 + c**2 * m_se**2, np.inf)
        var = np.concatenate([se_of(d["offset_se"]) ** 2, [m_se**2], var_h, var_t, se_of(d["mount_rotvec_se"]) ** 2])
        R = np.asarray(d["rotation_to_body"], float)
        sigma = np.asarray(d.get("noise_sd", d.get("residual_rms")), float)
        off = np.asarray(d["offset"], float)
    except KeyError as exc:
        raise DataFormatError(f"{where}: transducer {leg}: missing key {exc.args[0]!r} of a payload calibration", path=where,
                              column=str(exc.args[0])) from None
    gb = _base_gravity(d)
    Cm = matrix_of_entry(d, leg, where)
    _say_undetermined_mass(m_se, leg, where)
    if cov is not None:
        C, und, null = cov
        return PayloadCalibration(leg, off, m, m * c, R, np.where(np.isfinite(C), C, 0.0), sigma, g, full_cov=True,
                                  undetermined=np.asarray(und, bool), null=null, tilt=tilt, gravity_body=gb,
                                  sensor_matrix=Cm)
    return PayloadCalibration(leg, off, m, m * c, R, np.diag(np.where(np.isfinite(var), var, 0.0)), sigma, g, full_cov=False,
                              undetermined=np.isinf(var), tilt=tilt, gravity_body=gb, sensor_matrix=Cm)


def se_of(v) -> np.ndarray:
    """Standard errors as stored (a number, a list, null): null, the writer's word for a parameter the data leave
    undetermined (``OUTPUT_FORMAT.md``: inf is written null), read back as inf."""
    if v is None:
        return np.asarray(np.inf)
    if isinstance(v, (list, tuple)):
        return np.asarray([np.inf if x is None else x for x in v], float)
    return np.asarray(v, float)


def _say_undetermined_mass(m_se: float, leg: str, where: str) -> None:
    """The log's word for a load mass the calibration left undetermined (``load_mass_se_kg`` null: a sensor matrix
    fitted with its force gain free and no ``load_mass_kg`` weighed): the forces' se are inf."""
    if not np.isfinite(m_se):
        log.warning("%s: transducer %s: load_mass_se_kg is null: the load's mass is not determined by the calibration's data "
                    "(a force gain of the sensor matrix and the mass trade; give load_mass_kg to fix it): contact forces "
                    "that depend on it have se inf", where, leg)


def matrix_of_entry(d: dict, leg: str, where: str) -> np.ndarray | None:
    """``C`` (6, 6) of a transducer's entry (``sensor_matrix``; ``estimate/freeload/sensor_matrix.py``): None for no
    matrix and for the identity (the factory matrix kept: ``correct`` and ``export`` then run the very code they run
    without one). Its se (``sensor_matrix_se``) are not read: ``correct/free.py`` says why they are not propagated."""
    from ..estimate.freeload.sensor_matrix import sensor_matrix_of

    try:
        C = sensor_matrix_of(d)
    except ValueError as exc:
        raise DataFormatError(f"{where}: transducer {leg}: {exc}", path=where, column=f"legs.{leg}.sensor_matrix") from None
    if C is None or np.array_equal(C, np.eye(6)):
        return None
    return C


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
    of its name beside ``calibration.json`` when that path is gone), its groups checked against the stored ones. ``cc``: the run's :class:`~ftcal_nlp.estimate.uncertainty.CalibrationCovariance`
    (its block of this transducer); None, or the transducer not in it: the diagonal of the stored se."""
    where = str(cal_path)
    try:
        urdf, link, groups = str(d["urdf"]), str(d["link"]), d["urdf_groups"]
        off = np.asarray(d["offset"], float)
        E = np.asarray(d.get("mount_rotation", np.eye(3)), float)
        sigma = np.asarray(d.get("noise_sd", d.get("residual_rms")), float)
        var_tail = se_of(d["mount_rotvec_se"]) ** 2
        var_off = se_of(d["offset_se"]) ** 2
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
    Cm = matrix_of_entry(d, leg, where)
    if cov is not None:
        C, und, null = cov
        return UrdfLoadCalibration(leg, load, off, theta, E, np.where(np.isfinite(C), C, 0.0), sigma, g, True,
                                   np.asarray(und, bool), null, tilt, gravity_body=_base_gravity(d), sensor_matrix=Cm)
    var_th = np.concatenate([se_of([groups[n]["mass_se_kg"], *groups[n]["first_moment_se_kgm"]]) for n in names]) ** 2
    var = np.concatenate([var_off, var_th, var_t, var_tail])
    return UrdfLoadCalibration(leg, load, off, theta, E, np.diag(np.where(np.isfinite(var), var, 0.0)), sigma, g, False,
                               np.isinf(var), None, tilt, gravity_body=_base_gravity(d), sensor_matrix=Cm)


def _urdf_tree(urdf: str, leg: str, cal_path: Path):
    """``(path, KinematicTree)`` of a leg entry's ``urdf`` (relative to ``calibration.json``'s folder, or absolute; a
    file of its name beside ``calibration.json`` when that path is gone)."""
    from ..core.data import read_urdf_tree

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
    from ..core.calibration import ROTATION_TOL, urdf_rotation_at_zero

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
                                   np.asarray(und, bool), null, base.tilt, gravity_body=base.gravity_body,
                                   sensor_matrix=base.sensor_matrix)
    return UrdfLoadCalibration(leg, load, base.offset, theta, E, base.cov, base.sigma, g, False, base.undetermined, None,
                               base.tilt, gravity_body=base.gravity_body, sensor_matrix=base.sensor_matrix)



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



def payload_calibrations(cal_path: str | Path) -> dict[str, PayloadCalibration | UrdfLoadCalibration] | None:
    """The free-load calibrations of ``calibration.json`` (payloads and URDF loads; read and checked by
    :func:`ftcal_nlp.core.calibration.read_calibration_json`), or None when it is not a free-load calibration."""
    d = read_calibration_json(cal_path)
    return free_loads_from_dict(d, Path(cal_path)) if is_free_load(d) else None


def read_calibration(path: str | Path, **kw) -> "Calibration | dict[str, PayloadCalibration | UrdfLoadCalibration]":
    """The calibration in ``path`` for ``correct`` and ``export``, read and checked by
    :func:`ftcal_nlp.core.calibration.read_calibration_json`: a :class:`~ftcal_nlp.core.calibration.Calibration` (hexapod legs;
    ``kw`` as :meth:`~ftcal_nlp.core.calibration.Calibration.from_json_dict`), or for free loads the per-transducer
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
        if l.get("load_kind") == "urdf_subtree" or l.get("link") is not None:
            # a URDF load, or a payload oriented by the joints (an arm whose URDF leaves the tool out)
            u = urdf_from_json(l, k, g, cal_path, cc) if l.get("load_kind") == "urdf_subtree" else arm_payload_from_json(l, k, g, cal_path, cc)
            out[k] = u
            x_names = param_names(k, u.load.param_names, u.tilt is not None)
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
    free-load run, ``effects/correction.py``) and their joint covariance; ``p`` itself without any."""
    from dataclasses import replace

    from ..effects.correction import free_effects_of, with_covariance

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
    from ..estimate.uncertainty import CalibrationCovariance

    name = meta.get("covariance_file") if isinstance(meta, dict) else None
    if not name:
        return None
    path = cal_path.parent / str(name)
    if not path.is_file():
        log.warning("%s: meta.covariance_file = %r is not there (%s)", cal_path, name, path)
        return None
    return CalibrationCovariance.load(path)
