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
import os
import time
import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from .core.calibration import Calibration
from .calibration_run import CalibrationRun
from .core.checks import residual_note
from .config import RunConfig, load_config
from .core.errors import ConfigError, DataFormatError, FtcalError
from .core.outdir import OutputExistsError, OutputFolder, check_apart, dataset_inputs, write_guarded  # noqa: F401  (OutputExistsError: re-exported)
from .correct import offsets_frame
from .core.csvout import write_csv
from .core.data import Dataset, read_dataset
from .truth import LoadTruth
from .diagnose.validation import run_validation
from .pipeline import calibrate, stage
from .report import write_report
from .sim import SimConfig, simulate, write_simulation
from .correct.tracking import log_changes
from .estimate.uncertainty import free_load_covariance

COVARIANCE_FILE = "calibration_cov.npz"   # beside calibration.json, named in its meta.covariance_file

log = logging.getLogger("ftcal_nlp.run")


def load_or_simulate(cfg: RunConfig, force: bool) -> tuple[Dataset, LoadTruth | Calibration | None]:
    """The dataset of the config: read from the manifest, or simulated (and written) first; with its truth
    (``truth.json`` beside the manifest: a Calibration for a hexapod, a ``truth.LoadTruth`` for a free load).

    ``[simulate] kind = "payload" | "urdf_leg"`` simulates a section-5 dataset (``sim.free``); no ``kind``
    (or ``"hexapod"``) the BigAnt one."""
    from .sim.free import FREE_SIM_KINDS, simulate_free, write_free_load
    from .sim.free.writer import free_load_files
    from .sim.writer import simulation_files
    from .sim.free import config_from_dict as free_config
    from .truth import load_truth, load_truth_from_dict

    if cfg.manifest is not None and cfg.manifest.is_file():
        ds = read_dataset(cfg.manifest)
        truth_path = cfg.manifest.parent / "truth.json"
        truth = load_truth(truth_path, mass_kg=ds.robot.mass_kg, g=ds.robot.g, robot=ds.robot) if truth_path.is_file() else None
        return ds, truth
    if cfg.simulate is None:
        raise DataFormatError(f"{cfg.manifest}: file not found (and no [simulate] table to generate it)", path=cfg.manifest)
    folder = cfg.simulate_dir or (cfg.manifest.parent if cfg.manifest is not None else cfg.output_dir / "dataset")
    check_simulation_target(cfg, folder)
    if cfg.simulate.get("kind", "hexapod") in FREE_SIM_KINDS:
        try:
            free = simulate_free(free_config(cfg.simulate))
        except ValueError as exc:
            raise ConfigError(f"{cfg.path}: {exc}", path=cfg.path, key="simulate") from None
        manifest = write_guarded(folder, free_load_files(free), lambda: write_free_load(free, folder, overwrite=True), force=force)
        log.info("simulated %s dataset written to %s", free.config.kind, manifest.parent)
        ds = read_dataset(manifest)
        return ds, load_truth_from_dict(free.truth, manifest.parent / "truth.json", ds.robot)
    if cfg.simulate.get("kind", "hexapod") != "hexapod":
        raise ConfigError(f"{cfg.path} [simulate]: kind = {cfg.simulate['kind']!r}; known kinds: "
                          f"{['hexapod', *sorted(FREE_SIM_KINDS)]}", path=cfg.path, key="simulate.kind")
    sim_cfg = SimConfig.from_dict(cfg.simulate, where=f"{cfg.path} [simulate]")
    res = simulate(sim_cfg)
    manifest = write_guarded(folder, simulation_files(res), lambda: write_simulation(res, folder, overwrite=True), force=force)
    why = f"[data].manifest {cfg.manifest} not found: " if cfg.manifest is not None else ""
    log.warning("%s: %sthe [simulate] table was simulated into %s; everything below is of SIMULATED data",
                cfg.path, why, manifest.parent)
    return read_dataset(manifest), res.truth


def check_simulation_target(cfg: RunConfig, folder: Path) -> None:
    """A missing manifest is simulated only where the ``[simulate]`` table writes it, into a folder without
    recordings: a manifest path with a typo must not calibrate simulated data in place of the dataset named."""
    if cfg.manifest is None:
        return
    target = folder / "dataset.toml"
    if target.absolute() != cfg.manifest.absolute():
        raise ConfigError(
            f"{cfg.path} [data].manifest: {cfg.manifest} not found; the [simulate] table writes {target}, so the run would "
            "calibrate simulated data instead of the dataset named: a typo in the path? (to simulate, point [data].manifest "
            "at the simulated dataset.toml)", path=cfg.path, key="data.manifest")
    if folder.is_dir() and any(p.suffix in (".csv", ".parquet", ".toml") for p in folder.iterdir()):
        raise ConfigError(
            f"{cfg.path} [data].manifest: {cfg.manifest} not found, but {folder} holds recordings or tables; expected the "
            "manifest of that dataset (a typo in its name?), or an empty folder to simulate into", path=cfg.path, key="data.manifest")


