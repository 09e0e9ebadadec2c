"""Speed: wall and CPU time of what a run does, per stage, NLP and baseline in one process.

The default problem is ``SimConfig()`` (the full 3^6 pose grid, four hanging
recordings of 10 leg turns at 100 Hz), written to a temporary folder in the
interchange format so that loading is timed as a user meets it. Then
:func:`ftcal_nlp.calibrate` itself is timed, ``repeats`` times per method, and
its own stage clocks (``CalibrationRun.timings`` / ``cpu_timings``) give the
per-stage rows, so the table measures exactly what ``python -m ftcal_nlp.run``
does:

* ``nlp``: the run's defaults (``CalibrationSettings()``: IPOPT, exact balance,
  feasible-GLS final fit), baselines and diagnosis off;
* ``baseline``: the report's method (hanging ``baseline``; Cayley + alternating
  least squares with the report's balance, K-norm);
* ``calibrate()`` rows: the whole call, without and (NLP) with the diagnosis,
  so the diagnosis' cost is stated beside the run's;
* ``report``: ``ftcal_nlp.report.write_report`` of the NLP run with diagnosis.

"Calibration" is hanging + model selection + standing (the 5 s target). The
median over repeats is reported (the machine is shared: CPU time,
``time.process_time``, is reported beside wall time). BLAS must be limited to
one thread by the caller (``__main__`` does).
"""

from __future__ import annotations

import tempfile
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TypeVar

import numpy as np
import pandas as pd

from ..core.data import read_dataset
from ..estimate.hanging import fit_hanging
from ..pipeline import calibrate
from ..report import write_report
from ..estimate.selection import select_models
from ..core.settings import CalibrationSettings, DiagnoseSettings, HangingSettings, StandingSettings
from ..sim import SimConfig, simulate, write_simulation
from ..estimate.standing import Poses, extract_poses, fit_standing

CALIBRATION_STAGES = ("hanging", "model selection", "standing")
PIPELINE_STAGES = ("poses", "hanging", "model selection", "standing")
_OFF = DiagnoseSettings(enabled=False)
METHODS = {
    "nlp": CalibrationSettings(hanging=HangingSettings(compare_baseline=False), standing=StandingSettings(compare_baseline=False), diagnose=_OFF),
    "baseline": CalibrationSettings(hanging=HangingSettings(method="baseline", compare_baseline=False),
                                    standing=StandingSettings(solver="baseline", balance="report", weighting="knorm",
                                                              compare_baseline=False), diagnose=_OFF),
}


@dataclass(frozen=True)
class SpeedSettings:
    repeats: int = 3
    sim_overrides: dict = field(default_factory=dict)   # SimConfig fields; empty: the default problem
    folds: int = 5
    diagnosis: bool = True                               # also time calibrate() with the diagnosis
    whole_run: bool = True                               # also time ftcal_nlp.run.run (load .. report) with and without it


_R = TypeVar("_R")


def timed(fn: Callable[[], _R], repeats: int) -> tuple[_R, list[float], list[float]]:
    """Call ``fn`` ``repeats`` times; returns the last result, wall and CPU seconds of each call."""
    walls: list[float] = []
    cpus: list[float] = []
    for _ in range(max(1, repeats)):
        w0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
    return out, walls, cpus


def _row(stage: str, method: str, walls: list[float], cpus: list[float], note: str = "") -> dict:
    return {"stage": stage, "method": method, "wall_s": float(np.median(walls)), "wall_min_s": float(np.min(walls)),
            "cpu_s": float(np.median(cpus)), "repeats": len(walls), "note": note}


def _settings(method: str, folds: int, diagnosis: bool = False) -> CalibrationSettings:
    cs = METHODS[method]
    cs = replace(cs, selection=replace(cs.selection, folds=folds))
    return replace(cs, diagnose=DiagnoseSettings(enabled=True, folds=folds)) if diagnosis else cs


def _time_calibrate(ds, cs: CalibrationSettings, repeats: int):
    """``calibrate(ds, cs)`` ``repeats`` times: the last run, whole-call wall/CPU, per-stage wall/CPU lists."""
    walls, cpus, run = [], [], None
    stage_w: dict[str, list[float]] = {}
    stage_c: dict[str, list[float]] = {}
    for _ in range(max(1, repeats)):
        w0, c0 = time.perf_counter(), time.process_time()
        run = calibrate(ds, cs)
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
        for k, v in run.timings.items():
            stage_w.setdefault(k, []).append(v)
            stage_c.setdefault(k, []).append(run.cpu_timings.get(k, np.nan))
    return run, walls, cpus, stage_w, stage_c


