"""The bench as one call: settings for the quick and the full run, and :func:`run_bench`.

Parts (each optional): ``accuracy`` (accuracy.py, crb/hexapod.py), ``speed``
(speed.py), ``scaling`` (scaling.py), ``profile`` (profile.py, on the speed
bench's problem), ``correction`` (correction.py: se throughput, offset tracking), ``export`` (export_speed.py: the
exported C and the batched numpy correction), ``plan`` (plan_check.py: the plan's predicted se against the
calibration's reported se and the spread over seeds), ``detect`` (detect_check.py: the plan's detection
sizes against the diagnosis' detection rate at them), ``loads`` (accuracy_loads.py, crb/free_load.py: the free loads of
issue 22, NLP and the peers against the bound), ``load_speed`` (speed.py: payload of 1e5 samples, 6-joint URDF
load of 1e4 held samples), ``diagnosis_ratio`` (speed.py: the diagnosis' stage against ``calibrate()`` without it, on
the default problem and a payload of 1e5 samples; issue 23). Results are written by report.py into ``out``.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from .accuracy import AccuracySettings
from .accuracy_loads import LoadAccuracySettings
from .correction import CorrectionBenchSettings
from .detect_check import DetectCheckSettings
from .export_speed import ExportSpeedSettings
from .plan_check import PlanCheckSettings
from ..plan import Protocol
from .scaling import HANGING_TASKS, ScalingSettings
from .speed import DiagnosisRatioSettings, LoadSpeedSettings, SpeedSettings

PARTS = ("accuracy", "loads", "speed", "load_speed", "diagnosis_ratio", "scaling", "profile", "correction", "export", "plan",
         "detect")


@dataclass(frozen=True)
class BenchSettings:
    accuracy: AccuracySettings = field(default_factory=AccuracySettings)
    speed: SpeedSettings = field(default_factory=SpeedSettings)
    scaling: ScalingSettings = field(default_factory=ScalingSettings)
    correction: CorrectionBenchSettings = field(default_factory=CorrectionBenchSettings)
    export: ExportSpeedSettings = field(default_factory=ExportSpeedSettings)
    plan: PlanCheckSettings = field(default_factory=PlanCheckSettings)
    detect: DetectCheckSettings = field(default_factory=DetectCheckSettings)
    loads: LoadAccuracySettings = field(default_factory=LoadAccuracySettings)
    load_speed: LoadSpeedSettings = field(default_factory=LoadSpeedSettings)
    diagnosis_ratio: DiagnosisRatioSettings = field(default_factory=DiagnosisRatioSettings)
    profile_all: bool = True          # every NLP stage, the load and the report; False: the slowest ones
    profile_count: int = 2            # with profile_all False: the slowest calibration stage and the slowest others
    parts: tuple[str, ...] = PARTS
    mode: str = "full"


def full_settings() -> BenchSettings:
    """The full bench (~10 min on 2 shared cores): 20 datasets and all four pipelines, 3 repeats, 28 scaling points."""
    return BenchSettings(accuracy=AccuracySettings(pipelines=("nlp", "baseline", "baseline_exact_balance", "nlp_report_balance")))


def quick_settings() -> BenchSettings:
    """The quick bench (~2 min): 4 datasets, one repeat, 9 scaling points (no tracemalloc), the slowest calibration stage profiled."""
    return BenchSettings(
        accuracy=AccuracySettings(seeds=(0, 1, 2, 3)),
        speed=SpeedSettings(repeats=1),
        scaling=ScalingSettings(poses=(100, 1000, 10000), hanging_samples=(10_000, 30_000, 100_000),
                                standing_tasks=("selection_nlp",), hanging_tasks=HANGING_TASKS, tracemalloc=False),
        export=ExportSpeedSettings(n_samples=300_000, repeats=3),
        plan=PlanCheckSettings(seeds=(0, 1, 2, 3)),
        detect=DetectCheckSettings(effects=("casing_load",), seeds=(0, 1, 2, 3), clean_seeds=(0,)),
        loads=LoadAccuracySettings(seeds=(0, 1, 2, 3)),
        load_speed=LoadSpeedSettings(repeats=1),
        diagnosis_ratio=DiagnosisRatioSettings(repeats=1),
        profile_all=False,
        profile_count=1,
        mode="quick",
    )


def tiny_settings() -> BenchSettings:
    """A few seconds' smoke run (tests): one small dataset, a small speed problem, two scaling points."""
    sim_small = {"hanging_cycles": 1.5, "n_poses": 60, "walk_cycles": 0.5}
    return BenchSettings(
        accuracy=AccuracySettings(seeds=(0,), hanging_cycles=1.5, n_poses=60),
        speed=SpeedSettings(repeats=1, sim_overrides=sim_small, folds=3, diagnosis=False),
        scaling=ScalingSettings(poses=(100, 200), hanging_samples=(), standing_tasks=("standing_nlp",), hanging_tasks=(),
                                base_sim={"hanging_cycles": 1.5, "n_poses": 60}, tracemalloc=False),
        correction=CorrectionBenchSettings(walk_minutes=0.25, sim_overrides={"n_poses": 60, "hanging_cycles": 1.5, "walk_cycles": 0.0}),
        export=ExportSpeedSettings(n_samples=2_000, repeats=1),
        plan=PlanCheckSettings(reference=Protocol(hanging_turns=0.5, n_poses=20), seeds=(0,), halves=False),
        loads=LoadAccuracySettings(seeds=(0,), payload={"n_orientations": 6, "hold_s": 4.0}, urdf={"n_orientations": 4, "hold_s": 2.0}),
        load_speed=LoadSpeedSettings(payload_samples=5_000, urdf_held=1_000, repeats=1),
        profile_all=False,
        profile_count=1,
        diagnosis_ratio=DiagnosisRatioSettings(repeats=1, hexapod_sim=sim_small, payload_samples=5_000),
        # the detect part diagnoses whole datasets (~20 s even this small); tests/test_detection.py covers the prediction;
        # diagnosis_ratio too (tests/test_diagnosis_ratio.py runs it on small problems)
        parts=tuple(p for p in PARTS if p not in ("detect", "diagnosis_ratio")),
        mode="tiny",
    )


