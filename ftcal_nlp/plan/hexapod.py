"""The hexapod's plan: the standard error each parameter group will have, before recording (``plan``'s hexapod part).

A protocol (:class:`Protocol`) says what will be recorded: four hanging
recordings (two opposite pairs, +-x and +-z) of ``hanging_turns`` leg turns of
``turn_s`` each (the shaft speed), ``n_poses`` standing poses held ``pose_s``
each, a share ``board_share`` of them on the tilted board, and the noise: the
transducer's per-sample sd (default ATI Gamma class, 0.05 N / 0.003 N*m) and
the motion capture's per-pose error (default 0.05 deg). The prediction is the
Cramer-Rao bound (:mod:`ftcal_nlp.crb`) of that protocol at a truth drawn by the
simulator (seeded; noise-free geometry of the recordings it would give):

* offsets, leg weights: ``F^-1`` of the hanging model (report eqs. 4-7);
* the CoM curves: the estimator smooths them (GCV weight ``lam`` of a second-
  difference penalty ``P``), so the prediction is its posterior covariance
  ``(F + lam P + Pi)^-1`` at the ``lam`` the estimator picks on the simulated
  protocol (``com_curves_unsmoothed`` gives ``F^-1``, the unbiased-grid bound);
* mounting rotations and positions: the errors-in-variables bound of the
  exact balance (E), hanging parameters known;
* the total CoM (every leg at phi = 0, relative to the body-without-legs CoM):
  both bounds propagated.

Each group's number is the RMS over its parameters of the predicted se, in the
group's unit. The hanging groups scale as ``1/sqrt(hanging time)``, the standing
ones about as ``1/sqrt(n_poses)``: :func:`search` uses these rules to size the
shortest protocol meeting the targets of the protocol file's ``[targets]``
table, then checks the result with a full prediction.

Detection size (``detection`` in ``plan.json``, :mod:`ftcal_nlp.plan.detection`; ``--no-detection`` skips it,
``--detect NAME ...`` restricts it): for each effect of the diagnosis' library, the smallest size (in the
unit of its ``Magnitude``) at which the diagnosis flags a gap with probability 0.8 (over the noise and the
effect's own random parameters) at its decision threshold (``diagnose/attribute.py``: held-out excess over
the noise floor above 0.5 on the standing poses, 0.1 on the hanging samples), the kind that flags it first,
and where the size lies against the effect's realistic range (``below``: every realistic size is detected).
The excess an effect adds is measured on paired simulations of the protocol (with and without the effect,
the same noise draws) through the diagnosis' own base scoring, at the size found and for three draws of the
effect's parameters; the floors are the diagnosis' on the plan's noisy simulation. Not predicted: the design
check (a common tilt of the fitted frames: ``mocap_bias``), walking, and ``moving_com`` (a gap only under
the report's balance). ~30 s on the default protocol.

From a pilot dataset (``plan dataset.toml``): its calibration (diagnosis off)
gives the measured transducer noise (hanging residual RMS) and its protocol
(turns and turn time of the hanging recordings, poses found and their hold
time, share of tilted poses); keys of ``--protocol FILE`` then change it. The
mounting rotations and positions are bounded on the pilot's own poses with its
calibration as the truth, scaled by ``sqrt(pilot poses / planned poses)``; the
hanging groups and the total CoM use the simulator's BigAnt-like geometry with
the pilot's mass and noise.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from .. import crb
from .detection import POWER, Detection, detection_sizes
from ..estimate.hanging import fit_hanging
from ..estimate.hanging.com_qp import second_difference
from ..estimate.hanging.problem import PRIOR_SD_M
from ..core.settings import HangingSettings
from .reading import PlanError, PlanInput, protocol_table, read_toml

if TYPE_CHECKING:
    from ..core.calibration import Calibration
    from ..estimate.standing import Poses

log = logging.getLogger(__name__)

GRID_POSES = 729  # the simulator's 3^6 pose grid: more poses repeat poses
HANGING_RECORDINGS = 4
# group -> (unit, factor from SI)
GROUPS = {
    "offsets_force": ("N", 1.0),
    "offsets_torque": ("N*m", 1.0),
    "leg_weights": ("N", 1.0),
    "com_curves": ("mm", 1e3),
    "com_curves_unsmoothed": ("mm", 1e3),
    "rotations": ("deg", float(np.degrees(1.0))),
    "translations": ("mm", 1e3),
    "total_com": ("mm", 1e3),
}
HANGING_GROUPS = ("offsets_force", "offsets_torque", "leg_weights", "com_curves", "com_curves_unsmoothed")
STANDING_GROUPS = ("rotations", "translations")


@dataclass(frozen=True)
class Protocol:
    """What a session records, and the noise it will carry (SI units unless the name says otherwise)."""

    hanging_turns: float = 10.0        # leg turns per hanging recording (4 recordings: +-x, +-z)
    turn_s: float = 20.0               # time of one turn: shaft speed 2 pi / turn_s
    n_poses: int = GRID_POSES          # standing poses (<= 729, the 3^6 grid)
    pose_s: float = 5.0                # time per pose, transition included (2.3 s of it settling)
    board_share: float = 0.08          # share of the poses on the tilted board
    walk_s: float = 0.0                # walking time (not used by the calibration; counted in the duration)
    noise_force_N: float = 0.05        # per-sample transducer noise (ATI Gamma class)
    noise_torque_Nm: float = 0.003
    mocap_pose_deg: float = 0.05       # motion-capture orientation error per pose, per axis
    mocap_jitter_deg: float = 0.05     # white, every sample
    rate_hz: float = 100.0
    mass_kg: float = 8.18
    g: float = 9.81
    seed: int = 0
    targets: dict = field(default_factory=dict)  # group -> target se in the group's unit

    def __post_init__(self) -> None:
        for name in ("hanging_turns", "turn_s", "pose_s", "rate_hz", "mass_kg", "g"):
            if not getattr(self, name) > 0:
                raise PlanError(f"protocol: {name} must be > 0, got {getattr(self, name)!r}")
        if not (isinstance(self.n_poses, int) and 1 <= self.n_poses <= GRID_POSES):
            raise PlanError(f"protocol: n_poses must be an integer in [1, {GRID_POSES}], got {self.n_poses!r}")
        if not 0 <= self.board_share <= 1:
            raise PlanError(f"protocol: board_share is a fraction in [0, 1], got {self.board_share!r}")
        if self.pose_s <= 2.3:
            raise PlanError(f"protocol: pose_s must exceed the 2.3 s a pose change takes to settle, got {self.pose_s!r}")
        for name in ("walk_s", "noise_force_N", "noise_torque_Nm", "mocap_pose_deg", "mocap_jitter_deg"):
            if getattr(self, name) < 0:
                raise PlanError(f"protocol: {name} must be >= 0, got {getattr(self, name)!r}")
        unknown = sorted(set(self.targets) - set(GROUPS))
        if unknown:
            raise PlanError(f"protocol: [targets] has unknown group(s) {unknown}; known: {sorted(GROUPS)}")
        for k, v in self.targets.items():
            if not (isinstance(v, (int, float)) and v > 0):
                raise PlanError(f"protocol: [targets] {k} must be a positive number (se in {GROUPS[k][0]}), got {v!r}")

    @property
    def duration_s(self) -> float:
        """Recording time: hanging, standing, walking (set-up between recordings not counted)."""
        return HANGING_RECORDINGS * self.hanging_turns * self.turn_s + self.n_poses * self.pose_s + self.walk_s

    def sim_config(self, seed: int | None = None):
        from ..sim import SimConfig

        return SimConfig(
            seed=self.seed if seed is None else seed, rate_hz=self.rate_hz, hanging_cycles=self.hanging_turns,
            hanging_cycle_s=self.turn_s, n_poses=None if self.n_poses >= GRID_POSES else self.n_poses,
            pose_s=self.pose_s, board_pose_fraction=self.board_share, walk_cycles=0.0,
            noise_force_N=self.noise_force_N, noise_torque_Nm=self.noise_torque_Nm,
            mocap_pose_error_deg=self.mocap_pose_deg, mocap_jitter_deg=self.mocap_jitter_deg,
            mass_kg=self.mass_kg, g=self.g)

    @classmethod
    def from_dict(cls, d: dict, *, where: str = "protocol") -> "Protocol":
        known = {f.name for f in fields(cls)}
        d = dict(d.get("protocol", d))
        if "targets" in d and not isinstance(d["targets"], dict):
            raise PlanError(f"{where}: [targets] must be a table of group = se")
        unknown = sorted(set(d) - known)
        if unknown:
            raise PlanError(f"{where}: unknown key(s) {unknown}; known keys: {sorted(known)}")
        if "n_poses" in d and isinstance(d["n_poses"], float) and d["n_poses"].is_integer():
            d["n_poses"] = int(d["n_poses"])
        try:
            return cls(**d)
        except PlanError as exc:
            raise PlanError(f"{where}: {exc}") from None


@dataclass(frozen=True)
class Prediction:
    """Predicted se of each group (RMS over its parameters, group units) and per parameter (SI)."""

    protocol: Protocol
    se: dict[str, float]
    per_param: dict[str, np.ndarray]
    n_poses_found: int
    smoothing: dict[str, float]
    detection: Detection | None = None  # detection sizes of the library effects (detection.py); None: not asked for
    search: tuple[dict, ...] = ()       # the protocols a search tried (:func:`search`), in plan.json when given

    def table(self) -> pd.DataFrame:
        rows = []
        for g, (unit, _) in GROUPS.items():
            t = self.protocol.targets.get(g)
            rows.append({"group": g, "unit": unit, "predicted_se": self.se[g], "target": t,
                         "met": None if t is None else bool(self.se[g] <= t)})
        return pd.DataFrame(rows)

    def detection_table(self) -> pd.DataFrame:
        """Per library effect: the smallest size detected with power 0.8, its unit, the kind that sees it first,
        the realistic range and where the size lies against it (``detection.py``)."""
        if self.detection is None:
            raise PlanError("no detection sizes in this prediction: predict(..., detection=True) or --detection gives them")
        return pd.DataFrame([{"effect": d.effect, "detection_size": d.size, "kind": d.kind or "n/a",
                              "realistic": f"{d.realistic[0]:g}-{d.realistic[1]:g}", "in_range": d.in_realistic_range,
                              "vs_range": d.position, "unit": d.unit} for d in self.detection.sizes])

    def to_json_dict(self) -> dict:
        js = {"protocol": {k: v for k, v in asdict(self.protocol).items()}, "duration_s": self.protocol.duration_s,
              "n_poses_extracted": self.n_poses_found,
              "groups": {r.group: {"se": r.predicted_se, "unit": r.unit, "target": r.target, "met": r.met}
                         for r in self.table().itertuples()}}
        if self.detection is not None:
            js["detection"] = self.detection.to_json_dict()
        if self.search:
            js["search"] = list(self.search)
        return js

    def text(self) -> str:
        """What ``plan`` prints: the protocol and its recording time, the groups' se against their targets, and the
        detection sizes when predicted."""
        p = self.protocol
        lines = [f"protocol: {p.hanging_turns:g} turns x {p.turn_s:g} s per hanging recording (x{HANGING_RECORDINGS}), "
                 f"{p.n_poses} poses x {p.pose_s:g} s ({100 * p.board_share:.0f} % on the board): {p.duration_s / 60:.1f} min recorded",
                 self.table().to_string(index=False, float_format=lambda v: f"{v:.3g}")]
        if self.detection is not None:
            lines += [f"smallest effect size detected with power {POWER:g} (diagnosis' gap threshold):",
                      self.detection_table().to_string(index=False, float_format=lambda v: f"{v:.3g}")]
        return "\n".join(lines)


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def smoothed_com_sd(F: np.ndarray, lay: crb.HangingLayout, lam: float) -> np.ndarray:
    """(G, 3) sd of the CoM grid under the estimator's penalty: ``(F + lam P + Pi)^-1`` (hanging/uncertainty.py)."""
    G = lay.n_grid
    D = second_difference(G)
    H = F.copy()
    idx = lay.r(np.arange(G)[:, None], np.arange(3)[None, :]).ravel()  # grid-major: 3 g + d
    H[np.ix_(idx, idx)] += lam * np.kron(D.T @ D, np.eye(3)) + np.eye(3 * G) / PRIOR_SD_M**2
    cov = crb.crb(H, 1e-13).cov
    return np.sqrt(np.maximum(np.diag(cov)[idx], 0.0)).reshape(G, 3)