def _time_whole_run(manifest: Path, tmp: Path, diagnosis: bool, folds: int, repeats: int) -> tuple[list[float], list[float]]:
    """Wall/CPU of ``ftcal_nlp.run.run`` on the written dataset (load, calibrate, files, report), the run's
    own defaults but for the diagnosis switch and the folds."""
    import contextlib
    import io

    from ..config import load_config
    from ..run import run

    cfg_path = tmp / f"whole_{int(diagnosis)}.toml"
    cfg_path.write_text(f'[data]\nmanifest = "{manifest}"\n[output]\ndir = "{tmp / f"whole_out_{int(diagnosis)}"}"\n'
                        f"[selection]\nfolds = {folds}\n[diagnose]\nenabled = {'true' if diagnosis else 'false'}\nfolds = {folds}\n")
    cfg = load_config(cfg_path)
    with contextlib.redirect_stdout(io.StringIO()):  # run prints its end summary
        _, walls, cpus = timed(lambda: run(cfg, force=True), repeats)
    return walls, cpus


def run_speed(settings: SpeedSettings = SpeedSettings(), progress: bool = True) -> dict:
    """Time ``calibrate`` (module docstring). Returns ``times`` (DataFrame: stage, method, wall_s,
    wall_min_s, cpu_s, repeats, note), ``totals`` and the problem's sizes."""
    from tqdm import tqdm

    R = settings.repeats
    rows: list[dict] = []
    bar = tqdm(total=2 + len(METHODS) + int(settings.diagnosis), desc="speed", disable=not progress)
    sim = simulate(SimConfig(**settings.sim_overrides))
    runs: dict = {}
    totals: dict = {}
    with tempfile.TemporaryDirectory(prefix="ftcal_bench_") as tmp:
        manifest = write_simulation(sim, Path(tmp) / "data")
        ds, w, c = timed(lambda: read_dataset(manifest), R)
        rows.append(_row("load", "shared", w, c))
        bar.update()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for method in METHODS:
                run, walls, cpus, sw, sc = _time_calibrate(ds, _settings(method, settings.folds), R)
                runs[method] = run
                for st in PIPELINE_STAGES:
                    note = f"selected {run.selection.best}" if st == "model selection" else (f"model {run.calibration.model}" if st == "standing" else "")
                    rows.append(_row(st, method, sw[st], sc[st], note))
                rows.append(_row("calibrate() without diagnosis", method, walls, cpus))
                totals[method] = {"calibration_wall_s": float(sum(np.median(sw[k]) for k in CALIBRATION_STAGES)),
                                  "calibration_cpu_s": float(sum(np.median(sc[k]) for k in CALIBRATION_STAGES)),
                                  "run_wall_s": float(np.median(walls)), "run_cpu_s": float(np.median(cpus))}
                totals[method]["with_poses_wall_s"] = totals[method]["calibration_wall_s"] + float(np.median(sw["poses"]))
                bar.update()
            report_run = runs["nlp"]
            if settings.diagnosis:
                run, walls, cpus, sw, sc = _time_calibrate(ds, _settings("nlp", settings.folds, diagnosis=True), R)
                rows.append(_row("diagnosis", "shared", sw["diagnosis"], sc["diagnosis"], f"verdict {run.diagnosis.verdict}"))
                rows.append(_row("calibrate() with diagnosis", "nlp", walls, cpus))
                totals["nlp"]["run_with_diagnosis_wall_s"] = float(np.median(walls))
                report_run = run
                bar.update()
        report_run = replace(report_run, truth=sim.truth)  # a frozen run: a new one with the truth
        out_dir = Path(tmp) / "report"
        out_dir.mkdir()
        _, w, c = timed(lambda: write_report(report_run, out_dir), 1)
        rows.append(_row("report", "shared", w, c))
        if settings.whole_run:
            for diag in (False, True):
                walls, cpus = _time_whole_run(manifest, Path(tmp), diag, settings.folds, R)
                label = "whole run (python -m ftcal_nlp.run) " + ("with" if diag else "without") + " diagnosis"
                rows.append(_row(label, "nlp", walls, cpus))
                totals["nlp"]["whole_run_" + ("with" if diag else "without") + "_diagnosis_wall_s"] = float(np.median(walls))
        bar.update()
    bar.close()
    times = pd.DataFrame(rows)
    poses = runs["nlp"].poses
    sizes = {"hanging_samples": int(sum(r.n for r in ds.hanging)), "standing_samples": int(sum(r.n for r in ds.standing)),
             "poses": int(poses.n), "selected_nlp": runs["nlp"].selection.best, "selected_baseline": runs["baseline"].selection.best}
    context = {"sim": sim, "dataset": ds, "poses": poses, "runs": runs, "run_result": report_run, "folds": settings.folds}
    return {"times": times, "totals": totals, "sizes": sizes, "settings": settings, "load_average": _load_average(),
            "context": context}


