"""``python -m ftcal_nlp.run CONFIG.toml [--force]``: dataset in, calibration and report out.

The command line around :func:`ftcal_nlp.calibrate`: it reads the config, loads
(or simulates and writes) the dataset, calls ``calibrate`` with the config's
settings, and writes what the run produced: ``calibration.json`` (and its joint
covariance ``calibration_cov.npz``, named in its ``meta.covariance_file``), the
corrected walking recordings in ``corrected/`` (with se and contact columns;
``tracked_offsets/`` with ``[correct] track_offsets``), ``diagnosis.json`` and the report
(tables, figures, ``report.md``, ``report.html``), then prints a short summary.
With ``[offsets_only] calibration = ...`` only the offsets are re-estimated from
the standing poses and everything else is kept (report Sec. V). A config with a
``[validation]`` table runs the diagnosis' withheld-effect validation instead.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
import tomllib
from dataclasses import replace
from pathlib import Path

import matplotlib
import numpy as np
from threadpoolctl import threadpool_limits

from .calibration import Calibration
from .calibration_run import CalibrationRun
from .config import RunConfig, load_config
from .errors import ConfigError, FtcalError, OutputError
from .correct import offsets_frame
from .data import DataFormatError, Dataset, read_dataset
from .diagnose.validate import run_validation
from .pipeline import calibrate, stage
from .report import write_report
from .sim import SimConfig, simulate, write_simulation
from .tracking import log_changes

COVARIANCE_FILE = "calibration_cov.npz"   # beside calibration.json, named in its meta.covariance_file

log = logging.getLogger("ftcal_nlp.run")


class OutputExistsError(OutputError):
    """The output folder holds an earlier result and ``--force`` was not given."""


def prepare_output(folder: Path, force: bool, *, create: bool = True) -> None:
    """Refuse to write into a non-empty output folder unless ``force``; create it (unless ``create`` is false:
    a run creates it only once it has a result, so that a failed run leaves no trace)."""
    if folder.exists() and any(folder.iterdir()) and not force:
        raise OutputExistsError(f"{folder} exists and is not empty; pass --force to overwrite it")
    if create:
        folder.mkdir(parents=True, exist_ok=True)


def load_or_simulate(cfg: RunConfig, force: bool) -> tuple[Dataset, Calibration | None]:
    """The dataset of the config: read from the manifest, or simulated (and written) first."""
    if cfg.manifest is not None and cfg.manifest.is_file():
        ds = read_dataset(cfg.manifest)
        truth_path = cfg.manifest.parent / "truth.json"
        # a section-5 truth.json (free loads) is not a calibration of the hexapod layout: kept out of the comparison
        truth = (Calibration.load(truth_path, mass_kg=ds.robot.mass_kg, g=ds.robot.g)
                 if truth_path.is_file() and '"legs"' in truth_path.read_text() else None)
        return ds, truth
    if cfg.simulate is None:
        raise DataFormatError(f"{cfg.manifest}: file not found (and no [simulate] table to generate it)")
    folder = cfg.simulate_dir or (cfg.manifest.parent if cfg.manifest is not None else cfg.output_dir / "dataset")
    if cfg.simulate.get("kind", "hexapod") != "hexapod":  # a free load (DATA_FORMAT.md section 5): sim/free
        from .sim.free import simulate_to_folder

        try:
            manifest = simulate_to_folder(cfg.simulate, folder, overwrite=force)
        except ValueError as exc:
            raise ConfigError(f"{cfg.path} [simulate]: {exc}") from exc
        log.info("simulated dataset written to %s", manifest.parent)
        return read_dataset(manifest), None
    sim_cfg = SimConfig.from_dict(cfg.simulate)
    res = simulate(sim_cfg)
    manifest = write_simulation(res, folder, overwrite=force)
    log.info("simulated dataset written to %s", manifest.parent)
    return read_dataset(manifest), res.truth


def run(cfg: RunConfig, *, force: bool = False) -> CalibrationRun:
    """Run the pipeline of ``cfg`` and write every output into ``cfg.output_dir`` (nothing when it fails)."""
    prepare_output(cfg.output_dir, force, create=False)
    t0 = time.perf_counter()
    ds, truth = load_or_simulate(cfg, force)
    t_load = time.perf_counter() - t0
    log.info("%d recordings: %s", len(ds.recordings), ", ".join(f"{r.name} ({r.kind}, {r.n} rows)" for r in ds.recordings))
    prior = None
    if cfg.offsets_only.calibration is not None:
        prior = Calibration.load(cfg.offsets_only.calibration, mass_kg=ds.robot.mass_kg, g=ds.robot.g)
    res = calibrate(ds, cfg.settings, offsets_only=prior)
    res.truth = truth
    res.timings = {"load": t_load, **res.timings}
    cov_meta = {"covariance_file": COVARIANCE_FILE} if res.uncertainty is not None else {}
    res.calibration = replace(res.calibration, meta={"config": str(cfg.path), **res.calibration.meta, **cov_meta})
    prepare_output(cfg.output_dir, force)
    with stage("write calibration", res.timings):
        res.calibration.save(cfg.output_dir / "calibration.json")
        if res.uncertainty is not None:
            res.uncertainty.save(cfg.output_dir / COVARIANCE_FILE)
    with stage("write corrected", res.timings):
        write_corrected(res, cfg.output_dir)
    if res.diagnosis is not None:
        (cfg.output_dir / "diagnosis.json").write_text(json.dumps(res.diagnosis.to_json_dict(), indent=1))
        if res.diagnosis.joint is not None and res.diagnosis.joint.calibration is not None:
            # the calibration refit with the named effect: `correct` applies the effect's corrections
            effect_calibration(res).save(cfg.output_dir / "calibration_with_effect.json")
            for note in res.diagnosis.joint.notes:
                log.warning("joint refit with %s: %s", res.diagnosis.effect, note)
    with stage("report", res.timings):
        if res.free_loads is not None:  # the report's sections for free loads come with issue 22b: the summary for now
            skipped = "".join(f"* {n}\n" for n in res.notes if "skipped" in n)
            (cfg.output_dir / "report.md").write_text(f"```\n{res.free_loads.summary().as_text()}\n```\n{skipped}")
        else:
            write_report(res, cfg.output_dir)
    print(summary_text(res, cfg))
    return res


def effect_calibration(res: CalibrationRun) -> Calibration:
    """The calibration refit with the diagnosis' named effect, as ``calibration_with_effect.json`` holds it.

    The joint fit's own covariance of the calibration parameters is not formed: where the joint
    calibration has the calibration's error model, the calibration's covariance file (same
    parameters, same data) stands in for it (``meta.covariance_note`` says so), rather than none."""
    cal = res.diagnosis.joint.calibration
    if res.uncertainty is not None and cal.model == res.calibration.model:
        cal = replace(cal, meta={**cal.meta, "covariance_file": COVARIANCE_FILE,
                                 "covariance_note": "the calibration's, before the joint refit with the effect"})
    return cal


def write_corrected(res: CalibrationRun, folder: Path) -> None:
    """``corrected/<name>.csv`` for every walking recording and, where offsets were tracked,
    ``tracked_offsets/<name>.csv`` (``correct.offsets_frame``)."""
    (folder / "corrected").mkdir(exist_ok=True)
    for name, df in res.corrected.items():
        df.to_csv(folder / "corrected" / f"{name}.csv", index=False, float_format="%.7g")
    if res.tracked_offsets:
        (folder / "tracked_offsets").mkdir(exist_ok=True)
    for name, tr in res.tracked_offsets.items():
        offsets_frame(res.corrected[name]["t"].to_numpy(), tr).to_csv(folder / "tracked_offsets" / f"{name}.csv", index=False, float_format="%.7g")
        log_changes(tr)


def summary_text(res: CalibrationRun, cfg: RunConfig) -> str:
    """The short end-of-run summary: model, residual before/after, where the report is."""
    lines = [f"ftcal_nlp: {cfg.path}"]
    if res.poses is not None:
        lines.append("poses: " + " -> ".join(f"{v} {k}" for k, v in res.poses.counts.items()))
    lines.append(f"model: {res.calibration.model}")
    if res.standing is not None:
        r = np.asarray(res.standing.residuals)
        lines.append("calibrated total-wrench residual RMS (fx fy fz tx ty tz): " + " ".join(f"{v:.3g}" for v in np.sqrt((r**2).mean(0))))
    if res.free_loads is not None:
        for k, r in res.free_loads.legs.items():
            lines.append(f"{k}: {r.n_used} quasi-static samples; residual RMS (fx fy fz tx ty tz): " + " ".join(f"{v:.3g}" for v in r.rms))
            lines += [f"  {n}" for n in r.identifiability()]
    try:
        if res.poses is None:
            raise ValueError("no standing poses")
        naive = res.naive_total_residuals()
        lines.append("naive-tare total-wrench residual RMS (fx fy fz tx ty tz): " + " ".join(f"{v:.3g}" for v in np.sqrt((naive**2).mean(0))))
    except (ValueError, IndexError) as exc:
        lines.append(f"naive-tare residual not computed: {exc}")
    if res.diagnosis is not None:
        lines.append(f"diagnosis: {res.diagnosis.verdict}" + (f" ({res.diagnosis.effect})" if res.diagnosis.effect else ""))
    lines.append("stage times: " + ", ".join(f"{k} {v:.2f}s" for k, v in res.timings.items()))
    lines.append(f"report: {cfg.output_dir / 'report.md'}")
    return "\n".join(lines)


def _is_validation_config(path: str) -> bool:
    p = Path(path)
    if not p.is_file():
        return False
    try:
        return "validation" in tomllib.loads(p.read_text())
    except tomllib.TOMLDecodeError:
        return False  # load_config reports it


def _run_validation(path: str, force: bool, run_validation) -> int:
    """A ``[validation]`` config: the withheld-effect validation of the diagnosis (issue 7)."""
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
    matplotlib.use("Agg")  # files only; the entry point, not the library, picks the backend
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s", datefmt="%H:%M:%S")
    try:
        if _is_validation_config(args.config):
            with threadpool_limits(limits=1):
                return _run_validation(args.config, args.force, run_validation)
        cfg = load_config(args.config)
        # many small LAPACK calls: threaded BLAS only adds contention on a few cores
        with threadpool_limits(limits=1):
            run(cfg, force=args.force)
    except (FtcalError, FileExistsError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
