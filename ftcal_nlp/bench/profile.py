"""Where the time goes: cProfile of pipeline stages, top functions and named hot spots.

``profile_call(fn)`` runs ``fn`` under ``cProfile`` and returns every function's
own (``tottime``) and cumulative (``cumtime``) time with its fraction of the
stage. ``hot_spots`` sums the cumulative time of named pieces of the estimators
(CasADi's symbolic build and ``nlpsol`` construction, IPOPT solves, the GCV
eigenproblem, the cvxpy QP, the Fisher information, ...), which is what a change
to an estimator would act on. cProfile's own overhead inflates Python-heavy
code (roughly 1.2-2x here), so fractions, not seconds, are what to compare.
"""

from __future__ import annotations

import cProfile
import io
import pstats
import time
from collections.abc import Callable

import pandas as pd

# (stage, label, (module-path fragment, function name)): cumulative time of these calls.
HOT_SPOTS = (
    ("hanging", "symbolic NLP build + nlpsol (HangingNLP.build)", ("hanging/nlp.py", "build")),
    ("hanging", "IPOPT solves (HangingNLP.solve)", ("hanging/nlp.py", "solve")),
    ("hanging", "GCV smoothing choice (choose_smoothing)", ("hanging/com_qp.py", "choose_smoothing")),
    ("hanging", "cvxpy QP set-up (ComQP.__init__)", ("hanging/com_qp.py", "__init__")),
    ("hanging", "cvxpy QP solves (ComQP.solve)", ("hanging/com_qp.py", "solve")),
    ("hanging", "torque design matrix (torque_design)", ("hanging/com_qp.py", "torque_design")),
    ("hanging", "Fisher standard errors (leg_covariance)", ("hanging/uncertainty.py", "leg_covariance")),
    ("hanging", "objective evaluations (joint_objective)", ("hanging/estimate.py", "joint_objective")),
    ("hanging", "sample compression (compress_recording)", ("hanging/binning.py", "compress_recording")),
    ("hanging", "baseline Kalman smoother", ("hanging/baseline.py", "kalman_smoother_random_walk")),
    ("hanging", "baseline least_squares (s+, s-)", ("scipy/optimize/_lsq/least_squares.py", "least_squares")),
    ("model selection", "symbolic build (compile_problem)", ("standing/nlp.py", "compile_problem")),
    ("model selection", "nlpsol construction (CompiledProblem.solver)", ("standing/nlp.py", "solver")),
    ("model selection", "IPOPT solves (CompiledProblem.solve)", ("standing/nlp.py", "solve")),
    ("model selection", "Gauss-Newton uncertainty (uncertainty)", ("standing/result.py", "uncertainty")),
    ("model selection", "physical maps + Jacobian (physical)", ("standing/result.py", "physical")),
    ("model selection", "baseline alternating least squares", ("standing/baseline.py", "solve_baseline")),
    ("standing", "symbolic build (compile_problem)", ("standing/nlp.py", "compile_problem")),
    ("standing", "IPOPT solve (CompiledProblem.solve)", ("standing/nlp.py", "solve")),
    ("standing", "Gauss-Newton uncertainty (uncertainty)", ("standing/result.py", "uncertainty")),
    ("poses", "Savitzky-Golay derivatives (savgol_filter)", ("scipy/signal/_savitzky_golay.py", "savgol_filter")),
    ("poses", "per-pose medians (numpy median)", ("numpy/lib/_function_base_impl.py", "median")),
    ("poses", "median quaternions (_median_quaternion)", ("standing/poses.py", "_median_quaternion")),
    ("load", "CSV parsing (pandas read_csv)", ("pandas/io/parsers/readers.py", "read_csv")),
    ("load", "Parquet reading (pandas read_parquet)", ("pandas/io/parquet.py", "read_parquet")),
    ("load", "validation (recording_from_frame)", ("ftcal_nlp/core/data.py", "recording_from_frame")),
    ("diagnosis", "CV fold complements (numpy setdiff1d)", ("numpy/lib/_arraysetops_impl.py", "setdiff1d")),
    ("diagnosis", "IPOPT solves (CasADi Function calls)", ("~", "<built-in method casadi._casadi.Function_call>")),
    ("diagnosis", "nlpsol constructions (CasADi nlpsol)", ("~", "<built-in method casadi._casadi.nlpsol>")),
    ("diagnosis", "effect fits on standing poses (standing_fit.fit)", ("diagnose/standing_fit.py", "fit")),
    ("diagnosis", "linear effect scores (linear_fit.score_linear)", ("diagnose/linear_fit.py", "score_linear")),
    ("diagnosis", "localisation CV (localise._cv_ss)", ("diagnose/localise.py", "_cv_ss")),
    ("diagnosis", "pose-history view (views._pose_history)", ("diagnose/views.py", "_pose_history")),
    ("report", "saving PNGs (savefig)", ("matplotlib/figure.py", "savefig")),
    ("report", "violin plots (violinplot)", ("matplotlib/axes/_axes.py", "violinplot")),
    ("report", "LaTeX/Markdown tables (write_table)", ("ftcal_nlp/report/__init__.py", "write_table")),
)