def _load_average() -> float:
    """1-minute load average of the machine (other processes compete for the 2 cores)."""
    try:
        import os

        return float(os.getloadavg()[0])
    except OSError:
        return float("nan")


def profile_targets(context: dict, workdir: Path, names: list[str] | None = None, methods: tuple[str, ...] = ("nlp",)) -> dict:
    """Callables re-running stages of the speed bench's problem with the settings ``calibrate`` used, for :mod:`.profile`.

    ``names``: which to build (all by default): ``load``, ``poses``, ``hanging (nlp)``,
    ``model selection (nlp)``, ``standing (nlp)``, ``calibrate (nlp)``, ``diagnosis``, ``report``.
    The dataset for ``load`` is written into ``workdir`` here, outside what is profiled.
    """
    from ..diagnose import diagnose_run

    ds, poses, robot = context["dataset"], context["poses"], context["dataset"].robot
    out: dict[str, Callable] = {}
    if names is None or "load" in names:
        manifest = write_simulation(context["sim"], Path(workdir) / "data", overwrite=True)
        out["load"] = lambda: read_dataset(manifest)
    for m in methods:
        cs = _settings(m, context["folds"])
        run = context["runs"][m]
        prior = run.hanging.to_calibration(robot)
        out["poses"] = lambda cs=cs: Poses.concat([extract_poses(r, robot, cs.standing.poses) for r in ds.standing])
        out[f"hanging ({m})"] = lambda cs=cs: fit_hanging(ds.hanging, robot, cs.hanging)
        out[f"model selection ({m})"] = lambda cs=cs, prior=prior: select_models(poses, prior, robot, cs.standing, cs.selection)
        out[f"standing ({m})"] = lambda cs=cs, prior=prior, best=run.calibration.model: fit_standing(poses, prior, robot, cs.standing, model=best)
        out[f"calibrate ({m})"] = lambda cs=cs: calibrate(ds, cs)
    out["diagnosis"] = lambda: diagnose_run(context["run_result"])
    report_dir = Path(workdir) / "report"
    report_dir.mkdir(parents=True, exist_ok=True)
    out["report"] = lambda: write_report(context["run_result"], report_dir)
    return out if names is None else {k: v for k, v in out.items() if k in names}


# ----------------------------------------------------------------------------- free loads (issue 22, item 9)

#: targets of issue 22: a payload of 1e5 samples, a 6-joint URDF load of 1e4 quasi-static samples
LOAD_TARGETS_S = {"payload": 1.0, "urdf_chain6": 5.0}


def chain_urdf_text(n_joints: int = 6) -> str:
    """A URDF with ``n_joints`` revolute joints below a sensor link ``ft`` (axes z, y, y, x, y, x, ...; each link
    a mass with an off-axis CoM), one joint above it: the speed bench's load of URDF links."""
    axes = ["0 0 1", "0 1 0", "0 1 0", "1 0 0", "0 1 0", "1 0 0"]
    links = ['<link name="base"><inertial><origin xyz="0 0 0"/><mass value="5.0"/>'
             '<inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial></link>',
             '<link name="mount"><inertial><origin xyz="0 0 -0.02"/><mass value="0.5"/>'
             '<inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.001"/></inertial></link>', '<link name="ft"/>']
    joints = ['<joint name="j_above" type="revolute"><parent link="base"/><child link="mount"/><origin xyz="0 0 -0.05"/>'
              '<axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>',
              '<joint name="ft_mount" type="fixed"><parent link="mount"/><child link="ft"/><origin xyz="0 0 -0.04" rpy="0 0 0.3"/></joint>']
    parent = "ft"
    for k in range(n_joints):
        m = 1.5 - 0.2 * k
        links.append(f'<link name="l{k}"><inertial><origin xyz="{0.01 * (k % 3)} {-0.008 + 0.004 * k} {-0.12 + 0.01 * k}"/>'
                     f'<mass value="{m:.2f}"/><inertia ixx="0.005" ixy="0" ixz="0" iyy="0.005" iyz="0" izz="0.002"/></inertial></link>')
        joints.append(f'<joint name="j{k}" type="revolute"><parent link="{parent}"/><child link="l{k}"/>'
                      f'<origin xyz="0 0 {-0.05 if k == 0 else -0.2}"/><axis xyz="{axes[k % len(axes)]}"/>'
                      f'<limit lower="-1.2" upper="1.2" effort="1" velocity="1"/></joint>')
        parent = f"l{k}"
    return '<?xml version="1.0"?>\n<robot name="chain6">\n' + "\n".join(links + joints) + "\n</robot>\n"