def data_origin(cfg: RunConfig, truth: Calibration | LoadTruth | None) -> str | None:
    """How the dataset came to be, when simulated (a ``truth.json`` beside the manifest, or the ``[simulate]``
    table of this run), else None."""
    if truth is None:
        return None
    if cfg.manifest is not None and (cfg.manifest.parent / "truth.json").is_file():
        return f"simulated: the dataset of {cfg.manifest} comes with its truth (truth.json beside it)"
    return f"simulated by this run from the [simulate] table of {cfg.path}"


def input_paths(cfg: RunConfig) -> dict[str, Path]:
    """What the run reads, found cheaply (the manifest and robot.toml parsed as TOML, no recording read): the
    config, the dataset's folder and manifest, robot.toml, the URDF, every recording, the simulated dataset's
    folder, an ``[offsets_only] calibration``. Keys say what each is, for the error of :func:`outdir.check_apart`."""
    out: dict[str, Path] = {"config file": cfg.path}
    if cfg.offsets_only.calibration is not None:
        out["[offsets_only] calibration"] = cfg.offsets_only.calibration
    if cfg.simulate_dir is not None:
        out["simulated dataset's folder"] = cfg.simulate_dir
    if cfg.manifest is not None:
        out.update(dataset_inputs(cfg.manifest))
    out.update({f"[holdout] recording {p}": p for p in cfg.holdout.recordings})
    return out


def run(cfg: RunConfig, *, force: bool = False, quiet: bool = False) -> CalibrationRun:
    """Run the pipeline of ``cfg`` and write every output into ``cfg.output_dir`` (nothing when it fails).

    Before anything is read or fitted, the output folder is checked apart from the inputs (not one of them,
    not above one: :func:`input_paths`), refused when it holds files the tool did not write or (without
    ``force``) an earlier result, writable, and locked; the outputs are written into a staging folder beside
    it and swapped in whole at the end (``outdir.py``): a failed or interrupted run leaves an earlier result
    exactly as it was, and ``force`` replaces only the files the tool wrote. The summary is printed unless ``quiet``
    (``-q``: only warnings and errors; the summary is in report.md)."""
    inputs = input_paths(cfg)
    log.debug("inputs: %s", "; ".join(f"{k} {v}" for k, v in inputs.items()))
    check_apart(cfg.output_dir, inputs)
    with OutputFolder(cfg.output_dir, force=force) as out:
        folder = out.path
        assert folder is not None, "OutputFolder.__enter__ made the staging folder"
        if cfg.manifest is None and cfg.simulate_dir is None:  # the simulated dataset goes with the results
            cfg = replace(cfg, simulate_dir=folder / "dataset")
        res = _run_into(cfg, force, folder)
        out.commit()
    if not quiet:
        print(summary_text(res, cfg))
    return res


def _run_into(cfg: RunConfig, force: bool, folder: Path) -> CalibrationRun:
    """The run of ``cfg`` with its outputs written into ``folder`` (the staging folder of :func:`run`)."""
    log.debug("writing into the staging folder %s", folder)
    t0 = time.perf_counter()
    ds, truth = load_or_simulate(cfg, force)
    t_load = time.perf_counter() - t0
    log.info("%d recordings: %s", len(ds.recordings), ", ".join(f"{r.name} ({r.kind}, {r.n} rows)" for r in ds.recordings))
    if cfg.holdout.recordings:   # [holdout]: checked before the fit, run after the report
        from .holdout import check_run_holdout

        check_run_holdout(cfg.holdout, ds)
    prior = None
    if cfg.offsets_only.calibration is not None:
        prior = Calibration.load(cfg.offsets_only.calibration, mass_kg=ds.robot.mass_kg, g=ds.robot.g)
    res = calibrate(ds, cfg.settings, offsets_only=prior)
    # a free-load run's covariance file holds the estimator's (loads.calibrated reads it back)
    covariance = res.uncertainty if res.uncertainty is not None else free_load_covariance(res.free_loads)
    cov_meta: dict[str, object] = {"covariance_file": COVARIANCE_FILE} if covariance is not None else {}
    origin = data_origin(cfg, truth)
    cov_meta["data"] = {"simulated": origin is not None, **({"origin": origin} if origin else {})}
    # a new frozen run with what only the command line knows: the truth, the load time, the config, the notes; the
    # stages below are timed into `timings`, given to a new run before the report (which shows them) and at the end
    timings = {"load": t_load, **res.timings}
    res = replace(res, truth=truth, timings=dict(timings),
                  calibration=replace(res.calibration, meta={"config": str(cfg.path), **res.calibration.meta, **cov_meta}))
    res = replace(res, notes=_issue_notes(res, origin))
    with stage("write calibration", timings):
        res.calibration.save(folder / "calibration.json")
        if covariance is not None:
            covariance.save(folder / COVARIANCE_FILE)
    if res.corrected or res.tracked_offsets:   # no stage (nor folder) where nothing is corrected: a free-load run
        with stage("write corrected", timings):
            write_corrected(res, folder)
    if res.diagnosis is not None:
        (folder / "diagnosis.json").write_text(json.dumps(res.diagnosis.to_json_dict(), indent=1))
        last = last_joint(res.diagnosis)
        if last is not None and last.calibration is not None:
            # the calibration refit with the named effects (the chain's last joint refit): `correct` applies them all
            effect_calibration(res).save(folder / "calibration_with_effect.json")
            for note in dict.fromkeys((*res.diagnosis.joint.notes, *last.notes)):
                log.warning("joint refit with %s: %s", last.effect if note in last.notes else res.diagnosis.effect, note)
        elif res.free_loads is not None:
            write_free_effect_calibration(res, folder)
    res = replace(res, timings=dict(timings))
    with stage("report", timings):
        write_report(res, folder)
    if cfg.holdout.recordings:   # validation on a later session: holdout/ in the output folder
        from .holdout import run_holdout

        with stage("holdout", timings):
            run_holdout(cfg.holdout, folder, cfg.output_dir)
    return replace(res, timings=dict(timings))