@dataclass(frozen=True)
class Pilot:
    """What a pilot dataset lends a plan: its extracted poses and its calibration (standing in for the truth)."""

    poses: Poses
    calibration: Calibration
    pose_s: float
    rate_hz: float

    def standing_sd(self, protocol: Protocol) -> np.ndarray:
        """sd (6K,) of ``(delta_k, p'_k)`` for ``protocol``: the bound on the pilot's own poses, scaled to
        ``protocol.n_poses`` (``1/sqrt``) and evaluated with the protocol's noise and hold time."""
        offsets, _, R, p_prime = self.calibration.stacked()
        n = np.full(self.poses.n, max(1.0, (protocol.pose_s - 2.3) * protocol.rate_hz))
        sz = crb.pose_orientation_sd(n, np.radians(protocol.mocap_jitter_deg), np.radians(protocol.mocap_pose_deg))
        sigma = np.array([protocol.noise_force_N] * 3 + [protocol.noise_torque_Nm] * 3)
        b = crb.standing_bound_at(self.poses, R, p_prime, offsets, self.calibration.body_weight_N, sigma, n, sz)
        return b.sd * np.sqrt(self.poses.n / protocol.n_poses)


def predict(protocol: Protocol, seed: int | None = None, pilot: Pilot | None = None, detection: bool | tuple = False) -> Prediction:
    """The predicted se of every group for ``protocol`` (module docstring); with a ``pilot``, the mounting
    rotations and positions come from the pilot's own pose geometry; ``detection``: also the detection size
    of every library effect (True) or of the effects named (:mod:`ftcal_nlp.plan.detection`, ~30 s more on the
    default protocol)."""
    from ..effects import resolve_effects
    from ..sim import simulate
    from ..estimate.standing import extract_poses

    if not isinstance(detection, bool):
        resolve_effects(list(detection))  # an unknown name fails now, not after the simulation
    sim = simulate(protocol.sim_config(seed))
    legs = tuple(sim.dataset.robot.legs)
    K = len(legs)
    poses = extract_poses(sim.dataset.standing[0], sim.dataset.robot)
    n_grid = HangingSettings().n_grid
    hb = crb.hanging_bound(sim, n_grid)
    sb = crb.standing_bound(sim, poses, hb, references=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        hang = fit_hanging(sim.dataset.hanging, sim.dataset.robot)  # only for the smoothing weight GCV picks
    lam = {k: float(hang.legs[k].smoothing) for k in legs}
    per = {
        "offsets_force": np.concatenate([np.sqrt(np.diag(hb.offset_cov(k)))[:3] for k in legs]),
        "offsets_torque": np.concatenate([np.sqrt(np.diag(hb.offset_cov(k)))[3:] for k in legs]),
        "leg_weights": np.array([np.sqrt(hb.weight_var(k)) for k in legs]),
        "com_curves": np.concatenate([smoothed_com_sd(hb.fisher[k], hb.layouts[k], lam[k]).ravel() for k in legs]),
        "com_curves_unsmoothed": np.concatenate([hb.com_sd(k).ravel() for k in legs]),
        "rotations": sb.bound.sd[: 3 * K],
        "translations": sb.bound.sd[3 * K :],
        "total_com": np.sqrt(np.diag(crb.total_com_cov(sim, hb, sb.bound.cov))),
    }
    if pilot is not None:
        sd = pilot.standing_sd(protocol)
        per["rotations"], per["translations"] = sd[: 3 * K], sd[3 * K :]
    se = {g: _rms(per[g]) * GROUPS[g][1] for g in GROUPS}
    det = None
    if detection:
        names = None if isinstance(detection, bool) else list(detection)
        det = detection_sizes(protocol, sim, hang, poses, float(np.median(list(lam.values()))), effects=names, seed=seed)
    return Prediction(protocol, se, per, int(poses.n), lam, det)


def reported_se(calibration) -> dict[str, float]:
    """The se a calibration reports, by group (RMS over parameters, group units); total CoM not reported (NaN)."""
    L = [calibration.legs[k] for k in calibration.leg_names]

    def cat(get):
        v = [get(l) for l in L]
        return None if any(x is None for x in v) else np.concatenate([np.ravel(x) for x in v])

    parts = {
        "offsets_force": cat(lambda l: None if l.offset_se is None else l.offset_se[:3]),
        "offsets_torque": cat(lambda l: None if l.offset_se is None else l.offset_se[3:]),
        "leg_weights": cat(lambda l: l.leg_weight_se_N),
        "com_curves": cat(lambda l: l.com_xyz_se),
        "rotations": cat(lambda l: l.rotation_se_rad),
        "translations": cat(lambda l: l.position_from_com_se_m),
    }
    return {g: (_rms(parts[g]) * GROUPS[g][1] if parts.get(g) is not None else float("nan")) for g in GROUPS}


# ----------------------------------------------------------------------------- search


def _scaled(p: Protocol, turns: float, n_poses: float) -> Protocol:
    return replace(p, hanging_turns=float(max(0.5, np.ceil(2 * turns) / 2)), n_poses=int(min(GRID_POSES, max(8, np.ceil(n_poses)))))


def search(protocol: Protocol, rounds: int = 4, pilot: Pilot | None = None, detection: bool | tuple = False) -> tuple[Prediction, list[dict]]:
    """The shortest protocol (hanging turns, number of poses; speed, hold time and noise as given) whose
    predicted se meet ``protocol.targets``: scaled by ``1/sqrt(time)`` (hanging groups) and ``1/sqrt(n_poses)``
    (standing groups, and both for the total CoM), then predicted again, for a few rounds.

    Returns the last prediction (with ``detection``, the detection sizes on it) and the trail of every
    protocol tried. Raises :class:`PlanError` when no
    target is given; the last prediction says (``met``) which targets the pose grid cannot reach.
    """
    if not protocol.targets:
        raise PlanError("protocol: --search needs a [targets] table (group = target se in the group's unit)")
    trail = []
    pred = predict(protocol, pilot=pilot)
    for _ in range(rounds):
        trail.append({"hanging_turns": pred.protocol.hanging_turns, "n_poses": pred.protocol.n_poses,
                      "duration_s": pred.protocol.duration_s, **{f"se_{g}": pred.se[g] for g in protocol.targets}})
        ratio = {g: (pred.se[g] / t) ** 2 for g, t in protocol.targets.items()}
        f_h = max([ratio[g] for g in ratio if g in HANGING_GROUPS] + [ratio.get("total_com", 0.0)], default=0.0)
        f_s = max([ratio[g] for g in ratio if g in STANDING_GROUPS] + [ratio.get("total_com", 0.0)], default=0.0)
        # groups without a target do not constrain: shrink towards the smallest sensible protocol
        turns = pred.protocol.hanging_turns * (f_h if f_h > 0 else 0.0)
        n = pred.protocol.n_poses * (f_s if f_s > 0 else 0.0)
        nxt = _scaled(pred.protocol, turns, n)
        if (nxt.hanging_turns, nxt.n_poses) == (pred.protocol.hanging_turns, pred.protocol.n_poses):
            break
        pred = predict(nxt, pilot=pilot)
    if detection:  # of the protocol found only (a prediction of its own)
        pred = predict(pred.protocol, pilot=pilot, detection=detection)
    return pred, trail


# ----------------------------------------------------------------------------- pilot dataset


def protocol_from_pilot(manifest: str | Path, overrides: dict | None = None, dataset=None) -> tuple[Protocol, Pilot]:
    """The protocol and noise of a pilot dataset (module docstring), ``overrides`` changing keys; and its poses.
    ``dataset``: the manifest's dataset when already read (else read here)."""
    from ..core.data import read_dataset
    from ..pipeline import calibrate
    from ..core.settings import CalibrationSettings, DiagnoseSettings

    ds = read_dataset(manifest) if dataset is None else dataset
    if not ds.hanging or not ds.standing:
        raise PlanError(f"{manifest}: a pilot dataset needs hanging and standing recordings")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run = calibrate(ds, CalibrationSettings(diagnose=DiagnoseSettings(enabled=False)))
    # a full calibration (not offsets-only) of a dataset with hanging and standing recordings has both
    assert run.hanging is not None and run.poses is not None
    legs = ds.robot.legs
    res = np.stack([run.hanging.legs[k].residual_rms for k in legs])
    turns = [float(np.median([np.ptp(r.phi[k]) for k in legs]) / (2 * np.pi)) for r in ds.hanging]
    durations = [float(r.t[-1] - r.t[0]) for r in ds.hanging]
    standing_s = sum(float(r.t[-1] - r.t[0]) for r in ds.standing)
    n = int(run.poses.n)
    tilt = np.degrees(np.arccos(np.clip(run.poses.R_WB[:, 2, 2], -1, 1)))
    pose_s, rate_hz = max(standing_s / max(n, 1), 2.5), float(1 / np.median(np.diff(ds.hanging[0].t)))
    d = {"hanging_turns": float(np.mean(turns)), "turn_s": float(np.sum(durations) / max(np.sum(turns), 1e-9)),
         "n_poses": min(n, GRID_POSES), "pose_s": pose_s, "board_share": float(np.mean(tilt > 15.0)),
         "noise_force_N": _rms(res[:, :3]), "noise_torque_Nm": _rms(res[:, 3:]), "rate_hz": rate_hz,
         "mass_kg": ds.robot.mass_kg, "g": ds.robot.g}
    log.info("pilot %s: %s", manifest, ", ".join(f"{k}={v:.4g}" for k, v in d.items()))
    return Protocol.from_dict({**d, **(overrides or {})}, where=str(manifest)), Pilot(run.poses, run.calibration, pose_s, rate_hz)


def load_input(path: str | Path | None, protocol_file: str | Path | None = None, dataset=None) -> tuple[Protocol, Pilot | None]:
    """A protocol file, a pilot dataset manifest (it lists recordings), a ``robot.toml``, or nothing (defaults);
    keys of ``protocol_file`` change the protocol. Returns the protocol and the pilot (or None). ``dataset``: the
    pilot's dataset when already read."""
    over = protocol_table(protocol_file)
    if path is None:
        return Protocol.from_dict(over, where=str(protocol_file or "defaults")), None
    path = Path(path)
    d = read_toml(path)
    if "recording" in d or "recordings" in d:
        return protocol_from_pilot(path, over, dataset)
    if "transducers" in d and "mass_kg" in d:  # robot.toml: its mass, the stated (or default) noise
        return Protocol.from_dict({"mass_kg": d["mass_kg"], "g": d.get("g", 9.81), **over}, where=str(path)), None
    return Protocol.from_dict({**d.get("protocol", d), **over}, where=str(path)), None


def plan_for(inp: PlanInput, options) -> Prediction:
    """``plan``'s hexapod part: the protocol of ``inp`` (defaults, a protocol file, a hexapod robot.toml or a pilot,
    ``--protocol`` keys changing it) predicted, or with ``options.search`` the shortest protocol meeting its targets;
    the detection sizes unless ``options.no_detection`` (``options.detect``: of those effects only)."""
    if getattr(options, "temperature_target", None) is not None:   # a hexapod's correct has no temperature to read
        raise PlanError("--temperature-target plans a free load's temperature coefficients (DATA_FORMAT.md section 5); "
                        f"{inp.source or 'the default protocol'} is a hexapod: it takes no --temperature-target",
                        key="--temperature-target")
    protocol, pilot = load_input(inp.source, inp.protocol_file, inp.dataset)
    detection = False if options.no_detection else (tuple(options.detect) if options.detect else True)
    if options.search:
        pred, trail = search(protocol, pilot=pilot, detection=detection)
        return replace(pred, search=tuple(trail))
    return predict(protocol, pilot=pilot, detection=detection)
