#!/usr/bin/env python3
"""The sensor's own matrix (``[free_load] sensor_matrix``, issue 33) on the real ATI Axia80 wrist sessions.

Usage (after ``convert_leledeyuan00_ati.py SRC/datas OUT``; the data are not redistributable, keep OUT outside
the repository or in the git-ignored ``data/``)::

    python data/external/ati_sensor_matrix.py OUT [--sessions timeseries,poses100,poses7] [--modes force,full,force:0]

What it prints, per session and mode (``"none"``: the factory matrix; ``"force"``: the 3x3 force block refitted;
``"full"``: the 6x6; ``"force:0"``: the force block with the ridge grid ``[0]``, the unregularised estimate, to
compare the sessions' matrices), all else the package's defaults (nothing here is tuned to these data):

1. the fit: mass, CoM z, the ridge weight kept by the package's in-session held-out choice, its held-out scores,
   the residual RMS with the factory matrix and with ``C``, and the matrix's named combinations the data
   determine (value +- se; ``freeload.sensor_matrix.named_combinations``);
2. across sessions (their Table III, Andrade Chavez et al. 2016): calibrate on session A, per-axis RMS error on
   session B of the fit without the matrix and with it, the latter in % of the former (factory = 100 %)
   (``validate_across_sessions``: B's own offset, A's load, A's world tilt, A's mounting rotation);
3. the same pairs with B's load refitted: B's readings multiplied by A's ``C`` then fitted with the factory matrix,
   against B fitted as read (per-axis residual RMS on B's quasi-static samples, %). Needed here because the three
   sessions' payload masses disagree by up to 12 % (another gripper state, drift; REAL_DATA.md): in table 2 that
   mismatch dominates both columns, table 3 asks only whether A's gains and cross-couplings carry over.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

from ftcal_nlp.core.data import Dataset, read_dataset
from ftcal_nlp.estimate.freeload import fit_free_loads
from ftcal_nlp.estimate.freeload.sensor_matrix import WRENCH, validate_across_sessions
from ftcal_nlp.core.settings import FreeLoadSettings

LEG = "wrist"
SESSIONS = ("timeseries", "poses100", "poses7")


def settings(mode: str) -> FreeLoadSettings:
    """``"none"``, ``"force"``, ``"full"``: the package's defaults with that ``sensor_matrix``; ``"force:0"``: the
    force block with the ridge grid ``[0]`` (no pull to the factory matrix: the unregularised estimate, to compare
    the sessions' matrices with each other, not a setting to use)."""
    m, _, r = mode.partition(":")
    return FreeLoadSettings(sensor_matrix=m) if not r else FreeLoadSettings(sensor_matrix=m, sensor_matrix_ridge=(float(r),))


def fit(ds: Dataset, mode: str):
    """The wrist's free-load fit with ``settings(mode)``."""
    return fit_free_loads(ds, settings(mode)).legs[LEG]


def premultiplied(ds: Dataset, C: np.ndarray) -> Dataset:
    """``ds`` with every reading ``r`` replaced by ``C r``: the fit with a free offset then sees ``C (r - o)``."""
    recs = tuple(dataclasses.replace(r, wrench={k: (w @ C.T if k == LEG else w) for k, w in r.wrench.items()})
                 for r in ds.recordings)
    return dataclasses.replace(ds, recordings=recs)


def fmt(v: np.ndarray, digits: int = 4) -> str:
    return " ".join(f"{x:.{digits}g}" for x in v)


def describe(name: str, mode: str, r) -> None:
    print(f"\n### {name}, sensor_matrix = \"{mode}\"\n")
    print(f"- {r.n_used} quasi-static samples; mass {r.theta[0]:.4f} kg (se {r.bse[f'{LEG}.mass_kg']:.2g}); CoM z "
          f"{1e3 * r.theta[3] / r.theta[0]:.1f} mm")
    sm = r.sensor_matrix
    if sm is None:
        print(f"- residual RMS fx..tz: {fmt(r.rms)}")
        return
    h = sm.ridge
    print(f"- ridge kept: {h.chosen:g}; held-out score per weight (mean over the folds, +- se of its difference to the least): "
          + ", ".join(f"{g:g}: {s:.3g}+-{e:.2g}" for g, s, e in zip(h.grid, h.score, h.score_se)))
    print(f"- residual RMS fx..tz, factory -> C: {fmt(sm.rms_factory)} -> {fmt(sm.rms)}")
    det = [c for c in sm.combinations if c["determined"] and c["se"] > 0]
    und = [c["combination"].split(".C.")[1] for c in sm.combinations if not c["determined"]]
    print("- determined: " + ("; ".join(f"{c['combination'].split('.C.')[1]} {c['value']:+.4f} +- {c['se']:.4f}"
                                        for c in det) or "none with se > 0"))
    print(f"- undetermined (held at the factory value): {', '.join(und) or 'none'}")
    if mode == "force":
        print(f"- C force block: {np.array2string(sm.C[:3, :3], precision=4, suppress_small=True)}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("converted", type=Path, help="output folder of convert_leledeyuan00_ati.py")
    ap.add_argument("--sessions", default=",".join(SESSIONS))
    ap.add_argument("--modes", default="force,full,force:0", help="sensor_matrix modes; MODE:R sets the ridge grid to [R]")
    a = ap.parse_args(argv)
    names = [s for s in a.sessions.split(",") if s]
    modes = [m for m in a.modes.split(",") if m]
    ds = {n: read_dataset(a.converted / n / "dataset.toml") for n in names}
    fits: dict[tuple[str, str], object] = {}
    print("## 1. Fits, per session")
    for n in names:
        for m in ["none", *modes]:
            try:
                fits[n, m] = fit(ds[n], m)
            except Exception as e:   # a failing mode is a finding to report, not a reason to stop the others
                print(f"\n### {n}, sensor_matrix = \"{m}\": FAILED: {type(e).__name__}: {e}")
                continue
            describe(n, m, fits[n, m])
    s = FreeLoadSettings()
    pairs = [(A, B) for A in names for B in names if A != B]
    head = "| calibrated on -> evaluated on | " + " | ".join(f"{ax} %" for ax in WRENCH) + " | factory RMS fx..tz (N, N*m) |"
    rule = "|---" * 8 + "|"
    print("\n## 2. Across sessions, A's load and matrix on B (validate_across_sessions; factory = 100 %)")
    for m in modes:
        print(f"\n{m}:\n\n{head}\n{rule}")
        for A, B in pairs:
            if (A, m) in fits and (A, "none") in fits:
                df = validate_across_sessions(fits[A, "none"], fits[A, m], ds[B], s)
                pct, f0 = df.iloc[:, 2].to_numpy(), df["factory_rms"].to_numpy()
                print(f"| {A} -> {B} | " + " | ".join(f"{v:.0f}" for v in pct) + f" | {fmt(f0, 3)} |")
    print("\n## 3. Across sessions, A's matrix on B's readings, B's load refitted (factory = 100 %)")
    for m in modes:
        print(f"\n{m}:\n\n{head}\n{rule}")
        for A, B in pairs:
            if (A, m) in fits and (B, "none") in fits:
                f0 = fits[B, "none"].rms
                f1 = fit(premultiplied(ds[B], fits[A, m].sensor_matrix.C), "none").rms
                print(f"| {A} -> {B} | " + " | ".join(f"{v:.0f}" for v in 100 * f1 / f0) + f" | {fmt(f0, 3)} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
