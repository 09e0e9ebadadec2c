"""Validate a free-load calibration on a later session: where in gravity's directions it holds, where it does not.

``python -m ftcal_nlp holdout calibration.json later.csv [more.csv ...] -o DIR [--alpha 0.01] [--gravity-body X Y Z]``

The recordings are of the free load touching nothing (``DATA_FORMAT.md`` section 5: a wrist payload with ``qw..qz``
or ``gx..gz``, a URDF leg or an arm read through ``q_{joint}``), taken after the calibration. Each is corrected with
the calibration (``correct.free.contact_frame``: the contact wrench and its se per sample, the same checks as
``correct``); rows a stuck or clipped channel flags (``{X}_fault``) are left out. Per sample, gravity's direction in
the transducer's frame (the calibration's estimated frame: the nominal or URDF rotation at the sample's joints times
the mounting rotation, its world tilt applied) places it in one of 26 regions; ``freeload/holdout.py`` has the
statistics and the test. Writes into ``DIR`` (beside whatever is there; ``outdir.write_guarded``): ``holdout.csv``
(a row per transducer and region), ``holdout.md`` (the verdict, naming the regions where the calibration does not
hold and a pose of each) and ``holdout.png`` (error per region with the test's limits; a Mollweide map of the
gravity directions coloured by each region's largest mean / se).

A run does the same on its own calibration where its config has ``[holdout] recordings = ["later.csv", ...]``
(``config.HoldoutSettings``), into ``holdout/`` of its output folder: calibrate on one session, validate on the other.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import tomllib
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from .core.data import GRAVITY_COLUMNS, JOINT_PREFIX, QUAT_COLUMNS, WRENCH_COMPONENTS, read_table
from .core.errors import ConfigError, DataFormatError
from .estimate.freeload.holdout import ALPHA, Holdout, LegSamples, holdout, holdout_markdown, holdout_table, plot_holdout

log = logging.getLogger(__name__)

FILES = ("holdout.csv", "holdout.md", "holdout.png")
RUN_FOLDER = "holdout"   # a run's holdout outputs, inside its output folder


def _free_loads(cal_path: Path) -> dict:
    from .correct.calibrated import read_calibration

    cal = read_calibration(cal_path)
    if not isinstance(cal, dict):
        raise ConfigError(f"{cal_path}: holdout validates free-load calibrations (DATA_FORMAT.md section 5: a wrist payload, "
                          "a URDF leg, an arm); this one holds hexapod legs, whose later recordings walk (correct gives "
                          "their contact wrenches)", path=cal_path)
    return cal


def _check_recording(cal: dict, df: pd.DataFrame, where: str) -> None:
    """What ``correct`` would take but a validation cannot use: a table ``correct`` wrote (its se columns)."""
    done = [f"{k}_fx_se" for k in cal if f"{k}_fx_se" in df.columns]
    if done:
        raise DataFormatError(f"{where}: column {done[0]}: this is a corrected table (the output of correct); expected the "
                              "raw recording of the free load touching nothing (readings, orientation or joints)",
                              path=where, column=done[0])


def gravity_in_sensor(p, sub: pd.DataFrame, where: str, base: np.ndarray | None) -> np.ndarray:
    """Unit direction of gravity (N, 3) in the estimated ft frame of calibration ``p`` for the numeric rows ``sub``:
    ``R_B,ft^T g_B``, ``R_B,ft`` the payload's fixed rotation or the URDF's at the rows' joints times the mounting
    rotation, ``g_B`` with the calibration's world tilt (``correct``'s own functions)."""
    from .correct.recording import gravity_of_frame, orientation_of_frame
    from .correct.calibrated import PayloadCalibration, tilted_gravity

    g_B = tilted_gravity(p, gravity_of_frame(sub, p.g, where, base), orientation_of_frame(sub))[0]
    if isinstance(p, PayloadCalibration):
        g = g_B @ p.R_B_ft
    else:
        n = len(sub)
        q = {j: sub[f"{JOINT_PREFIX}{j}"].to_numpy(float) if f"{JOINT_PREFIX}{j}" in sub.columns else np.zeros(n)
             for j in p.joints}
        g = np.einsum("nji,nj->ni", p.load.nominal_rotation(q, n) @ p.E, g_B)
    return g / np.linalg.norm(g, axis=1, keepdims=True)


def samples_used(cal_path: Path | None) -> dict[str, int]:
    """Per transducer the samples its calibration rests on (``samples_used`` of ``calibration.json``), where stored."""
    try:
        legs = json.loads(Path(cal_path).read_text()).get("legs", {}) if cal_path is not None else {}
    except (OSError, ValueError, AttributeError):
        return {}
    return {k: int(v["samples_used"]) for k, v in legs.items() if isinstance(v, dict) and isinstance(v.get("samples_used"), int)}


def leg_samples(cal: dict, path: Path, source: int, gravity_body=None, cal_path: Path | None = None) -> dict[str, LegSamples]:
    """Per transducer of the free-load calibration ``cal`` the samples of recording ``path`` (number ``source``):
    contact wrench and se (``correct.free.contact_frame``), the calibration's noise sd, gravity in the sensor's frame,
    row numbers, times and pose columns; ``cal_path`` the calibration's file (its ``samples_used``)."""
    from .correct.free import contact_frame
    from .correct.recording import base_gravity

    where = str(path)
    df = read_table(path)
    _check_recording(cal, df, where)
    out = contact_frame(cal, df, where, gravity_body)
    t_all = pd.to_numeric(df["t"], errors="coerce").to_numpy(float)
    rows = np.flatnonzero(np.isin(t_all, out["t"].to_numpy(float)))
    if len(rows) != len(out):   # t strictly increasing among kept rows; a dropped row repeating a kept time
        raise DataFormatError(f"{where}: column 't' repeats a time on a row the correction dropped; expected one row per "
                              "sample", path=where, column="t")
    joints = [f"{JOINT_PREFIX}{j}" for p in cal.values() for j in p.joints]
    pose_cols = [c for c in dict.fromkeys(joints) if c in df.columns]
    pose_cols += [c for c in (*QUAT_COLUMNS, *GRAVITY_COLUMNS) if c in df.columns]
    sub = df.iloc[rows][pose_cols].apply(pd.to_numeric, errors="coerce").reset_index(drop=True)
    base = base_gravity(cal, sub, where, gravity_body)
    n_cal = samples_used(cal_path)
    res = {}
    for k, p in cal.items():
        w = out[[f"{k}_{c}" for c in WRENCH_COMPONENTS]].to_numpy(float)
        se = out[[f"{k}_{c}_se" for c in WRENCH_COMPONENTS]].to_numpy(float)
        ok = np.all(np.isfinite(w), axis=1)
        if f"{k}_fault" in out.columns:
            bad = out[f"{k}_fault"].to_numpy() == 1
            log.warning("%s: %d rows of %s with a stuck or clipped channel left out of the validation", where,
                        int(bad.sum()), k)
            ok &= ~bad
        u = gravity_in_sensor(p, sub, where, base[k])
        res[k] = LegSamples(k, w[ok], se[ok], np.asarray(p.sigma, float), u[ok], np.full(int(ok.sum()), source),
                            rows[ok], out["t"].to_numpy(float)[ok], sub[ok].reset_index(drop=True), n_cal.get(k))
    return res