@dataclass(frozen=True)
class LoadSpeedSettings:
    """Problem sizes: ``payload_samples`` samples of a wrist tool (all held but the moves), ``urdf_held`` held samples
    of the ``urdf_joints``-joint chain; ``repeats`` per estimator (median reported)."""

    payload_samples: int = 100_000
    urdf_held: int = 10_000
    urdf_joints: int = 6
    repeats: int = 3
    estimators: tuple[str, ...] = ("nlp", "ft_calib", "calib_force")


def load_speed_configs(settings: LoadSpeedSettings, urdf_path: Path):
    """The two timed problems: a payload of about ``payload_samples`` samples at 100 Hz (holds of 40 s, moves of
    4 s), and the chain URDF with ``urdf_held`` held samples (50 holds: 10 tilts x 5 joint poses)."""
    from ..sim.free import PayloadConfig, UrdfLegConfig

    n_holds = max(2, int(round((settings.payload_samples / 100.0 + 4.0) / 44.0)))
    hold_s = (settings.payload_samples / 100.0 - 4.0 * (n_holds - 1)) / n_holds
    payload = PayloadConfig(seed=0, n_orientations=n_holds, hold_s=hold_s, move_s=4.0)
    urdf = UrdfLegConfig(seed=0, urdf=str(urdf_path), transducer="ft", ft_link="ft", n_orientations=10,
                         poses_per_orientation=5, hold_s=settings.urdf_held / 50 / 100.0, move_s=1.0)
    return {"payload": payload, "urdf_chain6": urdf}


def run_load_speed(settings: LoadSpeedSettings = LoadSpeedSettings(), progress: bool = True) -> dict:
    """Wall time of each free-load estimator on the two problems (the estimate only, not the reading of the files:
    quasi-static selection, compression, solve, covariance), median of ``repeats`` after a first call timed on
    its own (``first_call_s``: CasADi builds its functions then). Returns ``times`` (DataFrame: problem,
    estimator, n, n_held, joints_below_sensor, wall_s, wall_min_s, first_call_s, target_s) and ``failures``."""
    from tqdm import tqdm

    from ..sim.free import simulate_free
    from .accuracy_loads import ESTIMATORS

    rows, failures = [], {}
    with tempfile.TemporaryDirectory(prefix="ftcal_load_speed_") as tmp:
        urdf_path = Path(tmp) / "chain6.urdf"
        urdf_path.write_text(chain_urdf_text(settings.urdf_joints))
        cfgs = load_speed_configs(settings, urdf_path)
        for problem, cfg in tqdm(cfgs.items(), desc="speed (free loads)", disable=not progress):
            res = simulate_free(cfg)
            for name in settings.estimators:
                walls = []
                try:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        # the first call builds the CasADi functions of the problem's size: timed on its own row
                        first = ESTIMATORS[name](res, Path(tmp) / f"{problem}_{name}_first").wall_s
                        for r in range(max(1, settings.repeats)):
                            walls.append(ESTIMATORS[name](res, Path(tmp) / f"{problem}_{name}_{r}").wall_s)
                except NotImplementedError:
                    continue
                except Exception as exc:       # shown in the summary, never a silent gap
                    failures[f"{problem}/{name}"] = f"{type(exc).__name__}: {exc}"
                    continue
                rows.append({"problem": problem, "estimator": name, "n": len(res.held), "n_held": int(res.held.sum()),
                             "joints_below_sensor": settings.urdf_joints if problem != "payload" else 0,
                             "wall_s": float(np.median(walls)), "wall_min_s": float(np.min(walls)), "first_call_s": float(first),
                             "target_s": LOAD_TARGETS_S[problem] if name == "nlp" else np.nan})
    return {"times": pd.DataFrame(rows), "failures": failures, "settings": settings, "load_average": _load_average()}


# ----------------------------------------------------------------------------- the diagnosis' cost (issue 23, item 6)

#: issue 23: the diagnosis takes at most this many times the calibration without it
DIAGNOSIS_RATIO_TARGET = 3.0