def _slowest(times, k: int = 2) -> list[str]:
    """Names of the slowest NLP-side stages (profile keys of speed.profile_targets)."""
    t = times[times.method.isin(["nlp", "shared"])].dropna(subset=["wall_s"]).sort_values("wall_s", ascending=False)
    keys = []
    for r in t.itertuples():
        if r.stage.startswith("calibrate()"):  # whole-call rows; the profile looks at stages
            continue
        key = r.stage if r.stage in ("load", "poses", "report", "diagnosis") else f"{r.stage} (nlp)"
        if key not in keys:
            keys.append(key)
    calib = [f"{s} (nlp)" for s in ("hanging", "model selection", "standing")]
    slow_calib = next(k_ for k_ in keys if k_ in calib)
    out = [slow_calib] + [k_ for k_ in keys if k_ != slow_calib][: k - 1]
    return out


def run_bench(settings: BenchSettings, out: str | Path = "reports/bench", progress: bool = True) -> dict:
    """Run the chosen parts, write tables, figures and ``summary.md`` into ``out``; returns the results and the text."""
    from threadpoolctl import threadpool_limits

    from . import report
    from .accuracy import run_accuracy
    from .correction import run_correction
    from .detect_check import run_detect_check
    from .export_speed import run_export_speed
    from .plan_check import run_plan_check
    from .profile import profile_stages
    from .scaling import run_scaling
    from .speed import profile_targets, run_speed

    from .accuracy_loads import run_load_accuracy
    from .speed import run_diagnosis_ratio, run_load_speed

    acc = sp = sc = prof = corr = exp = plan = det = loads = lsp = dr = None
    with threadpool_limits(limits=1):  # many small LAPACK calls: threads only contend on 2 cores
        if "accuracy" in settings.parts:
            acc = run_accuracy(settings.accuracy, progress=progress)
        if "loads" in settings.parts:
            loads = run_load_accuracy(settings.loads, progress=progress)
        if "load_speed" in settings.parts:
            lsp = run_load_speed(settings.load_speed, progress=progress)
        if "diagnosis_ratio" in settings.parts:
            dr = run_diagnosis_ratio(settings.diagnosis_ratio, progress=progress)
        if "speed" in settings.parts or "profile" in settings.parts:
            sp = run_speed(settings.speed, progress=progress)
        if "profile" in settings.parts:
            assert sp is not None  # the speed part ran above for the profile
            keep = None if settings.profile_all else _slowest(sp["times"], settings.profile_count)
            with tempfile.TemporaryDirectory(prefix="ftcal_profile_") as tmp:
                prof = profile_stages(profile_targets(sp["context"], Path(tmp), keep))
        if "scaling" in settings.parts:
            sc = run_scaling(settings.scaling, progress=progress)
        if "correction" in settings.parts:
            corr = run_correction(settings.correction, progress=progress)
        if "export" in settings.parts:
            exp = run_export_speed(settings.export)
        if "plan" in settings.parts:
            plan = run_plan_check(settings.plan)
        if "detect" in settings.parts:
            det = run_detect_check(settings.detect)
    text = report.write_all(Path(out), acc, sp if "speed" in settings.parts else None, sc, prof, settings.mode, corr=corr,
                            export=exp, plan=plan, detect=det, loads=loads, load_speed=lsp,
                            diagnosis_ratio=dr)
    return {"accuracy": acc, "speed": sp, "scaling": sc, "profile": prof, "correction": corr, "export": exp, "plan": plan,
            "detect": det, "loads": loads, "load_speed": lsp, "diagnosis_ratio": dr, "summary": text}


__all__ = ["PARTS", "BenchSettings", "full_settings", "quick_settings", "run_bench", "tiny_settings"]
