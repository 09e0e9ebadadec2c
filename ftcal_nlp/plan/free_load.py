"""The free loads' plan (``DATA_FORMAT.md`` section 5): the standard error each load parameter will have (``plan``'s
free-load part).

Three ways in (``plan/reading.py`` tells them apart; ``plan --help`` shows them):

* ``plan DATASET.toml``: a recorded pilot (a section-5 manifest);
* ``plan ROBOT.toml --protocol HOLDS.toml``: a section-5 ``robot.toml`` (as the run reads it: rigid payloads, URDF
  loads with ``urdf`` and ``[transducers.X] link``, arms) and a protocol of holds;
* ``plan HOLDS.toml`` whose ``[protocol]`` names ``robot = "robot.toml"`` (relative to it): the same. (A
  ``[protocol] kind = "payload"`` without a robot keeps ``rotation_rpy`` for the nominal rotation.)

A robot.toml alone is an error that says what to add: the robot fixes what the loads are, the holds what the
session shows them, and neither guesses the other. The robot.toml is read by the run's reader (``data.read_robot``),
so a robot.toml the run refuses, ``plan`` refuses with the same words.

The prediction is the Cramer-Rao bound of :mod:`ftcal_nlp.crb.free_load` (its own reading model, independent of
the estimator): per quasi-static sample ``i`` the readings' derivative ``J_i`` with respect to the offsets, the
load's parameters, the world tilt of the orientation stream (where the estimator fits it) and the mounting
rotation, and

    F = sum_i J_i^T Sigma^-1 J_i,     se >= sqrt(diag F^+)   (on the directions F determines),

``Sigma = diag(s^2)`` per channel (plus the orientation jitter's errors in variables, ``crb.free_load``). Directions of
``F`` below ``solver.REL_EIG_TOL`` of the largest are not determined: their parameters get se ``null`` in
``plan.json`` and one line each names what cannot be separated from what (``crb.describe_dropped``), e.g. a
CoM component along an axis gravity never turns about, a link group whose joint never moves.

Noise, and the run's widening. The run weighs channel ``c`` by ``1 / (s_c^2 k_c)``, ``k_c`` the AR(1) variance
inflation of its residuals (``freeload.problem.serial_inflation``: a residual that stays through a hold carries
less than white noise; x8.7 in se on a real wrist time series). From a pilot, ``s`` is the pilot fit's residual sd
and ``k`` is computed by that same function on the pilot fit's residuals (:func:`pilot_widening`), so the plan's
se are the run's on those motions; ``plan.json`` gives ``serial_widening`` (``sqrt k``) and ``lag1_correlation``
and the text says so. A protocol of holds has no residuals: white noise at the stated sd (each hold of ``n``
samples counts ``n`` times, se fall as ``1/sqrt(hold_s * rate_hz)``), and the text says that too.

Inputs:

* a pilot: each free load is calibrated first (``fit_free_load``) and the bound evaluated at its estimate (a
  payload's mass and CoM; a URDF load's group masses and first moments), on the quasi-static samples that fit used;
  a world tilt, or the tilt of its one ``gravity_body`` recording, where the fit estimates it.
* ``[protocol]`` with a robot: ``transducer`` (default every transducer of the robot.toml), the holds as one of
  ``orientations`` (``[qw, qx, qy, qz]`` of B in W, each a hold), ``n_orientations`` (uniform on SO(3), ``seed``) or
  ``holds = [{quat = [qw, qx, qy, qz], q = {joint = rad, ...}}, ...]`` (joints a hold does not name at 0, as the
  run takes a missing ``q_{joint}`` column; without ``quat`` gravity is ``gravity_body``, e.g. ``[0, 0, -1]`` for an
  arm's fixed level base), ``hold_s``, ``rate_hz``, ``noise_force_N``, ``noise_torque_Nm``, ``mocap_jitter_deg``,
  ``mass_kg`` / ``com_m`` (a rigid payload's expected mass and CoM in ft, where the bound is evaluated; default
  1 kg, (0, 0, 0.05) m, named in a note), ``mount``, ``gravity_tilt`` (estimated, as the run's defaults), ``g``
  (default the robot's), ``kind`` (optional; must agree with the robot.toml). The load of a transducer is what the
  run makes of it: no ``link``, a rigid payload at the table's ``rotation``; a ``link`` with massive links below,
  the URDF's bodies; a ``link`` with none below (an arm whose URDF leaves the tool out), a rigid payload whose
  gravity comes through the joint angles. A world tilt is bounded over the holds with ``quat`` (the run tilts the
  orientation stream only); holds that are all ``gravity_body`` have that recording's tilt bounded where the bound
  determines it (else held at 0, as the run's ``recording_tilt = "auto"``); mixed with ``quat`` holds it is taken
  as known (a note says so).

Temperature (:mod:`.temperature`): a pilot whose recordings carry the transducer's temperature (``{X}_temp_C`` /
``temp_C``), or a protocol with ``temperature_range_C``, adds per transducer the se of the temperature coefficients
and the range a session needs for ``--temperature-target`` (``temperature`` in ``plan.json``, two lines of text).

``--search`` and ``--detect`` plan hexapod sessions (the detection sizes of the hexapod diagnosis); with a
free load they are an error naming why.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path

import numpy as np

from .. import crb
from ..core.geometry import quat_to_rotation, rotation_to_rotvec, rotvec_to_rotation
from .reading import PlanError, PlanInput
from .temperature import TemperaturePlan, pilot_temperature, protocol_temperature

log = logging.getLogger(__name__)

PROTOCOL_KINDS = ("payload", "urdf")


@dataclass(frozen=True)
class LoadPlan:
    """One transducer's predicted se: ``bound`` (``crb.LoadBound``), ``kind``, ``n_samples``, ``n_holds``
    (None for a dataset), ``noise`` (6,) the per-sample sd, ``undetermined`` (names of parameters in a dropped
    direction), ``widening`` (6,) the run's se factor for serially correlated residuals already in ``bound``
    (a pilot's; None: white noise assumed) and ``lag1`` the correlation it comes from."""

    transducer: str
    kind: str
    bound: crb.LoadBound
    n_samples: int
    noise: np.ndarray
    n_holds: int | None = None
    undetermined: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    widening: np.ndarray | None = None      # (6,) se factor per channel for serially correlated residuals (pilot)
    lag1: np.ndarray | None = None          # (6,) the pilot residuals' lag-1 correlation behind it
    temperature: TemperaturePlan | None = None   # the temperature coefficients' se and the range needed (plan/temperature.py)

    def se(self) -> dict[str, float | None]:
        """Predicted se per parameter (SI; mount: rad), None where undetermined."""
        return {n: (None if n in self.undetermined else float(s)) for n, s in self.bound.se.items()}

    def sd_of(self, weights: dict[str, float], tol: float = 1e-3) -> float | None:
        """Predicted se of ``sum_n weights[n] theta_n`` (a URDF load's total mass), None when it changes along a
        direction the protocol does not determine."""
        a = np.zeros(len(self.bound.names))
        for n, w in weights.items():
            a[self.bound.names.index(n)] = w
        N = crb.dropped_directions(self.bound.bound)
        if N.shape[1]:
            a_s = a / self.bound.bound.scale                      # d(a . theta) along a scaled direction u: a_s . u
            if np.abs(a_s @ N).max() > tol * np.linalg.norm(a_s):
                return None
        return self.bound.sd_of(weights)

    def groups(self) -> dict[str, tuple[float | None, str]]:
        """RMS over a group's parameters of the predicted se, in the group's unit (None: undetermined in it)."""
        se = self.se()

        def rms(names, factor=1.0):
            v = [se[n] for n in names if n in se]
            return None if not v or any(x is None for x in v) else float(factor * np.sqrt(np.mean(np.square(v))))

        out = {"offsets_force": (rms(crb.OFFSET_NAMES[:3]), "N"), "offsets_torque": (rms(crb.OFFSET_NAMES[3:]), "N*m")}
        mass_names = [n for n in self.bound.names if n.endswith("mass_kg")]
        total = None if not mass_names else self.sd_of({n: 1.0 for n in mass_names})
        out["load_mass"] = (total, "kg")
        if self.kind == "rigid_payload":
            out["load_com"] = (rms(("com_x", "com_y", "com_z"), 1e3), "mm")
        else:
            for n in mass_names:
                grp = n[: -len(".mass_kg")]
                out[f"{grp}.mass"] = (rms((n,)), "kg")
                out[f"{grp}.first_moment"] = (rms(tuple(f"{grp}.moment_{c}" for c in "xyz"), 1e3), "kg*mm")
        if "tilt_rx" in self.bound.names:
            out["gravity_tilt"] = (rms(crb.TILT_NAMES, float(np.degrees(1.0))), "deg")
        if "mount_rx" in self.bound.names:
            out["mount_rotation"] = (rms(crb.ROT_NAMES, float(np.degrees(1.0))), "deg")
        return out

    def to_json_dict(self) -> dict:
        return {"load_kind": self.kind, "samples": self.n_samples, "holds": self.n_holds, "noise_sd": self.noise.tolist(),
                "serial_widening": None if self.widening is None else self.widening.tolist(),
                "lag1_correlation": None if self.lag1 is None else self.lag1.tolist(),
                "groups": {k: {"se": v, "unit": u} for k, (v, u) in self.groups().items()},
                "se": self.se(), "undetermined": list(self.bound.unidentified), "notes": list(self.notes),
                "temperature": None if self.temperature is None else self.temperature.to_json_dict()}

    def widening_text(self) -> str:
        """One line on the serial-correlation widening the se carry (or that they assume white noise)."""
        if self.widening is None:
            return ("white noise assumed (no pilot): the run widens se where residuals stay correlated through a hold; "
                    "plan a pilot dataset to carry that")
        w = np.array2string(self.widening, precision=2)
        r = "n/a" if self.lag1 is None else np.array2string(self.lag1, precision=2)  # _plan gives both or neither
        return (f"se widened as the run widens them for serially correlated residuals: x{w} in fx..tz (the pilot fit's "
                f"residuals, lag-1 correlation {r}; freeload.problem.serial_inflation)")


@dataclass(frozen=True)
class FreeLoadPlan:
    """Every transducer's :class:`LoadPlan`, and where they come from (``source``: protocol or pilot dataset)."""

    source: str
    loads: dict[str, LoadPlan]
    protocol: dict = field(default_factory=dict)

    def to_json_dict(self) -> dict:
        return {"kind": "free_load", "source": self.source, "protocol": self.protocol,
                "transducers": {k: p.to_json_dict() for k, p in self.loads.items()}}

    def text(self) -> str:
        lines = [f"free-load plan ({self.source}): predicted se (Cramer-Rao bound)"]
        for k, p in self.loads.items():
            holds = f", {p.n_holds} holds" if p.n_holds is not None else ""
            lines.append(f"{k} ({p.kind}, {p.n_samples} quasi-static samples{holds}):")
            for g, (v, u) in p.groups().items():
                lines.append(f"  {g:<28s} {'not determined' if v is None else f'{v:.3g}'} {'' if v is None else u}")
            lines += [f"  not determined: {n}" for n in p.bound.unidentified]
            lines.append(f"  noise: {p.widening_text()}")
            lines += [] if p.temperature is None else p.temperature.text()
            lines += [f"  note: {n}" for n in p.notes]
        return "\n".join(lines)


def _undetermined(bound: crb.LoadBound, tol: float = 1e-3) -> tuple[str, ...]:
    """Parameters with a component (scaled coordinates, relative size over ``tol``) in a dropped direction."""
    N = crb.dropped_directions(bound.bound)
    if N.shape[1] == 0:
        return ()
    touched = np.abs(N).max(axis=1) > tol
    return tuple(n for n, t in zip(bound.names, touched) if t)


def _plan(leg: str, kind: str, bound: crb.LoadBound, n: int, noise: np.ndarray, holds: int | None,
          notes: tuple[str, ...] = (), serial: tuple[np.ndarray, np.ndarray] | None = None) -> LoadPlan:
    und = _undetermined(bound)
    for line in bound.unidentified:
        log.warning("%s: not determined by this protocol: %s", leg, line)
    lag1, widening = (None, None) if serial is None else serial
    return LoadPlan(leg, kind, bound, n, np.asarray(noise, float), holds, und, notes, widening, lag1)


def pilot_widening(ds, leg: str, fit) -> tuple[np.ndarray, np.ndarray]:
    """``(rho, factor)`` (6,) each: the lag-1 correlation of the pilot fit's residuals and the se factor the run
    applies for it (``sqrt`` of ``freeload.problem.serial_inflation``, the estimator's own function, on the same
    residuals: the samples the fit used, numbered by recording and row as the estimator numbers them)."""
    from ..estimate.freeload.problem import serial_inflation

    res, src, idx = [], [], []
    for i, rec in enumerate(r for r in ds.hanging if r.hangs_free(leg)):
        m = fit.used.get(rec.name)
        if m is None or not m.any():
            continue
        res.append(rec.wrench[leg][m] - fit.predict_recording(rec, ds.robot.g)[m])
        src.append(np.full(int(m.sum()), i))
        idx.append(np.flatnonzero(m))
    rho, inflation = serial_inflation(np.concatenate(res), np.concatenate(src), np.concatenate(idx))
    return rho, np.sqrt(inflation)


# ----------------------------------------------------------------------------- a pilot dataset


def plan_from_dataset(ds, settings=None, temperature_target: float | None = None) -> FreeLoadPlan:
    """The plan of a section-5 dataset's free loads (module docstring): each fitted, the bound at its estimate on
    the samples the fit used with the noise it measured; where the pilot carries a temperature, the temperature
    coefficients' se and the range needed for ``temperature_target`` (N/degC; ``plan/temperature.py``)."""
    from ..estimate.freeload import fit_free_load
    from ..core.checks import screen_sensor_faults
    from ..core.errors import SolverError
    from ..pipeline import check_free_load_fits, checked_free_load_samples, raise_free_load_causes

    # the run's checks before and after the fit: a pilot a run refuses is no ground for a plan
    ds, _ = screen_sensor_faults(ds, unit="transducer", every_recording_fatal=False)
    samples = checked_free_load_samples(ds, settings)
    loads, fits = {}, {}
    for leg in ds.free_load_legs:
        try:
            fits[leg] = fit_free_load(ds, leg, settings)
        except SolverError as exc:   # as the run: the causes whose refit makes the load plausible, if any
            raise_free_load_causes(ds, {leg: samples[leg]}, exc)
            raise
    check_free_load_fits(ds, fits, samples)
    for leg in ds.free_load_legs:
        fit = fits[leg]
        recs = [r for r in ds.hanging if r.name in fit.used]
        # the run weighs each channel by 1 / (sd^2 inflation): the bound at the same weights is the run's se
        serial = pilot_widening(ds, leg, fit)
        sigma = fit.sigma * serial[1]
        g_B = np.concatenate([ds.robot.g * r.gravity_directions()[fit.used[r.name]] for r in recs])
        mount = bool(np.all(np.isfinite(fit.se[-3:]) | np.isinf(fit.se[-3:])))   # NaN: the mount was not estimated
        rv = rotation_to_rotvec(fit.rotation)
        dB: np.ndarray | None = None
        notes: tuple[str, ...] = ()
        if fit.tilt is not None and not np.all(np.isfinite(fit.se[6 + len(fit.theta):8 + len(fit.theta)])):
            notes = (TILT_HELD,)
        elif fit.tilt is not None:   # the fit's world tilt: gravity through the stream's orientations, tilted
            from ..estimate.freeload.problem import tilt_gravity

            gs, dBs = [], []
            for r in recs:   # the tilt acts through the orientation stream's recordings only
                m = fit.used[r.name]
                if r.quat is None:
                    gs.append(ds.robot.g * r.gravity_directions()[m])
                    dBs.append(np.zeros((int(m.sum()), 3, 2)))
                    continue
                R_WB = quat_to_rotation(r.quat[m])
                gs.append(ds.robot.g * np.einsum("nkj,k->nj", R_WB, tilt_gravity(fit.tilt)))
                dBs.append(crb.tilt_directions(R_WB, ds.robot.g))
            g_B, dB = np.concatenate(gs), np.concatenate(dBs)
        elif len(fit.recording_tilts) == 1:   # one gravity_body recording's tilt (the bound has one tilt block)
            g_B, dB = _recording_tilt(ds, recs, fit)
            notes = ((f"gravity_tilt: the tilt of gravity_body recording {next(iter(fit.recording_tilts))!r} (the run's "
                      "recording_tilt_rad), estimated by the run and bounded here"),)
        if fit.load.kind == "rigid_payload":   # oriented by its rotation, or by the joints (an arm's tool)
            q = {j: np.concatenate([r.q[j][fit.used[r.name]] if j in r.q else np.zeros(int(fit.used[r.name].sum()))
                                    for r in recs]) for j in fit.load.base_joints}
            R = fit.load.nominal_rotation(q, len(g_B)) @ fit.rotation
            g_ft = np.einsum("nji,nj->ni", R, g_B)
            mass = float(fit.theta[0])
            bound = crb.payload_bound(g_ft, mass, fit.theta[1:4] / mass, sigma, mount=mount, offset=fit.offset,
                                            tilt_dirs=None if dB is None else np.einsum("nji,njt->nit", R, dB))
        else:
            tree, link = ds.robot.tree, ds.robot.transducers[leg].link
            joints = tuple(fit.load.base_joints) + tuple(fit.load.load_joints)
            q = {j: np.concatenate([r.q[j][fit.used[r.name]] if j in r.q else np.zeros(int(fit.used[r.name].sum()))
                                    for r in recs]) for j in joints}
            g_ft = crb.urdf_gravity_in_ft(tree, link, q, g_B, rv)
            dg = None if dB is None else np.stack([crb.urdf_gravity_in_ft(tree, link, q, dB[:, :, k], rv)
                                                   for k in range(2)], axis=2)
            bodies = {l: (b.mass_kg, b.com_m) for l, b in tree.bodies.items()}
            # at the fit's groups (mass and first moment): the mount's rows scale with them, as the run's se do
            same = [set(g.links) for g in crb.joint_groups(tree, link)] == [set(g.links) for g in fit.load.groups]
            bound = crb.urdf_bound(tree, link, q, g_ft, bodies, sigma, mount=mount, offset=fit.offset,
                                         tilt_dirs=dg, group_theta=fit.theta.reshape(-1, 4) if same else None)[0]
            if not same:
                notes += (("evaluated at the URDF's nominal bodies (the bound depends on them only through the mounting "
                           "rotation's rows)"),)
        if fit.recording_tilts and (fit.tilt is not None or len(fit.recording_tilts) > 1):
            # estimated by the fit, not in the bound: the bound is a little optimistic there
            notes += ((f"the tilts of the gravity_body recordings {list(fit.recording_tilts)} are estimated by the fit and "
                       "not in the bound (taken as known here)"),)
        loads[leg] = replace(_plan(leg, fit.load.kind, bound, len(g_B), fit.sigma, None, notes, serial),
                             temperature=pilot_temperature(ds, leg, fit, temperature_target))
    return FreeLoadPlan(f"pilot dataset {ds.manifest}", loads)


def _recording_tilt(ds, recs, fit) -> tuple[np.ndarray, np.ndarray]:
    """Gravity in B (N, 3) at the fit's tilt of its one ``gravity_body`` recording and ``d g_B / d tilt`` (N, 3, 2)
    (zero on the other recordings): that recording's gravity is ``g F u``, ``F`` the frame of its nominal direction
    (``freeload.problem.gravity_frame``), so it enters the bound as a world tilt does with ``R_WB = F^T``."""
    from ..estimate.freeload.problem import gravity_frame, tilt_gravity

    (name, tilt), = fit.recording_tilts.items()
    gs, dBs = [], []
    for r in recs:
        m = fit.used[r.name]
        n = int(m.sum())
        if r.name != name:
            gs.append(ds.robot.g * r.gravity_directions()[m])
            dBs.append(np.zeros((n, 3, 2)))
            continue
        F = gravity_frame(r.gravity_directions()[:1])[0]
        gs.append(np.broadcast_to(ds.robot.g * F @ tilt_gravity(tilt), (n, 3)))
        dBs.append(crb.tilt_directions(np.broadcast_to(F.T, (n, 3, 3)), ds.robot.g))
    return np.concatenate(gs), np.concatenate(dBs)


# ----------------------------------------------------------------------------- a protocol of held orientations


TILT_HELD = ("the world tilt of the orientation stream: held at 0 by the estimator (gravity spans fewer than three "
             "directions in ft, freeload.estimate): not in the bound")


def _tilt_held(g_ft: np.ndarray) -> bool:
    """Whether the estimator holds the world tilt at 0 for these gravity directions (one direction, a short arc)."""
    from ..estimate.freeload.estimate import NARROW, gravity_spread

    return bool(gravity_spread(g_ft)[1] < NARROW)


def _num(d: dict, key: str, default, where: str, positive: bool = True) -> float:
    v = d.get(key, default)
    if not isinstance(v, (int, float)) or isinstance(v, bool) or (positive and not v > 0) or (not positive and v < 0):
        raise PlanError(f"{where}: key '{key}' must be a {'positive' if positive else 'non-negative'} number, got {v!r}",
                        key=key)
    return float(v)


def _quats(v, where: str, key: str) -> np.ndarray:
    try:
        q = np.asarray(v, float).reshape(-1, 4)
    except (TypeError, ValueError):
        q = None
    if q is None or not len(q) or not np.all(np.isfinite(q)) or np.any(np.linalg.norm(q, axis=1) < 1e-9):
        raise PlanError(f"{where}: key '{key}' must be a list of [qw, qx, qy, qz] (nonzero), got {v!r}", key=key)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _session(d: dict, where: str, g_default: float) -> tuple[int, np.ndarray, float, float, bool, bool]:
    """The keys of a protocol of holds every load shares: samples per hold (``hold_s * rate_hz``), the reading noise sd
    (6,), the orientation jitter (rad), ``g``, and whether the mount and the world tilt are estimated (the run's
    defaults: both)."""
    from ..core.settings import FreeLoadSettings

    n_per = int(round(_num(d, "hold_s", 5.0, where) * _num(d, "rate_hz", 100.0, where)))
    sigma = np.r_[np.full(3, _num(d, "noise_force_N", 0.05, where)), np.full(3, _num(d, "noise_torque_Nm", 0.003, where))]
    jitter = np.radians(_num(d, "mocap_jitter_deg", 0.0, where, positive=False))
    g = _num(d, "g", g_default, where)
    for key, default in (("mount", True), ("gravity_tilt", FreeLoadSettings().gravity_tilt)):
        if not isinstance(d.get(key, default), bool):
            raise PlanError(f"{where}: key '{key}' must be true or false, got {d[key]!r}", key=key)
    return n_per, sigma, jitter, g, d.get("mount", True), d.get("gravity_tilt", FreeLoadSettings().gravity_tilt)


#: a protocol's planned temperature (plan/temperature.py): the range a session sweeps, the coefficients' target se
TEMPERATURE_KEYS = ("temperature_range_C", "temperature_target_N_per_C")
KNOWN = {"payload": {"kind", "orientations", "n_orientations", "seed", "hold_s", "rate_hz", "noise_force_N", "noise_torque_Nm",
                     "mocap_jitter_deg", "mass_kg", "com_m", "rotation_rpy", "mount", "gravity_tilt", "g", *TEMPERATURE_KEYS}}


def plan_from_protocol(d: dict, path: Path, robot_path: Path | None = None,
                       temperature_target: float | None = None) -> FreeLoadPlan:
    """The plan of a protocol of held orientations (module docstring); ``d`` the ``[protocol]`` table of ``path``;
    with a robot.toml (``robot_path``, or the table's ``robot``, or ``kind = "urdf"``) :func:`plan_from_robot`."""
    if robot_path is not None or "robot" in d or d.get("kind") == "urdf":
        return plan_from_robot(d, path, robot_path, temperature_target)
    where = f"{path} [protocol]"
    kind = d.get("kind")
    if kind not in PROTOCOL_KINDS:
        raise PlanError(f"{where}: key 'kind' = {kind!r}; expected one of {list(PROTOCOL_KINDS)}", key="kind")
    unknown = sorted(set(d) - KNOWN[kind])
    if unknown:
        raise PlanError(f"{where}: unknown key(s) {unknown}; known keys for kind = {kind!r}: {sorted(KNOWN[kind])}",
                        key=unknown[0])
    n_per, sigma, jitter, g, mount, tilt = _session(d, where, 9.81)
    if "orientations" in d:
        quats = _quats(d["orientations"], where, "orientations")
    else:
        n = d.get("n_orientations", 14)
        if not isinstance(n, int) or n < 1:
            raise PlanError(f"{where}: key 'n_orientations' must be a positive integer, got {n!r}", key="n_orientations")
        q = np.random.default_rng(int(d.get("seed", 0))).standard_normal((n, 4))
        quats = q / np.linalg.norm(q, axis=1, keepdims=True)
    m = _num(d, "mass_kg", 1.0, where)
    com = np.asarray(d.get("com_m", [0.0, 0.0, 0.05]), float)
    if com.shape != (3,):
        raise PlanError(f"{where}: key 'com_m' must be 3 numbers (m, in ft), got {d.get('com_m')!r}", key="com_m")
    rpy = np.asarray(d.get("rotation_rpy", [0.0, 0.0, 0.0]), float)
    if rpy.shape != (3,):
        raise PlanError(f"{where}: key 'rotation_rpy' must be 3 numbers (rad), got {d.get('rotation_rpy')!r}",
                        key="rotation_rpy")
    R_nom = rotvec_to_rotation(rpy[2] * np.eye(3)[2]) @ rotvec_to_rotation(rpy[1] * np.eye(3)[1]) @ rotvec_to_rotation(rpy[0] * np.eye(3)[0])
    g_B = -g * quat_to_rotation(quats)[:, 2, :]                  # R_WB^T [0, 0, -g]
    g_ft = np.repeat(g_B @ R_nom, n_per, axis=0)
    dg = np.repeat(np.einsum("ji,njt->nit", R_nom, crb.tilt_directions(quat_to_rotation(quats), g)), n_per, axis=0)
    held = tilt and _tilt_held(g_ft)
    bound = crb.payload_bound(g_ft, m, com, sigma, mount=mount, orientation_sd_rad=jitter,
                                    tilt_dirs=dg if tilt and not held else None)
    plan = replace(_plan("payload", "rigid_payload", bound, len(g_ft), sigma, len(quats), (TILT_HELD,) if held else ()),
                   temperature=protocol_temperature(d, len(g_ft), sigma, where, temperature_target))
    proto = {"kind": kind, "holds": len(quats), "samples_per_hold": n_per, "mass_kg": m, "com_m": com.tolist()}
    return FreeLoadPlan(f"protocol {path}", {"payload": plan}, proto)


# ----------------------------------------------------------------------------- a robot.toml and its holds


ROBOT_KEYS = {"kind", "robot", "transducer", "holds", "orientations", "n_orientations", "seed", "gravity_body", "hold_s",
              "rate_hz", "noise_force_N", "noise_torque_Nm", "mocap_jitter_deg", "mass_kg", "com_m", "mount", "gravity_tilt",
              "g", *TEMPERATURE_KEYS}
HOLD_KEYS = {"quat", "q"}
DEFAULT_MASS_KG, DEFAULT_COM_M = 1.0, (0.0, 0.0, 0.05)


@dataclass(frozen=True)
class Holds:
    """The holds of a protocol: ``quat`` (H, 4) (NaN rows: no orientation, gravity from ``gravity_body``),
    ``q`` joint -> (H,) angles (joints a hold does not name at 0), ``gravity_body`` (3,) unit or None."""

    quat: np.ndarray
    q: dict[str, np.ndarray]
    gravity_body: np.ndarray | None

    @property
    def tracked(self) -> np.ndarray:
        return np.all(np.isfinite(self.quat), axis=1)

    def gravity_B(self, g: float) -> np.ndarray:
        """Gravity (H, 3) in B: ``R_WB^T (0, 0, -g)`` for a hold with its orientation, else ``g gravity_body``."""
        out = np.empty((len(self.quat), 3))
        t = self.tracked
        out[t] = -g * quat_to_rotation(self.quat[t])[:, 2, :]
        if (~t).any():
            if self.gravity_body is None:   # read_holds refuses this; a Holds built by hand may not
                raise PlanError(f"holds {np.flatnonzero(~t).tolist()} have no quat and the protocol no gravity_body",
                                key="gravity_body")
            out[~t] = g * self.gravity_body
        return out

    def tilt_B(self, g: float) -> np.ndarray:
        """``d g_B / d tilt`` (H, 3, 2) of the world tilt: zero for holds without an orientation (the estimator
        tilts only the orientation stream's world)."""
        out = np.zeros((len(self.quat), 3, 2))
        t = self.tracked
        out[t] = crb.tilt_directions(quat_to_rotation(self.quat[t]), g)
        return out


def _read_holds(d: dict, where: str, robot, legs: tuple[str, ...]) -> Holds:
    """The holds of ``d`` (``holds``, ``orientations`` or ``n_orientations``), checked against ``robot``."""
    given = [k for k in ("holds", "orientations", "n_orientations") if k in d]
    if len(given) > 1:
        raise PlanError(f"{where}: keys {given} both give the holds; keep one", key=given[1])
    if not given:
        raise PlanError(
            f"{where}: no holds: add key 'holds' = [{{quat = [qw, qx, qy, qz], q = {{joint = rad, ...}}}}, ...] (each hold's "
            "orientation of B in W and joint angles; without quat, gravity_body = [0, 0, -1] for a fixed level base), "
            "or 'orientations' = [[qw, qx, qy, qz], ...], or 'n_orientations' (drawn on SO(3) with 'seed')", key="holds")
    if "orientations" in d:
        quat = _quats(d["orientations"], where, "orientations")
        poses: list[dict[str, float]] = [{}] * len(quat)
    elif "n_orientations" in d:
        n = d["n_orientations"]
        if not isinstance(n, int) or isinstance(n, bool) or n < 1:
            raise PlanError(f"{where}: key 'n_orientations' must be a positive integer, got {n!r}", key="n_orientations")
        z = np.random.default_rng(int(d.get("seed", 0))).standard_normal((n, 4))
        quat, poses = z / np.linalg.norm(z, axis=1, keepdims=True), [{}] * n
    else:
        holds = d["holds"]
        if not isinstance(holds, list) or not holds or not all(isinstance(h, dict) for h in holds):
            raise PlanError(f"{where}: key 'holds' must be a non-empty list of tables {{quat = [qw, qx, qy, qz], "
                            "q = {joint = rad, ...}}", key="holds")
        for i, h in enumerate(holds):
            extra = sorted(set(h) - HOLD_KEYS)
            if extra:
                raise PlanError(f"{where}: holds[{i}]: unknown key(s) {extra}; a hold takes {sorted(HOLD_KEYS)}", key="holds")
            if "q" in h and not (isinstance(h["q"], dict) and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                                  for v in h["q"].values())):
                raise PlanError(f"{where}: holds[{i}].q must be a table {{joint = rad, ...}}, got {h['q']!r}", key="holds")
        quat = np.full((len(holds), 4), np.nan)
        with_quat = [i for i, h in enumerate(holds) if "quat" in h]
        if with_quat:
            quat[with_quat] = _quats([holds[i]["quat"] for i in with_quat], where, "holds.quat")
        poses = [h.get("q", {}) for h in holds]
    gb = None
    if "gravity_body" in d:
        gb = np.asarray(d["gravity_body"], float) if isinstance(d["gravity_body"], list) else np.zeros(0)
        if gb.shape != (3,) or not np.all(np.isfinite(gb)) or np.linalg.norm(gb) < 1e-9:
            raise PlanError(f"{where}: key 'gravity_body' must be 3 numbers (the direction of gravity in B, pointing "
                            f"down), got {d['gravity_body']!r}", key="gravity_body")
        gb = gb / np.linalg.norm(gb)
    missing = np.flatnonzero(~np.all(np.isfinite(quat), axis=1))
    if missing.size and gb is None:
        raise PlanError(f"{where}: holds {missing.tolist()} have no 'quat': give each hold's orientation, or "
                        "gravity_body = [0, 0, -1] (a fixed, level base: the joint angles give the orientation)",
                        key="gravity_body")
    named = sorted({j for h in poses for j in h})
    if named:
        no_link = [k for k in legs if robot.transducers[k].link is None]
        if robot.tree is None or no_link:
            raise PlanError(f"{where}: key 'holds' names joints {named}, but {'the robot.toml has no urdf' if robot.tree is None else f'transducer(s) {no_link} have no link'}: "
                            "joint poses move a load only through the URDF ([transducers.X] link = ...)", key="holds")
        bad = [j for j in named if j not in set(robot.tree.movable)]
        if bad:
            raise PlanError(f"{where}: key 'holds': joint(s) {bad} are not movable joints of the URDF (movable: "
                            f"{sorted(robot.tree.movable)})", key="holds")
    joints = robot.tree.movable if robot.tree is not None else ()
    q = {j: np.array([float(h.get(j, 0.0)) for h in poses]) for j in joints}
    _check_hold_limits(q, robot, where)
    return Holds(quat, q, gb)