def _concat(parts: list[LegSamples]) -> LegSamples:
    s0 = parts[0]
    poses = None if s0.poses is None else pd.concat([p.poses for p in parts], ignore_index=True)

    def cat(field: str) -> np.ndarray:
        return np.concatenate([getattr(p, field) for p in parts])

    return LegSamples(s0.leg, cat("w"), cat("se"), s0.sigma, cat("u"), cat("source"), cat("index"), cat("t"), poses,
                      s0.n_cal)


def own_recordings(cal_path: Path) -> list[Path]:
    """The recordings of the dataset the calibration was fitted on, where its ``meta.config`` (a run's config) names
    one that is still there (read as TOML and JSON only); [] otherwise."""
    from .core.outdir import dataset_inputs

    try:
        cfg = Path(json.loads(cal_path.read_text()).get("meta", {}).get("config", ""))
        man = tomllib.loads(cfg.read_text()).get("data", {}).get("manifest") if cfg.is_file() else None
    except (OSError, ValueError, AttributeError):
        return []
    if not isinstance(man, str):
        return []
    return [p for w, p in dataset_inputs(cfg.parent / os.path.expanduser(man)).items() if w.startswith("recording ")]


def validate(cal_path: str | Path, recordings: Sequence[str | Path], *, gravity_body=None,
             alpha: float = ALPHA) -> tuple[Holdout, dict[str, LegSamples]]:
    """The validation of the calibration ``cal_path`` on ``recordings`` (module docstring) and its samples."""
    cal_path = Path(cal_path)
    cal = _free_loads(cal_path)
    own = own_recordings(cal_path)
    parts: dict[str, list[LegSamples]] = {k: [] for k in cal}
    for i, rec in enumerate(map(Path, recordings)):
        if any(rec.exists() and p.exists() and os.path.samefile(rec, p) for p in own):
            log.warning("%s: a recording the calibration %s was fitted on: its errors are smaller than on a later "
                        "session (this checks the fit, it does not validate the calibration)", rec, cal_path)
        for k, s in leg_samples(cal, rec, i, gravity_body, cal_path).items():
            parts[k].append(s)
    return holdout({k: _concat(v) for k, v in parts.items()}, alpha), {k: _concat(v) for k, v in parts.items()}


def write_holdout(cal_path: str | Path, recordings: Sequence[str | Path], folder: Path, *, gravity_body=None,
                  alpha: float = ALPHA, label: str | None = None) -> Holdout:
    """:func:`validate`, then :data:`FILES` written into ``folder`` (created); returns the validation. ``label``: how
    ``holdout.md`` names the calibration (default its path)."""
    h, samples = validate(cal_path, recordings, gravity_body=gravity_body, alpha=alpha)
    folder.mkdir(parents=True, exist_ok=True)
    from .core.csvout import write_csv

    write_csv(holdout_table(h), folder / FILES[0])
    (folder / FILES[1]).write_text(holdout_markdown(h, [str(r) for r in recordings], label or str(cal_path)))
    plot_holdout(h, samples, folder / FILES[2])
    return h