def _issue_notes(res: CalibrationRun, origin: str | None) -> tuple[str, ...]:
    """The run's notes with those of the command line: simulated data first; a standing residual far
    above the sensor noise last (both logged)."""
    front: list[str] = []
    back: list[str] = []
    if origin is not None:
        log.info("the dataset is %s", origin)
        front.append(f"The dataset is {origin}.")
    if res.standing is not None and res.uncertainty is not None:
        note = residual_note(res.standing.residuals, res.uncertainty.noise, res.calibration)
        if note:
            log.warning("%s", note)
            back.append(note)
    return (*front, *res.notes, *back)


def last_joint(d):
    """The diagnosis' last joint refit: the hexapod chain's last link's (every named effect fitted together with the
    calibration, ``diagnose/hexchain.py``), else the named effect's (``d.joint``); None without one."""
    if d is None or d.joint is None:
        return None
    links = d.chain.links if getattr(d, "chain", None) is not None else []
    return links[-1].joint if links else d.joint


def effect_calibration(res: CalibrationRun) -> Calibration:
    """The calibration refit with the diagnosis' named effects, as ``calibration_with_effect.json`` holds it: the
    last joint refit (:func:`last_joint`; ``meta.effect`` names every effect fitted, ``members`` when several).

    The joint fit's own covariance of the calibration parameters is not formed: where the joint
    calibration has the calibration's error model, the calibration's covariance file (same
    parameters, same data) stands in for it (``meta.covariance_note`` says so), rather than none. The
    effects' parameters carry their own joint covariance (``meta.effect.eta_cov``, cross-effect terms included)."""
    j = last_joint(res.diagnosis)
    cal = j.calibration
    what = "the effect" if "+" not in j.effect else "the effects " + ", ".join(j.effect.split("+"))
    if res.uncertainty is not None and cal.model == res.calibration.model:
        cal = replace(cal, meta={**cal.meta, "covariance_file": COVARIANCE_FILE,
                                 "covariance_note": f"the calibration's, before the joint refit with {what}: it leaves out "
                                                    "the calibration parameters' correlations with the effects' "
                                                    "(meta.effect.eta_cov holds the effects' own)"})
    elif res.uncertainty is not None:
        # another error model: the calibration's covariance is of other parameters; say why none is named
        cal = replace(cal, meta={**cal.meta, "covariance_note": (
            f"none: the joint refit with {what} chose the error model {cal.model!r}, the calibration's covariance file is "
            f"of {res.calibration.model!r}; standard errors carry the sensor noise and meta.effect.eta_cov only")})
    return cal


def write_free_effect_calibration(res: CalibrationRun, folder: Path) -> None:
    """A free-load run whose diagnosis named effects: ``calibration_with_effect.json`` (the free-load calibration refit
    jointly with the chain's effects, ``meta.effect``: every transducer's members, their parameters and the session's
    reference) and its joint covariance file (``diagnose/free_effect_file.py``); nothing when none was named."""
    from .diagnose.free_effect_file import COVARIANCE_FILE as EFFECT_COVARIANCE_FILE, free_effect_calibration

    out = free_effect_calibration(res)
    if out is None:
        return
    cal, cov = out
    cal.save(folder / "calibration_with_effect.json")
    cov.save(folder / EFFECT_COVARIANCE_FILE)
    log.info("calibration_with_effect.json: the free loads refit with %s (correct applies them)", cal.meta["effect"]["name"])