@dataclass(frozen=True)
class DiagnosisRatioSettings:
    """``problems``: ``hexapod`` (the default problem, ``problems/bigant_sim.toml``: ``SimConfig()`` with seed 0
    and the run's default settings), ``payload`` (a wrist tool of ``payload_samples`` samples, the load-speed
    bench's payload, clean) and ``payload_effects`` (the same payload with ``payload_effects`` injected, each at its
    registry test size (``Magnitude.test``, inside its realistic range), injector seed 0: the chain then names
    effects, refines their shapes and looks again); ``repeats`` per setting (median reported)."""

    repeats: int = 3
    problems: tuple[str, ...] = ("hexapod", "payload", "payload_effects")
    hexapod_sim: dict = field(default_factory=dict)      # SimConfig overrides; empty: the default problem
    payload_samples: int = 100_000
    payload_effects: tuple[str, ...] = ("creep", "clock_offset")


def payload_effect_injectors(names: tuple[str, ...]) -> tuple[dict, ...]:
    """The free-load simulator's ``effects`` entries of ``names``: each at its registry test size, seed 0."""
    from ..effects import EFFECTS

    return tuple({"name": n, "scale": float(EFFECTS[n].magnitude.test), "seed": 0} for n in names)


def diagnosis_ratio_datasets(settings: DiagnosisRatioSettings, tmp: Path) -> dict:
    """``{problem: dataset}``: each simulated, written in the interchange format into ``tmp`` and read back."""
    from ..sim.free import simulate_free, write_free_load

    out = {}
    if "hexapod" in settings.problems:
        out["hexapod"] = read_dataset(write_simulation(simulate(SimConfig(**settings.hexapod_sim)), tmp / "hexapod"))
    cfg = load_speed_configs(LoadSpeedSettings(payload_samples=settings.payload_samples), tmp / "unused.urdf")["payload"]
    if "payload" in settings.problems:
        out["payload"] = read_dataset(write_free_load(simulate_free(cfg), tmp / "payload"))
    if "payload_effects" in settings.problems:
        cfg_e = replace(cfg, effects=payload_effect_injectors(settings.payload_effects))
        out["payload_effects"] = read_dataset(write_free_load(simulate_free(cfg_e), tmp / "payload_effects"))
    return out


def run_diagnosis_ratio(settings: DiagnosisRatioSettings = DiagnosisRatioSettings(), progress: bool = True) -> dict:
    """Wall time of :func:`ftcal_nlp.calibrate` with the diagnosis on against the same call with it off (the run's
    default settings otherwise), per problem: ``times`` (DataFrame: problem, injected (effects), samples, without_s, with_s,
    diagnosis_s (its stage clock), ratio = diagnosis_s / without_s (the target's), ratio_whole = with_s / without_s, and the
    same on CPU time (``time.process_time``: what other jobs on a shared machine do not inflate): without_cpu_s,
    diagnosis_cpu_s, ratio_cpu; target, verdict, effects, repeats)."""
    from tqdm import tqdm

    rows = []
    with tempfile.TemporaryDirectory(prefix="ftcal_diag_ratio_") as tmp:
        data = diagnosis_ratio_datasets(settings, Path(tmp))
        for problem, ds in tqdm(data.items(), desc="diagnosis ratio", disable=not progress):
            on = CalibrationSettings()
            off = replace(on, diagnose=DiagnoseSettings(enabled=False))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                _, w_off, c_off, _, _ = _time_calibrate(ds, off, settings.repeats)
                run, w_on, _, sw, sc = _time_calibrate(ds, on, settings.repeats)
            d = run.diagnosis
            n = int(sum(r.n for r in ds.hanging) + sum(r.n for r in ds.standing) + sum(r.n for r in getattr(ds, "walking", ())))
            without, with_, diag = float(np.median(w_off)), float(np.median(w_on)), float(np.median(sw.get("diagnosis", [np.nan])))
            without_cpu, diag_cpu = float(np.median(c_off)), float(np.median(sc.get("diagnosis", [np.nan])))
            injected = " + ".join(settings.payload_effects) if problem == "payload_effects" else ""
            rows.append({"problem": problem, "injected": injected, "samples": n, "without_s": without, "with_s": with_, "diagnosis_s": diag,
                         "ratio": diag / without, "ratio_whole": with_ / without, "without_cpu_s": without_cpu,
                         "diagnosis_cpu_s": diag_cpu, "ratio_cpu": diag_cpu / without_cpu, "target": DIAGNOSIS_RATIO_TARGET,
                         "verdict": None if d is None else d.verdict,
                         "effects": "" if d is None else " ".join(e["name"] for e in (d.effects or [])),
                         "repeats": len(w_on)})
    return {"times": pd.DataFrame(rows), "settings": settings, "load_average": _load_average()}