def verdict_lines(h: Holdout) -> list[str]:
    """The verdict in a line per transducer."""
    out = []
    for lh in h.legs.values():
        bad = ", ".join(f"gravity along {r.name} ({r.worst_axis} {r.mean[list(WRENCH_COMPONENTS).index(r.worst_axis)]:.3g}"
                        f" +- {r.mean_se[list(WRENCH_COMPONENTS).index(r.worst_axis)]:.2g})" for r in lh.failing)
        rms = " ".join(f"{v:.2f}" for v in lh.rms_z)
        out.append(f"holdout {lh.leg}: {len(lh.regions)} regions, {lh.n} samples, RMS z {rms} (expected "
                   f"{lh.band[0]:.2f}-{lh.band[1]:.2f}): " + (f"does not hold at {bad}" if bad else "holds in every region"))
    return out


# ----------------------------------------------------------------------------- a run's [holdout]


def check_run_holdout(settings, ds) -> None:
    """Before a run fits anything: its ``[holdout]`` recordings (``settings``: ``config.HoldoutSettings``) suit the
    dataset ``ds``: free loads only, and each recording (its header) carries every transducer's readings."""
    if not settings.recordings:
        return
    legs = list(ds.robot.legs)
    hexa = [k for k in legs if k not in ds.free_load_legs]
    if hexa:
        raise ConfigError(f"[holdout] validates free loads (DATA_FORMAT.md section 5); the dataset's transducers {hexa} "
                          "are hexapod legs: leave [holdout] out", key="holdout.recordings")
    for rec in settings.recordings:
        cols = set(map(str, read_table(rec).columns)) if rec.suffix.lower() == ".parquet" else set(
            pd.read_csv(rec, nrows=0).columns)
        missing = [f"{k}_{c}" for k in legs for c in WRENCH_COMPONENTS if f"{k}_{c}" not in cols]
        if missing:
            raise DataFormatError(f"{rec}: [holdout] recording without the readings {missing[:3]}{' ...' if len(missing) > 3 else ''} "
                                  f"of the dataset's transducers {legs}", path=rec, column=missing[0])


def run_holdout(settings, folder: Path, target: Path | None = None) -> Holdout | None:
    """A run's ``[holdout]``: its calibration (``folder/calibration.json``) validated on the recordings, written into
    ``folder/holdout/``; None without recordings. ``target``: the output folder ``folder`` stages (named in
    ``holdout.md``)."""
    if not settings.recordings:
        return None
    h = write_holdout(folder / "calibration.json", list(settings.recordings), folder / RUN_FOLDER,
                      gravity_body=settings.gravity_body, alpha=settings.alpha,
                      label=str((target or folder) / "calibration.json"))
    for line in verdict_lines(h):
        (log.info if h.holds else log.warning)("%s", line)
    return h


# ----------------------------------------------------------------------------- command line


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    from .cli import add_common, guarded, parse, setup

    ap = argparse.ArgumentParser(prog=prog or "python -m ftcal_nlp.holdout", description=__doc__.splitlines()[0])
    ap.add_argument("calibration", help="calibration.json of a free-load run (its calibration_cov.npz beside it)")
    ap.add_argument("recordings", nargs="+", help="later recording(s) of the free load touching nothing (CSV or Parquet)")
    ap.add_argument("--gravity-body", nargs=3, type=float, metavar=("X", "Y", "Z"),
                    help="a fixed base's gravity direction in B for recordings without qw..qz / gx..gz (default: the "
                         "calibration's gravity_body)")
    ap.add_argument("--alpha", type=float, default=ALPHA,
                    help="the test's size: the chance that a calibration that holds fails in some region (default 0.01)")
    add_common(ap, output_help="output folder for holdout.csv, holdout.md, holdout.png", output_required=True)
    args = parse(ap, argv)
    setup(args)
    return guarded(lambda: _main(args), extra=(ValueError,))


def _main(args) -> int:
    from .core.outdir import calibration_inputs, check_files_apart, output_path, write_guarded

    if not 0 < args.alpha < 1:
        raise ConfigError(f"--alpha {args.alpha}: expected a number between 0 and 1 (e.g. 0.01)", key="--alpha")
    cal_path = Path(os.path.expanduser(args.calibration))
    recs = [Path(os.path.expanduser(r)) for r in args.recordings]
    inputs = {**calibration_inputs(cal_path), **{f"recording {r}": r for r in recs}}
    check_files_apart(args.output, FILES, inputs)
    out = output_path(args.output)
    h = write_guarded(out, FILES, lambda: write_holdout(cal_path, recs, out, gravity_body=args.gravity_body,
                                                       alpha=args.alpha), force=args.force, kind="holdout")
    if not args.quiet:
        print("\n".join(verdict_lines(h)))
        print(f"wrote {', '.join(str(out / f) for f in FILES)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
