"""``python -m ftcal_nlp.run CONFIG.toml [--force]``: dataset in, calibration and report out.

Stages (each logged with counts and wall time): load or simulate the dataset;
hanging calibration (Sec. III-A); pose extraction (Sec. I-B); standing
calibration with model selection (Sec. III-B, IV-2); the calibration written as
``calibration.json``; every walking recording corrected into ``corrected/``;
the sim-to-real gap diagnosis; the report (tables, figures, ``report.md``,
``report.html``). With ``[offsets_only] calibration = ...`` only the offsets are
re-estimated from the standing poses and everything else is kept (Sec. V).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Iterator

import numpy as np
from threadpoolctl import threadpool_limits

from .calibration import Calibration
from .config import ConfigError, RunConfig, load_config
from .data import DataFormatError, Dataset, read_dataset

log = logging.getLogger("ftcal_nlp.run")


class OutputExistsError(RuntimeError):
    pass


@dataclass
class RunResult:
    """Everything a run produced; reports render from this only."""

    config: RunConfig
    dataset: Dataset
    calibration: Calibration
    hanging: Any = None
    hanging_baseline: Any = None
    poses: Any = None
    selection: Any = None
    standing: Any = None
    standing_baseline: Any = None
    diagnosis: Any = None
    truth: Calibration | None = None
    corrected: dict = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


@contextmanager
def stage(name: str, timings: dict[str, float]) -> Iterator[None]:
    log.info("[%s] ...", name)
    t0 = time.perf_counter()
    yield
    timings[name] = time.perf_counter() - t0
    log.info("[%s] done in %.2f s", name, timings[name])


def prepare_output(folder: Path, force: bool) -> None:
    """Create the output folder; refuse to write into a non-empty one unless ``force``."""
    if folder.exists() and any(folder.iterdir()) and not force:
        raise OutputExistsError(f"{folder} exists and is not empty; pass --force to overwrite it")
    folder.mkdir(parents=True, exist_ok=True)


def load_or_simulate(cfg: RunConfig, force: bool) -> tuple[Dataset, Calibration | None]:
    """The dataset of the config: read from the manifest, or simulated (and written) first."""
    if cfg.manifest is not None and cfg.manifest.is_file():
        ds = read_dataset(cfg.manifest)
        truth_path = cfg.manifest.parent / "truth.json"
        truth = Calibration.load(truth_path, mass_kg=ds.robot.mass_kg, g=ds.robot.g) if truth_path.is_file() else None
        return ds, truth
    if cfg.simulate is None:
        raise DataFormatError(f"{cfg.manifest}: file not found (and no [simulate] table to generate it)")
    from .sim import SimConfig, simulate, write_simulation

    sim_cfg = SimConfig.from_dict(cfg.simulate)
    res = simulate(sim_cfg)
    folder = cfg.simulate_dir or (cfg.manifest.parent if cfg.manifest is not None else cfg.output_dir / "dataset")
    manifest = write_simulation(res, folder, overwrite=force)
    log.info("simulated dataset written to %s", manifest.parent)
    return read_dataset(manifest), res.truth


def run(cfg: RunConfig, *, force: bool = False) -> RunResult:
    """Run the whole pipeline of ``cfg``; write every output into ``cfg.output_dir``."""
    from .correct import correct_recording
    from .hanging import fit_hanging
    from .standing import extract_poses, fit_standing
    from .standing.poses import Poses

    timings: dict[str, float] = {}
    prepare_output(cfg.output_dir, force)
    with stage("load", timings):
        ds, truth = load_or_simulate(cfg, force)
        log.info("%d recordings: %s", len(ds.recordings), ", ".join(f"{r.name} ({r.kind}, {r.n} rows)" for r in ds.recordings))
    robot = ds.robot
    hang = hang_base = None
    if cfg.offsets_only.calibration is not None:
        prior = Calibration.load(cfg.offsets_only.calibration, mass_kg=robot.mass_kg, g=robot.g)
        log.info("offsets-only re-estimation from %s", cfg.offsets_only.calibration)
    else:
        with stage("hanging", timings):
            hang = fit_hanging(ds.hanging, robot, method=cfg.hanging.method, n_grid=cfg.hanging.n_grid, smoothing=cfg.hanging.smoothing, seed=cfg.seed)
            for leg in hang.legs.values():
                for w in leg.warnings:
                    log.warning("%s", w)
        if cfg.hanging.compare_baseline and cfg.hanging.method != "baseline":
            with stage("hanging (baseline)", timings):
                hang_base = fit_hanging(ds.hanging, robot, method="baseline", n_grid=cfg.hanging.n_grid, seed=cfg.seed)
        prior = hang.to_calibration(robot)

    with stage("poses", timings):
        per_rec = [extract_poses(r, robot, cfg.standing.poses) for r in ds.standing]
        if not per_rec:
            raise DataFormatError(f"{cfg.manifest}: no standing recording; the transformation errors need standing poses")
        poses = Poses.concat(per_rec)
        log.info("poses: %s", " -> ".join(f"{v} {k}" for k, v in poses.counts.items()))

    selection = standing = standing_base = None
    if cfg.offsets_only.calibration is not None:
        with stage("standing (offsets only)", timings):
            standing = fit_standing(poses, prior, robot, fit_offsets=True, solver=cfg.standing.solver, balance=cfg.standing.balance)
        model_name = prior.model
    else:
        from .selection import select_models

        model_name = cfg.standing.model
        if model_name == "auto":
            with stage("model selection", timings):
                selection = select_models(
                    poses, prior, robot, candidates=list(cfg.standing.candidates), solver=cfg.standing.solver,
                    balance=cfg.standing.balance, folds=cfg.selection.folds, seed=cfg.selection.seed,
                )
                model_name = selection.best
                log.info("model selection:\n%s", selection.table().to_string(index=False))
        with stage("standing", timings):
            if selection is not None and model_name in selection.results and cfg.standing.weighting == "knorm":
                standing = selection.results[model_name]  # selection already fitted it to all poses
            else:
                standing = fit_standing(poses, prior, robot, model=model_name, solver=cfg.standing.solver, balance=cfg.standing.balance,
                                        weighting=cfg.standing.weighting)
        if cfg.standing.compare_baseline and cfg.standing.solver != "baseline":
            with stage("standing (baseline)", timings):
                try:
                    standing_base = fit_standing(poses, prior, robot, model=model_name, solver="baseline", balance=cfg.standing.balance)
                except RuntimeError as exc:  # a failed baseline is a finding, not a reason to stop
                    log.warning("baseline standing solver failed: %s", exc)
    meta = {"config": str(cfg.path), "solver": cfg.standing.solver, "balance": cfg.standing.balance,
            "weighting": getattr(standing, "weighting", "knorm"),
            # null standard errors in calibration.json are these: directions the poses do not determine
            "unidentified": list(getattr(standing, "unidentified_params", ()))}
    cal = replace(standing.calibration, model=str(model_name), meta=meta)

    result = RunResult(cfg, ds, cal, hang, hang_base, poses, selection, standing, standing_base, truth=truth, timings=timings)
    with stage("write calibration", timings):
        cal.save(cfg.output_dir / "calibration.json")
    with stage("correct walking", timings):
        (cfg.output_dir / "corrected").mkdir(exist_ok=True)
        for rec in ds.walking:
            df = correct_recording(cal, rec)
            df.to_csv(cfg.output_dir / "corrected" / f"{rec.name}.csv", index=False, float_format="%.7g")
            result.corrected[rec.name] = df
            log.info("corrected %s: %d rows", rec.name, len(df))
    if cfg.diagnose.enabled:
        with stage("diagnosis", timings):
            try:
                from .diagnose import diagnose_run
            except ImportError:
                msg = "diagnosis requested but ftcal_nlp.diagnose is not available in this version; diagnosis.json not written"
                log.warning(msg)
                result.notes.append(msg)
            else:
                result.diagnosis = diagnose_run(result)
                (cfg.output_dir / "diagnosis.json").write_text(json.dumps(result.diagnosis.to_json_dict(), indent=1))
    with stage("report", timings):
        from .report import write_report

        write_report(result, cfg.output_dir)
    print(summary_text(result))
    return result


def summary_text(res: RunResult) -> str:
    """The short end-of-run summary: model, residual before/after, where the report is."""
    lines = [f"ftcal_nlp: {res.config.path}"]
    if res.poses is not None:
        lines.append("poses: " + " -> ".join(f"{v} {k}" for k, v in res.poses.counts.items()))
    lines.append(f"model: {res.calibration.model}")
    if res.standing is not None:
        r = np.asarray(res.standing.residuals)
        lines.append("calibrated total-wrench residual RMS (fx fy fz tx ty tz): " + " ".join(f"{v:.3g}" for v in np.sqrt((r**2).mean(0))))
    from .report.figures import naive_total_residuals

    try:
        naive = naive_total_residuals(res)
        lines.append("naive-tare total-wrench residual RMS (fx fy fz tx ty tz): " + " ".join(f"{v:.3g}" for v in np.sqrt((naive**2).mean(0))))
    except (ValueError, IndexError) as exc:
        lines.append(f"naive-tare residual not computed: {exc}")
    if res.diagnosis is not None:
        lines.append(f"diagnosis: {res.diagnosis.verdict}" + (f" ({res.diagnosis.effect})" if res.diagnosis.effect else ""))
    lines.append("stage times: " + ", ".join(f"{k} {v:.2f}s" for k, v in res.timings.items()))
    lines.append(f"report: {res.config.output_dir / 'report.md'}")
    return "\n".join(lines)


def _is_validation_config(path: str) -> bool:
    import tomllib

    p = Path(path)
    if not p.is_file():
        return False
    try:
        return "validation" in tomllib.loads(p.read_text())
    except tomllib.TOMLDecodeError:
        return False  # load_config reports it


def _run_validation(path: str, force: bool, run_validation) -> int:
    """A ``[validation]`` config: the withheld-effect validation of the diagnosis (issue 7)."""
    import tomllib

    p = Path(path)
    d = tomllib.loads(p.read_text())
    out = d.get("output", {}).get("dir")
    if not isinstance(out, str):
        raise ConfigError(f"{p} [output].dir: expected a path string for the output folder")
    folder = p.parent / out
    prepare_output(folder, force)
    try:
        run_validation(d["validation"], folder)
    except ValueError as exc:
        raise ConfigError(f"{p}: {exc}") from exc
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ftcal_nlp.run", description="Calibrate the transducers of a legged robot from a dataset.")
    ap.add_argument("config", help="run config (TOML), e.g. problems/bigant_sim.toml")
    ap.add_argument("--force", action="store_true", help="overwrite a non-empty output folder")
    ap.add_argument("-v", "--verbose", action="store_true")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s", datefmt="%H:%M:%S")
    try:
        if _is_validation_config(args.config):
            from .diagnose.validate import run_validation

            with threadpool_limits(limits=1):
                return _run_validation(args.config, args.force, run_validation)
        cfg = load_config(args.config)
        # many small LAPACK calls: threaded BLAS only adds contention on a few cores
        with threadpool_limits(limits=1):
            run(cfg, force=args.force)
    except (ConfigError, DataFormatError, OutputExistsError, FileExistsError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