def write_corrected(res: CalibrationRun, folder: Path) -> None:
    """``corrected/<name>.csv`` for every walking recording (no folder without one) and, where offsets were tracked,
    ``tracked_offsets/<name>.csv`` (``correct.offsets_frame``)."""
    if res.corrected:  # a free-load run corrects no walk: no empty folder
        (folder / "corrected").mkdir(exist_ok=True)
    for name, df in res.corrected.items():
        write_csv(df, folder / "corrected" / f"{name}.csv")  # t and every value to the last bit (csvout.py)
    if res.tracked_offsets:
        (folder / "tracked_offsets").mkdir(exist_ok=True)
    for name, tr in res.tracked_offsets.items():
        write_csv(offsets_frame(res.corrected[name]["t"].to_numpy(), tr), folder / "tracked_offsets" / f"{name}.csv")
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
        for k, fit in res.free_loads.legs.items():
            lines.append(f"{k}: {fit.n_used} quasi-static samples; residual RMS (fx fy fz tx ty tz): " + " ".join(f"{v:.3g}" for v in fit.rms))
            lines += [f"  {n}" for n in fit.identifiability()]
    if res.poses is not None:  # a free-load dataset has no standing poses: nothing to compare
        try:
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


def _run_validation(path: str, force: bool, run_validation, output: Path | None = None) -> int:
    """A ``[validation]`` config: the withheld-effect validation of the diagnosis (issue 7)."""
    p = Path(path)
    d = tomllib.loads(p.read_text())
    out = d.get("output", {}).get("dir")
    if output is None and not isinstance(out, str):
        raise ConfigError(f"{p} [output].dir: expected a path string for the output folder")
    folder = output if output is not None else p.parent / os.path.expanduser(out)
    check_apart(folder, {"config file": p})
    with OutputFolder(folder, force=force) as staged:
        try:
            run_validation(d["validation"], staged.path, calibrate)
        except ValueError as exc:
            raise ConfigError(f"{p}: {exc}") from exc
        staged.commit()
    return 0


CONFIG_HELP = """\
config keys: README.md ("Use": the minimal config and the main keys), problems/bigant_sim.toml (an annotated
config), ftcal_nlp/config.py (sections and their validation) and ftcal_nlp/core/settings.py (every key with its
default and meaning: [hanging], [standing], [standing.poses], [selection], [diagnose], [correct]).
"""


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    from .cli import add_common, guarded, parse, setup

    ap = argparse.ArgumentParser(prog=prog or "python -m ftcal_nlp.run", description="Calibrate six-axis force/torque transducers from a dataset: "
                                 "the legs of a walking robot (hanging, standing, walking recordings) or a free load "
                                 "(a wrist sensor's tool, a URDF leg, an arm's tool: held orientations or joint poses). "
                                 "Writes calibration.json and a report; contact wrenches of walking recordings in corrected/.",
                                 epilog=CONFIG_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("config", help="run config (TOML), e.g. problems/bigant_sim.toml")
    add_common(ap, output_help="output folder (default: the config's [output] dir)",
               old_force=("--overwrite",), force_help="replace an earlier result the tool wrote in the output folder (files it did not write are kept)")
    args = parse(ap, argv)
    setup(args)
    return guarded(lambda: _main(args))


def _main(args: argparse.Namespace) -> int:
    output = Path(os.path.expanduser(args.output)) if args.output else None
    if _is_validation_config(args.config):
        with threadpool_limits(limits=1):
            return _run_validation(args.config, args.force, run_validation, output)
    cfg = load_config(args.config)
    if output is not None:
        cfg = replace(cfg, output_dir=output)
    check_models(cfg)
    # many small LAPACK calls: threaded BLAS only adds contention on a few cores
    with threadpool_limits(limits=1):
        run(cfg, force=args.force, quiet=args.quiet)
    return 0


def check_models(cfg: RunConfig) -> None:
    """The config's error model(s) exist (a registered name, an importable ``module:Class``, a plug-in file
    that defines the class): a :class:`ConfigError` before any data are read or fitted."""
    from .models import resolve

    st = cfg.settings.standing
    names = [("model", st.model)] if st.model != "auto" else [("candidates", c) for c in st.candidates]
    for key, name in names:
        try:
            resolve(name)
        except (FtcalError, ValueError, ImportError, SyntaxError, AttributeError, TypeError, OSError) as exc:
            raise ConfigError(f"{cfg.path} [standing].{key}: {exc}", path=cfg.path, key=f"standing.{key}") from exc


if __name__ == "__main__":
    raise SystemExit(main())