#: a planned hold may touch a joint's URDF limit within this (rad); a continuous joint turns at most this many turns
HOLD_LIMIT_TOL_RAD = 1e-3
HOLD_MAX_TURNS = 2.0


def _check_hold_limits(q: dict[str, np.ndarray], robot, where: str) -> None:
    """Every hold's joint angle within its URDF limits (revolute) or ``HOLD_MAX_TURNS`` turns (continuous): a pose the
    joint cannot take is no hold (degrees, most often)."""
    for name, v in q.items():
        jt = robot.tree.joint(name)
        lo, hi = (jt.lower, jt.upper) if jt.type == "revolute" and jt.lower is not None and jt.upper is not None \
            and jt.upper > jt.lower else (-HOLD_MAX_TURNS * 2 * np.pi, HOLD_MAX_TURNS * 2 * np.pi)
        if jt.type not in ("revolute", "continuous"):
            continue
        bad = np.flatnonzero((v < lo - HOLD_LIMIT_TOL_RAD) | (v > hi + HOLD_LIMIT_TOL_RAD))
        if bad.size:
            i = int(bad[0])
            deg = bool(np.all((np.radians(v) >= lo - HOLD_LIMIT_TOL_RAD) & (np.radians(v) <= hi + HOLD_LIMIT_TOL_RAD)))
            raise PlanError(
                f"{where}: holds[{i}].q.{name} = {v[i]:g}{f' (and {bad.size - 1} more hold(s))' if bad.size > 1 else ''}: beyond "
                f"the URDF's limits of joint '{name}' [{lo:.4g}, {hi:.4g}] rad; expected radians"
                + (" (all of them fit read as degrees: degrees?)" if deg else ""), key="holds")