def profile_call(fn: Callable[[], object]) -> tuple[pd.DataFrame, float, str]:
    """Run ``fn`` under cProfile. Returns (table of functions, profiled wall seconds, pstats text of the top 30)."""
    prof = cProfile.Profile()
    t0 = time.perf_counter()
    prof.enable()
    fn()
    prof.disable()
    total = time.perf_counter() - t0
    st = pstats.Stats(prof)
    rows = []
    for (file, line, name), (cc, nc, tt, ct, _) in st.stats.items():  # type: ignore[attr-defined]  # undocumented; typeshed omits it
        rows.append({"file": file, "line": line, "function": name, "ncalls": nc, "tottime_s": tt, "cumtime_s": ct})
    df = pd.DataFrame(rows)
    df["tottime_frac"] = df.tottime_s / total
    df["cumtime_frac"] = df.cumtime_s / total
    buf = io.StringIO()
    pstats.Stats(prof, stream=buf).sort_stats("cumulative").print_stats(30)
    return df, total, buf.getvalue()


def short_name(row) -> str:
    f = str(row["file"])
    for key in ("ftcal_nlp/", "site-packages/"):
        if key in f:
            f = f.split(key, 1)[1]
            break
    return f"{f}:{row['line']}({row['function']})"


def top_functions(df: pd.DataFrame, n: int = 15, by: str = "tottime_s", package_only: bool = False) -> pd.DataFrame:
    """The ``n`` largest entries by ``by``; ``package_only`` keeps ftcal_nlp's own functions."""
    d = df[df.file.str.contains("ftcal_nlp", regex=False)] if package_only else df
    d = d.sort_values(by, ascending=False).head(n).copy()
    d.insert(0, "where", [short_name(r) for _, r in d.iterrows()])
    return d[["where", "ncalls", "tottime_s", "tottime_frac", "cumtime_s", "cumtime_frac"]].reset_index(drop=True)


def hot_spots(df: pd.DataFrame, stage: str) -> pd.DataFrame:
    """Cumulative time of the named pieces of ``stage`` (module docstring) found in the profile."""
    rows = []
    for st, label, (frag, func) in HOT_SPOTS:
        if st != stage:
            continue
        m = df[df.file.str.replace("\\", "/").str.contains(frag, regex=False) & (df.function == func)]
        if len(m):
            rows.append({"stage": stage, "hot spot": label, "calls": int(m.ncalls.sum()),
                         "cumtime_s": float(m.cumtime_s.max()), "fraction": float(m.cumtime_frac.max())})
    return pd.DataFrame(rows, columns=["stage", "hot spot", "calls", "cumtime_s", "fraction"])


def profile_stages(stages: dict[str, Callable[[], object]]) -> dict:
    """Profile each named stage; returns per stage the full table, top lists, hot spots and the pstats text."""
    out = {}
    for name, fn in stages.items():
        df, total, text = profile_call(fn)
        key = name.split(" (")[0]
        out[name] = {"total_s": total, "table": df, "top_self": top_functions(df, by="tottime_s"),
                     "top_cumulative_package": top_functions(df, by="cumtime_s", package_only=True),
                     "hot_spots": hot_spots(df, key), "text": text}
    return out
