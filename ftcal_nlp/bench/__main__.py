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



def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    from threadpoolctl import threadpool_limits

    from ..cli import add_common, guarded, parse, setup
    from .runner import PARTS, full_settings, quick_settings, run_bench

    ap = argparse.ArgumentParser(prog=prog or "python -m ftcal_nlp.bench", description=__doc__.split("\n\n")[1])
    ap.add_argument("--quick", action="store_true", help="the ~1-2 minute version (fewer datasets, repeats and points)")
    add_common(ap, output_help="output folder (default reports/bench)", output_default="reports/bench", old_output=("--out",),
               force_help="accepted for symmetry: the bench always rewrites its own files")
    ap.add_argument("--only", nargs="+", choices=PARTS, help="run only these parts")
    ap.add_argument("--seeds", type=int, help="number of simulated datasets for the accuracy parts (hexapod and free loads)")
    a = parse(ap, argv)
    setup(a)
    if not (a.verbose or a.quiet):
        logging.getLogger().setLevel(logging.WARNING)  # the bench's own tables are its output
    s = quick_settings() if a.quick else full_settings()
    if a.only:
        s = replace(s, parts=tuple(a.only))
    if a.seeds:
        s = replace(s, accuracy=replace(s.accuracy, seeds=tuple(range(a.seeds))), loads=replace(s.loads, seeds=tuple(range(a.seeds))))

    def go() -> int:
        # set before numpy's first import when run as its own module; under `python -m ftcal_nlp bench` numpy is loaded
        with threadpool_limits(limits=1):
            res = run_bench(s, a.output, progress=not (a.no_progress or a.quiet))
        print(res["summary"])
        print(f"\nwritten: {os.path.abspath(a.output)}")
        return 0

    return guarded(go)


if __name__ == "__main__":
    sys.exit(main())