def _robot_path(d: dict, path: Path, robot_path: Path | None, where: str) -> Path:
    if robot_path is None:
        if "robot" not in d:
            raise PlanError(f"{where}: key 'robot' missing: the robot.toml (DATA_FORMAT.md sections 2 and 5) whose "
                            "transducers the holds plan, relative to this file", key="robot")
        return path.parent / str(d["robot"])
    if "robot" in d and (path.parent / str(d["robot"])).resolve() != Path(robot_path).resolve():
        raise PlanError(f"{where}: key 'robot' = {d['robot']!r}, but the command line gives {robot_path}: give the "
                        "robot once", key="robot")
    return Path(robot_path)


def _load_kind(robot, leg: str) -> tuple[str, bool]:
    """``(kind, through_urdf)``: ``urdf_subtree`` where links with mass hang below the transducer's link, else a
    ``rigid_payload`` (its gravity through the URDF where the transducer has a link: an arm whose URDF leaves the
    tool out, ``DATA_FORMAT.md`` section 5)."""
    from ..core.data import has_mass_below

    link = robot.transducers[leg].link
    if link is None:
        return "rigid_payload", False
    return ("urdf_subtree", True) if has_mass_below(robot.tree, link) else ("rigid_payload", True)


def _gravity_to_ft(robot, leg: str, q: dict[str, np.ndarray]):
    """Gravity in B (N, 3) -> in transducer ``leg``'s nominal ft: through the URDF at the joint angles ``q`` where
    it has a link, else by its table's ``rotation`` (``R_nom^T g_B`` per row)."""
    link = robot.transducers[leg].link
    if link is not None:
        return lambda v: crb.urdf_gravity_in_ft(robot.tree, link, q, v)
    R_nom = np.asarray(robot.transducers[leg].rotation, float)
    return lambda v: v @ R_nom


