"""``python -m ftcal_nlp.bench [--quick] [--out reports/bench] [--only PART ...]``: the benchmarks of issue 8.

Accuracy against the Cramer-Rao bound over simulated datasets, per-stage speed
on the default problem (NLP and the report's baseline in one process),
scaling of time and memory with poses and hanging samples, and a profile of the
slowest stages. Writes tables (CSV, Markdown), figures (PNG), ``summary.md``
(the README's table) and ``bench.json`` into ``--out`` and prints the summary.
"""

import os

# Multi-threaded BLAS makes the many small LAPACK calls 10-30x slower on 2 shared
# cores; the limit must be set before numpy is first imported.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse
import logging
import sys
from dataclasses import replace

import matplotlib


def main(argv: list[str] | None = None) -> int:
    from .runner import PARTS, full_settings, quick_settings, run_bench

    ap = argparse.ArgumentParser(prog="python -m ftcal_nlp.bench", description=__doc__.split("\n\n")[1])
    ap.add_argument("--quick", action="store_true", help="the ~1-2 minute version (fewer datasets, repeats and points)")
    ap.add_argument("--out", default="reports/bench", help="output folder (default reports/bench)")
    ap.add_argument("--only", nargs="+", choices=PARTS, help="run only these parts")
    ap.add_argument("--seeds", type=int, help="number of simulated datasets for the accuracy parts (hexapod and free loads)")
    ap.add_argument("--no-progress", action="store_true", help="no progress bars")
    a = ap.parse_args(argv)
    matplotlib.use("Agg")  # files only; the entry point, not the library, picks the backend
    logging.basicConfig(level=logging.WARNING)
    s = quick_settings() if a.quick else full_settings()
    if a.only:
        s = replace(s, parts=tuple(a.only))
    if a.seeds:
        s = replace(s, accuracy=replace(s.accuracy, seeds=tuple(range(a.seeds))), loads=replace(s.loads, seeds=tuple(range(a.seeds))))
    res = run_bench(s, a.out, progress=not a.no_progress)
    print(res["summary"])
    print(f"\nwritten: {os.path.abspath(a.out)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
