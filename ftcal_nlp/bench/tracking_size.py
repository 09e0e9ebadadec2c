"""Size of ``--track-offsets``' chi-square test on drift-free walks (issue 24, item 3).

``python -m ftcal_nlp.bench.tracking_size [--walks 40] [--seed 0] [-o reports/bench]``

For walk ``i`` (seed ``seed + i``): a BigAnt dataset is simulated and calibrated (its own calibration errors,
as a user's would be), then a later walk of the same robot with no offset shift and no drift
(``sim.later.simulate_later_walk(shift_N=0, drift_N=0, ...)``) is corrected with tracked offsets. A leg whose
change since calibration is called significant (p < ``tracking.SIGNIFICANCE``) is a false alarm; the test
holds its size when at most 5 % of the walks carry one (any leg). Writes ``tracking_size.csv`` (one row per
walk and leg: chi2, p) and prints the rates.
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

import pandas as pd

__all__ = ["tracking_size"]


def tracking_size(walks: int = 40, seed: int = 0, *, n_poses: int = 60, hanging_cycles: float = 1.5,
                  walk_cycles: float = 3.0) -> pd.DataFrame:
    """One row per walk and leg: ``walk``, ``seed``, ``leg``, ``chi2``, ``p``, ``significant``."""
    from ..correct import correct_recording_full
    from ..pipeline import calibrate
    from ..core.settings import CalibrationSettings, CorrectSettings, DiagnoseSettings, HangingSettings, StandingSettings
    from ..sim import SimConfig, simulate
    from ..sim.later import simulate_later_walk

    fast = CalibrationSettings(hanging=HangingSettings(compare_baseline=False),
                               standing=StandingSettings(compare_baseline=False, model="full"),
                               diagnose=DiagnoseSettings(enabled=False))
    rows = []
    for i in range(walks):
        s = seed + i
        sim = simulate(SimConfig(seed=s, n_poses=n_poses, hanging_cycles=hanging_cycles, walk_cycles=0.0))
        run = calibrate(sim.dataset, fast)
        walk = simulate_later_walk(sim, cycles=walk_cycles, shift_N=0.0, shift_Nm=0.0, drift_N=0.0, drift_Nm=0.0, seed=s)
        c = correct_recording_full(run.calibration, walk.recording, run.uncertainty, CorrectSettings(track_offsets=True))
        assert c.tracking is not None  # track_offsets on a walk of many samples
        tab = c.tracking.change_table()
        for leg, r in tab.iterrows():
            if r["tracked"]:
                rows.append({"walk": i, "seed": s, "leg": leg, "chi2": float(r["chi2"]), "p": float(r["p"]),
                             "significant": bool(r["significant"])})
    return pd.DataFrame(rows)


def summary(df: pd.DataFrame) -> dict:
    per_walk = df.groupby("walk")["significant"].any()
    return {"walks": int(per_walk.size), "walks_with_a_false_alarm": int(per_walk.sum()),
            "walk_rate": float(per_walk.mean()), "leg_tests": int(len(df)), "leg_rate": float(df["significant"].mean()),
            "mean_chi2": float(df["chi2"].mean()), "rate_at_0.05": float((df["p"] < 0.05).mean())}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ftcal_nlp.bench.tracking_size", description=__doc__.splitlines()[0])
    ap.add_argument("--walks", type=int, default=40)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("-o", "--output", default="reports/bench")
    a = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    t0 = time.perf_counter()
    df = tracking_size(a.walks, a.seed)
    out = Path(a.output)
    out.mkdir(parents=True, exist_ok=True)
    df.to_csv(out / "tracking_size.csv", index=False)
    s = summary(df)
    print(f"{s['walks_with_a_false_alarm']}/{s['walks']} drift-free walks with a leg called significant (rate {s['walk_rate']:.3f}; "
          f"goal <= 0.05); per leg test {s['leg_rate']:.4f} (nominal {1e-3:g}); mean chi2 {s['mean_chi2']:.2f} (6 under "
          f"the null); p < 0.05 in {s['rate_at_0.05']:.3f}; {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