def _urdf_bound(*args, **kw) -> crb.LoadBound:
    return crb.urdf_bound(*args, **kw)[0]


def plan_from_robot(d: dict, path: Path, robot_path: Path | None = None,
                    temperature_target: float | None = None) -> FreeLoadPlan:
    """The plan of a section-5 ``robot.toml``'s transducers held through a protocol's holds (module docstring);
    ``d`` the ``[protocol]`` table of ``path``, ``robot_path`` the robot.toml when the command line gives it (else
    the table's ``robot``, relative to ``path``)."""
    from ..core.data import read_robot
    from ..estimate.freeload.problem import gravity_frame
    from ..core.settings import FreeLoadSettings

    where = f"{path} [protocol]"
    unknown = sorted(set(d) - ROBOT_KEYS)
    if unknown:
        hint = " (the nominal rotation is the robot.toml's [transducers.X] rotation)" if "rotation_rpy" in unknown else ""
        raise PlanError(f"{where}: unknown key(s) {unknown}{hint}; known keys with a robot.toml: {sorted(ROBOT_KEYS)}",
                        key=unknown[0])
    rpath = _robot_path(d, path, robot_path, where)
    if not rpath.is_file():
        raise PlanError(f"{where}: key 'robot' = {d.get('robot')!r}: {rpath} not found (relative to {path})", key="robot")
    robot = read_robot(rpath)
    if "transducer" in d:
        leg = d["transducer"]
        if leg not in robot.legs:
            raise PlanError(f"{where}: key 'transducer' = {leg!r}: not a transducer of {rpath} (legs = "
                            f"{list(robot.legs)})", key="transducer")
        legs: tuple[str, ...] = (leg,)
    else:
        legs = tuple(robot.legs)
    kinds = {k: _load_kind(robot, k) for k in legs}
    if "kind" in d:
        want = {"payload": "rigid_payload", "urdf": "urdf_subtree"}.get(d["kind"])
        wrong = [k for k, (kd, _) in kinds.items() if kd != want]
        if want is None or wrong:
            raise PlanError(f"{where}: key 'kind' = {d['kind']!r}, but {rpath} makes the load of {wrong or legs} "
                            f"{sorted({kinds[k][0] for k in (wrong or legs)})} (a link with massive links below it: a "
                            "URDF load; else a rigid payload); leave 'kind' out", key="kind")
    holds = _read_holds(d, where, robot, legs)
    n_per, sigma, jitter, g, mount, tilt = _session(d, where, robot.g)
    payloads = [k for k, (kd, _) in kinds.items() if kd == "rigid_payload"]
    if not payloads and ("mass_kg" in d or "com_m" in d):
        raise PlanError(f"{where}: keys 'mass_kg' / 'com_m' give a rigid payload's expected mass and CoM; the load of "
                        f"{list(legs)} is the URDF's bodies below the link (they are the expected load)", key="mass_kg")
    m = _num(d, "mass_kg", DEFAULT_MASS_KG, where)
    com = np.asarray(d.get("com_m", DEFAULT_COM_M), float)
    if com.shape != (3,):
        raise PlanError(f"{where}: key 'com_m' must be 3 numbers (m, in ft), got {d.get('com_m')!r}", key="com_m")
    g_B, dB = np.repeat(holds.gravity_B(g), n_per, axis=0), np.repeat(holds.tilt_B(g), n_per, axis=0)
    q = {j: np.repeat(v, n_per) for j, v in holds.q.items()}     # every sample of a hold alike (white noise)
    on_stream = np.repeat(holds.tracked, n_per)
    rec_tilt = not on_stream.any() and FreeLoadSettings().recording_tilt is not False
    loads = {}
    for leg in legs:
        kind, through_urdf = kinds[leg]
        to_ft = _gravity_to_ft(robot, leg, q)
        g_ft = to_ft(g_B)
        held = tilt and on_stream.any() and _tilt_held(g_ft[on_stream])
        dg = np.stack([to_ft(dB[:, :, k]) for k in range(2)], axis=2) if tilt and on_stream.any() and not held else None
        notes: tuple[str, ...] = ((TILT_HELD,) if held else ())
        if on_stream.any() and not on_stream.all():
            notes += (("holds without an orientation take gravity from gravity_body: the run estimates a tilt per such "
                       "recording where the data fix it; not in the bound (taken as known here)"),)
        if rec_tilt:   # one gravity_body recording: its tilt, g F u (freeload.problem.gravity_frame), as a world tilt
            assert holds.gravity_body is not None  # rec_tilt: no hold has a quat, and read_holds asks gravity_body then
            F = gravity_frame(holds.gravity_body[None])[0]
            dBr = crb.tilt_directions(np.broadcast_to(F.T, (len(g_B), 3, 3)), g)
            dg = np.stack([to_ft(dBr[:, :, k]) for k in range(2)], axis=2)
        if kind == "rigid_payload":
            bound_of = partial(crb.payload_bound, g_ft, m, com, sigma, mount=mount, orientation_sd_rad=jitter)
            if "mass_kg" not in d or "com_m" not in d:
                notes += ((f"evaluated at mass_kg = {m:g} kg, com_m = {com.tolist()} m (protocol keys; default where "
                           "not given): the CoM's and mount's se scale with the tool's mass and lever"),)
            if through_urdf:
                notes += ((f"no link with mass below '{robot.transducers[leg].link}' in the URDF: a rigid payload whose "
                           "gravity comes through the URDF's joint angles"),)
        else:
            bodies = {lk: (b.mass_kg, b.com_m) for lk, b in robot.tree.bodies.items()}
            bound_of = partial(_urdf_bound, robot.tree, robot.transducers[leg].link, q, g_ft, bodies, sigma, mount=mount,
                               orientation_sd_rad=jitter)
            notes += ("evaluated at the URDF's nominal bodies",)
        bound = bound_of(tilt_dirs=dg)
        if rec_tilt and set(crb.TILT_NAMES) & set(_undetermined(bound)):   # the estimator holds it, as "auto"
            bound = bound_of(tilt_dirs=None)
            notes += (("the gravity_body holds' tilt is not separable from the mounting rotation here (the sensor "
                       "never turns relative to B): held at 0 by the run, as here"),)
        elif rec_tilt:
            notes += (("gravity_tilt: the tilt of the gravity_body holds' recording (the run's recording_tilt_rad), "
                       "estimated by the run and bounded here"),)
        loads[leg] = replace(_plan(leg, kind, bound, len(g_ft), sigma, len(holds.quat), notes),
                             temperature=protocol_temperature(d, len(g_ft), sigma, where, temperature_target))
    proto = {"robot": str(rpath), "holds": len(holds.quat), "samples_per_hold": n_per,
             "noise_sd": sigma.tolist(), "transducers": list(legs)}
    return FreeLoadPlan(f"protocol {path}, robot {rpath}", loads, proto)


def plan_for(inp: PlanInput, options) -> FreeLoadPlan:
    """``plan``'s free-load part: a pilot dataset's loads (:func:`plan_from_dataset`), or a protocol of holds with its
    robot.toml (:func:`plan_from_protocol`). ``--search`` and ``--detect`` plan hexapod sessions: an error here, as is
    ``--protocol`` with anything but a robot.toml."""
    for opt, name in ((options.search, "--search"), (options.detect, "--detect")):
        if opt:
            raise PlanError(f"{name} plans a hexapod session (hanging turns and standing poses, the hexapod diagnosis' "
                            f"detection sizes); {options.input} is a free load: it takes no {name}", key=name)
    if options.protocol and inp.kind != "robot":
        raise PlanError(f"--protocol: {options.input} is a {'pilot dataset (planned on its own samples and noise)' if inp.kind == 'dataset' else 'protocol already'}; "
                        "to plan other holds give the robot: plan ROBOT.toml --protocol HOLDS.toml", key="--protocol")
    target = getattr(options, "temperature_target", None)
    if target is not None and not target > 0:
        raise PlanError(f"--temperature-target must be a positive number (N/degC), got {target!r}", key="--temperature-target")
    if inp.kind == "dataset":
        return plan_from_dataset(inp.dataset, temperature_target=target)
    # read_input gives a free load's robot.toml (only with --protocol) and its protocol file their table of holds
    assert inp.table is not None and inp.source is not None
    if inp.kind == "robot":
        assert inp.protocol_file is not None
        return plan_from_protocol(inp.table, Path(inp.protocol_file), robot_path=Path(inp.source), temperature_target=target)
    return plan_from_protocol(inp.table, Path(inp.source), temperature_target=target)
