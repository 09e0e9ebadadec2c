"""Equivalence snapshot: every output of the tool's commands on the shared samples, to compare two trees.

How to use (from a checkout's root, with the project's venv; ``OUT`` outside the checkout):

    /work/venv/bin/python tests/equivalence/snapshot.py take OUT            # full: samples + BigAnt + free sweep
    /work/venv/bin/python tests/equivalence/snapshot.py take OUT --quick    # samples only (a few minutes)
    /work/venv/bin/python tests/equivalence/snapshot.py take OUT --sweeps   # full + the hexapod validation sweep
    /work/venv/bin/python tests/equivalence/snapshot.py take OUT --only payload urdf   # some cases only
    /work/venv/bin/python tests/equivalence/snapshot.py compare BASE OUT [--rtol 1e-12] [--common]

``take`` runs ``python -m ftcal_nlp ...`` as subprocesses (cwd = the checkout, so the checkout's ``ftcal_nlp`` is
the one imported, which is checked; ``OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PYTHONHASHSEED=0``: one BLAS thread so that sums are added in one order, a fixed hash seed so that no set order
can differ between two takes) and writes each case into
``OUT/<case>/``; the checkout is never written (temporary configs live in ``OUT/_configs``). A case folder that
exists already is refused (``--force`` replaces it), so cases can be added to a snapshot later. Per case the
wall time is printed and kept in ``OUT/_timings.json``; each command's stdout is ``OUT/<case>/stdout_<step>.txt``
(compared), its log ``OUT/_logs/<case>/<step>.log`` (not compared), its exit status ``OUT/<case>/exit_codes.json``
(compared: a command that fails on one tree only is a difference). A failing command does not stop the others.

Cases (``CASES`` below): ``hexapod`` (problems/sample.toml: run, correct walk.csv with and without
``--track-offsets``, export, plan problems/plan_protocol.toml, plan of the sample as a pilot), ``payload``,
``urdf``, ``arm`` (a config written into OUT, /work/shared/sample_arm), ``arm_notool`` (each: run, correct of the
sample's recording, export, and for payload / urdf the pilot plan), ``plan_free`` (plan of the payload robot with a
holds file and of the URDF robot with joint holds), ``bigant`` (problems/bigant_sim.toml: the dataset simulated
into OUT with its seed 0, then run, correct of its walk, export; not in --quick), ``sweep_free``
(problems/diagnose_validation_free_quick.toml; not in --quick) and ``sweep_hexapod``
(problems/diagnose_validation_quick.toml: ~20 min on 2 idle cores, so only with --sweeps or --only).
Wall time at the base commit on the 2 shared cores (load 6-10): full 27 min (hexapod 10, bigant 6, sweep_free 7,
the other five 3), --quick 6 min on a lighter load; two full takes were equal (compare exit 0).

``compare A B`` (``--common``: only the cases both hold, e.g. a --quick snapshot against a full one) walks both trees and prints one line per differing file (worst relative difference and where) and
each file present in one tree only; exit status 1 on any difference, 0 when equal. Rules:
numbers are equal when ``|a - b| <= rtol * max(|a|, |b|) + ATOL`` (ATOL = 1e-300: only so that exact zeros
compare; NaN equals NaN, inf equals inf of the same sign); CSV (every float parsed exactly) and parquet:
same columns in the same order, same number of rows, numeric columns by that rule, other columns as text; npz:
same arrays, same shapes; JSON: same keys, numbers by the rule, strings as text; text files (md, txt, tex, html,
C sources and headers, toml, anything else that decodes as UTF-8): the numbers extracted (C literal suffixes
too) compared by the rule, the text between them equal; PNG and other binary files: existence only.

Volatile things, never compared (the one list; ``VOLATILE_*`` below): timings (files ``stage_times.*``, JSON keys
naming seconds / times / wall or CPU time / dates / the tool's version, the ``stage times:`` line of the run's
summary, ``N iterations, T s`` and ``ipopt: STATUS, T ms`` cells, the cells of table columns (Markdown, HTML) whose
header names a timing and the rows of transposed tables whose first cell does (``| time [s] | 4.18 | ...``),
``wall time T s`` / ``in T s`` / ``T s per run`` phrases), embedded figures (``data:image`` in report.html), dates and clock
times in text, the tool's version, absolute paths (the OUT prefix and the checkout's path are replaced by
``<OUT>`` and ``<CHECKOUT>`` before comparing; ``_checkout`` and ``_outdir`` in the snapshot record them, so a
snapshot may be moved), lock files (``*.lock``), the harness's own ``_timings.json`` and
``_logs/``. ``.ftcal_manifest.json`` holds no hashes: it is compared (its ``version`` key excepted).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import re
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

ATOL = 1e-300
SHARED = Path("/work/shared")

# --- volatile: the one list of what is never compared -------------------------------------------------------------
VOLATILE_FILES = [re.compile(p) for p in (r"(^|/)stage_times\.[a-z]+$", r"\.lock$", r"^_timings\.json$", r"^_logs/",
                                          r"(^|/)\.[^/]*\.staging[^/]*(/|$)")]
# JSON keys whose value is a clock reading or the tool's version (matched on the key, case-insensitive)
VOLATILE_KEYS = re.compile(r"(^|_)(seconds|secs|wall|wall_s|wall_time|cpu|cpu_s|cpu_time|elapsed|elapsed_s|timings?|"
                           r"time_s|runtime|runtime_s|duration_wall|date|datetime|timestamp|created|written_at|version|"
                           r"stage_times|solve_time|t_wall|python|platform|host|hostname)($|_)"
                           r"|^(diag_s|calib_s|run_s|mean_time_per_run_s|mean_time_per_dataset_s)$", re.I)
# text: substitutions applied before the numbers are extracted
VOLATILE_TEXT: list[tuple[re.Pattern[str], str]] = [
    (re.compile(r"data:image/[a-z+]+;base64,[A-Za-z0-9+/=]+"), "<EMBEDDED FIGURE>"),  # figures: existence only
    (re.compile(r"\d{4}-\d{2}-\d{2}([T ]\d{2}:\d{2}(:\d{2}(\.\d+)?)?(Z|[+-]\d{2}:?\d{2})?)?"), "<DATE>"),
    (re.compile(r"\b\d{2}:\d{2}:\d{2}(\.\d+)?\b"), "<CLOCK>"),
    (re.compile(r"^stage times:.*$", re.M), "stage times: <VOLATILE>"),
    (re.compile(r"(\d+ iterations), [0-9.eE+-]+ s\b"), r"\1, <T> s"),
    (re.compile(r"(ipopt: \w+), [0-9.eE+-]+ ?(ms|s)\b", re.I), r"\1, <T> \2"),
    (re.compile(r"\b(in|took|after|wall time|CPU time|elapsed)( [0-9.eE+-]+) ?(s|ms|min)\b"), r"\1 <T> \3"),
    (re.compile(r"\b[0-9.eE+-]+ ?s per (run|dataset)\b"), r"<T> s per \1"),
    (re.compile(r"\bftcal_nlp (\d+\.\d+\.\d+\S*)"), "ftcal_nlp <VERSION>"),
]

NUM = re.compile(r"(?<![A-Za-z_])[-+]?(?:nan|inf(?:inity)?|(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?)(?:[fFlLuU]{1,3}\b)?",
                 re.I)


# --- take ---------------------------------------------------------------------------------------------------------
@dataclass
class Step:
    label: str
    argv: list[str]                         # after "python -m ftcal_nlp"


@dataclass
class Case:
    name: str
    group: str                              # "quick" (always), "full" (not --quick), "sweeps" (--sweeps only)
    steps: Callable[[Path, Path], list[Step]]   # (checkout, case folder) -> steps
    prepare: Callable[[Path, Path], None] | None = None
    notes: list[str] = field(default_factory=list)


def _free_sample(name: str, rec: str, config: Callable[[Path, Path], str], pilot: bool) -> Callable[[Path, Path], list[Step]]:
    def steps(co: Path, d: Path) -> list[Step]:
        s = [Step("run", ["run", config(co, d), "-o", str(d / "run")]),
             Step("correct", ["correct", str(d / "run" / "calibration.json"), str(SHARED / rec), "-o", str(d / "correct" / "contact.csv")]),
             Step("export", ["export", str(d / "run" / "calibration.json"), "-o", str(d / "export")])]
        if pilot:
            s.append(Step("plan_pilot", ["plan", str(SHARED / name / "dataset.toml"), "-o", str(d / "plan_pilot" / "plan.json")]))
        return s
    return steps


def _configs(d: Path) -> Path:
    c = d.parent / "_configs"
    c.mkdir(exist_ok=True)
    return c


def _arm_config(co: Path, d: Path) -> str:
    existing = co / "problems" / "sample_arm.toml"
    if existing.is_file():
        return "problems/sample_arm.toml"
    p = _configs(d) / "sample_arm.toml"
    p.write_text("# written by tests/equivalence/snapshot.py: the shared arm sample (tool in the URDF)\n"
                 f'[data]\nmanifest = "{SHARED / "sample_arm" / "dataset.toml"}"\n\n'
                 f'[output]\ndir = "{d / "run"}"\n\n[diagnose]\nenabled = true\n')
    return str(p)


def _hexapod(co: Path, d: Path) -> list[Step]:
    cal = str(d / "run" / "calibration.json")
    return [Step("run", ["run", "problems/sample.toml", "-o", str(d / "run")]),
            Step("correct", ["correct", cal, str(SHARED / "sample" / "walk.csv"), "-o", str(d / "correct" / "walk.csv")]),
            Step("correct_track", ["correct", cal, str(SHARED / "sample" / "walk.csv"), "--track-offsets",
                                   "-o", str(d / "correct_track" / "walk.csv")]),
            Step("export", ["export", cal, "-o", str(d / "export")]),
            Step("plan_protocol", ["plan", "problems/plan_protocol.toml", "-o", str(d / "plan_protocol" / "plan.json")]),
            Step("plan_pilot", ["plan", str(SHARED / "sample" / "dataset.toml"), "--no-detection",
                                "-o", str(d / "plan_pilot" / "plan.json")])]


def _plan_free(co: Path, d: Path) -> list[Step]:
    c = _configs(d)
    holds = c / "holds_payload.toml"
    holds.write_text('[protocol]\ntransducer = "wrist"\nn_orientations = 12\nseed = 3\nhold_s = 5.0\nmass_kg = 1.4\n'
                     "com_m = [0.0, 0.0, 0.08]\n")
    leg = c / "holds_urdf.toml"
    leg.write_text('[protocol]\ntransducer = "leg"\nholds = [\n'
                   '  {quat = [1, 0, 0, 0], q = {}},\n'
                   '  {quat = [0.7071067811865476, 0.7071067811865476, 0, 0], q = {}},\n'
                   '  {quat = [0.7071067811865476, 0, 0.7071067811865476, 0], q = {}},\n'
                   '  {quat = [0, 1, 0, 0], q = {}},\n'
                   '  {quat = [0.5, 0.5, 0.5, 0.5], q = {}},\n'
                   '  {quat = [0.7071067811865476, 0, 0, 0.7071067811865476], q = {}},\n]\n')
    return [Step("plan_payload_holds", ["plan", str(SHARED / "sample_payload" / "robot.toml"), "--protocol", str(holds),
                                        "-o", str(d / "plan_payload_holds" / "plan.json")]),
            Step("plan_urdf_holds", ["plan", str(SHARED / "sample_urdf" / "robot.toml"), "--protocol", str(leg),
                                     "-o", str(d / "plan_urdf_holds" / "plan.json")])]


def _bigant_config(co: Path, d: Path) -> Path:
    """problems/bigant_sim.toml with its dataset and output in the case folder (the checkout is not written)."""
    import tomllib
    src = co / "problems" / "bigant_sim.toml"
    text = src.read_text()
    tomllib.loads(text)  # a malformed config is the tree's own error
    data = d / "data"
    text = re.sub(r'(?m)^manifest\s*=.*$', f'manifest = "{data / "dataset.toml"}"', text)
    text = re.sub(r'(?m)^dir\s*=\s*"\.\./data/bigant_sim".*$', f'dir = "{data}"', text)
    text = re.sub(r'(?m)^dir\s*=\s*"\.\./reports/bigant_sim".*$', f'dir = "{d / "run"}"', text)
    cfg = tomllib.loads(text)
    assert cfg["simulate"]["dir"] == str(data) and cfg["output"]["dir"] == str(d / "run"), "bigant_sim.toml changed shape"
    p = _configs(d) / "bigant_sim.toml"
    p.write_text(text)
    return p


def _bigant(co: Path, d: Path) -> list[Step]:
    cfg = str(_bigant_config(co, d))
    cal = str(d / "run" / "calibration.json")
    return [Step("simulate", ["simulate", cfg]),
            Step("run", ["run", cfg]),
            Step("correct", ["correct", cal, str(d / "data" / "walk.csv"), "-o", str(d / "correct" / "walk.csv")]),
            Step("export", ["export", cal, "-o", str(d / "export")])]


def _sweep(config: str) -> Callable[[Path, Path], list[Step]]:
    return lambda co, d: [Step("run", ["run", config, "-o", str(d / "run")])]


CASES: list[Case] = [
    Case("hexapod", "quick", _hexapod),
    Case("payload", "quick", _free_sample("sample_payload", "sample_payload/wrist.csv", lambda co, d: "problems/sample_payload.toml", True)),
    Case("urdf", "quick", _free_sample("sample_urdf", "sample_urdf/leg.csv", lambda co, d: "problems/sample_urdf.toml", True)),
    Case("arm", "quick", _free_sample("sample_arm", "sample_arm/wrist.csv", _arm_config, False)),
    Case("arm_notool", "quick", _free_sample("sample_arm_notool", "sample_arm/wrist.csv",
                                             lambda co, d: "problems/sample_arm_notool.toml", False)),
    Case("plan_free", "quick", _plan_free),
    Case("bigant", "full", _bigant),
    Case("sweep_free", "full", _sweep("problems/diagnose_validation_free_quick.toml")),
    Case("sweep_hexapod", "sweeps", _sweep("problems/diagnose_validation_quick.toml")),
]


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env.update(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", PYTHONHASHSEED="0")
    env.pop("PYTHONPATH", None)
    return env


def _check_import(co: Path) -> str:
    r = subprocess.run([sys.executable, "-c", "import ftcal_nlp; print(ftcal_nlp.__file__)"], cwd=co, env=_env(),
                       capture_output=True, text=True, check=True)
    f = Path(r.stdout.strip()).resolve()
    if co.resolve() not in f.parents:
        sys.exit(f"snapshot: {co} imports ftcal_nlp from {f}, not from the checkout")
    return str(f)


def take(out: Path, quick: bool, sweeps: bool, only: list[str] | None, force: bool) -> int:
    co = Path.cwd().resolve()
    if not (co / "ftcal_nlp").is_dir() or not (co / "problems").is_dir():
        sys.exit(f"snapshot: run from a checkout's root (no ftcal_nlp/ or problems/ in {co})")
    out = out.resolve()
    if out == co or co in out.parents:
        sys.exit(f"snapshot: {out} is inside the checkout; the snapshot must be written elsewhere")
    names = {c.name for c in CASES}
    if only:
        bad = sorted(set(only) - names)
        if bad:
            sys.exit(f"snapshot: unknown case(s) {bad}; cases: {sorted(names)}")
        chosen = [c for c in CASES if c.name in only]
    else:
        groups = {"quick"} | (set() if quick else {"full"}) | ({"full", "sweeps"} if sweeps else set())
        chosen = [c for c in CASES if c.group in groups]
    out.mkdir(parents=True, exist_ok=True)
    for c in chosen:
        if (out / c.name).exists():
            if not force:
                sys.exit(f"snapshot: {out / c.name} exists (--force replaces it)")
            shutil.rmtree(out / c.name)
            shutil.rmtree(out / "_logs" / c.name, ignore_errors=True)
    print(f"checkout {co}: ftcal_nlp from {_check_import(co)}", flush=True)
    tpath = out / "_timings.json"
    timings = json.loads(tpath.read_text()) if tpath.is_file() else {}
    env = _env()
    failed = 0
    t_all = time.perf_counter()
    for c in chosen:
        d = out / c.name
        d.mkdir()
        logs = out / "_logs" / c.name
        logs.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        codes: dict[str, int] = {}
        steps: dict[str, float] = {}
        for s in c.steps(co, d):
            argv = [sys.executable, "-m", "ftcal_nlp", *s.argv, "--no-progress"]
            ts = time.perf_counter()
            with open(logs / f"{s.label}.log", "w") as err:
                err.write("$ " + " ".join(argv) + "\n")
                err.flush()
                r = subprocess.run(argv, cwd=co, env=env, stdout=subprocess.PIPE, stderr=err, text=True)
            (d / f"stdout_{s.label}.txt").write_text(r.stdout)
            codes[s.label] = r.returncode
            steps[s.label] = round(time.perf_counter() - ts, 2)
            if r.returncode:
                failed += 1
                print(f"  {c.name}/{s.label}: exit {r.returncode} (log {logs / (s.label + '.log')})", flush=True)
        (d / "exit_codes.json").write_text(json.dumps(codes, indent=1) + "\n")
        dt = time.perf_counter() - t0
        timings[c.name] = {"wall_s": round(dt, 2), "steps": steps}
        print(f"{c.name}: {dt:.1f} s  ({', '.join(f'{k} {v:.1f}' for k, v in steps.items())})", flush=True)
        tpath.write_text(json.dumps(timings, indent=1) + "\n")
    print(f"total {time.perf_counter() - t_all:.1f} s; {failed} command(s) failed; snapshot in {out}", flush=True)
    return 1 if failed else 0


# --- compare ------------------------------------------------------------------------------------------------------
class Worst:
    """The worst relative difference of a file and where it is; ``hard`` for a difference no rtol forgives."""

    def __init__(self) -> None:
        self.rel = 0.0
        self.where = ""
        self.hard: str | None = None
        self.count = 0

    def num(self, a: float, b: float, where: str, rtol: float) -> None:
        if a == b or (math.isnan(a) and math.isnan(b)):
            return
        if math.isinf(a) or math.isinf(b) or math.isnan(a) or math.isnan(b):
            self.fail(f"{where}: {a!r} vs {b!r}")
            return
        d = abs(a - b)
        scale = max(abs(a), abs(b))
        if d <= rtol * scale + ATOL:
            return
        self.count += 1
        rel = d / scale if scale else math.inf
        if rel > self.rel:
            self.rel, self.where = rel, f"{where}: {a!r} vs {b!r}"

    def fail(self, msg: str) -> None:
        self.count += 1
        if self.hard is None:
            self.hard = msg

    def __bool__(self) -> bool:
        return self.count > 0

    def line(self, name: str) -> str:
        parts = []
        if self.rel:
            parts.append(f"worst rel {self.rel:.3g} at {self.where}")
        if self.hard:
            parts.append(self.hard)
        return f"DIFF {name}: {self.count} difference(s); " + "; ".join(parts)


def _volatile_name(k: str) -> bool:
    """A key or column header that names a timing, a date or the version (VOLATILE_KEYS, non-alphanumerics as ``_``)."""
    return bool(VOLATILE_KEYS.search(re.sub(r"[^A-Za-z0-9]+", "_", str(k)).strip("_")))


def _mask_table_columns(s: str) -> str:
    """Markdown tables (``| a | b |`` rows under a header row): the cells of a column whose header names a timing
    (VOLATILE_KEYS on the header, spaces as underscores) replaced by ``<T>``."""
    if "|" not in s:
        return s
    lines = s.split("\n")
    masked: set[int] | None = None
    for i, line in enumerate(lines):
        t = line.strip()
        if not (t.startswith("|") and t.endswith("|")):
            masked = None
            continue
        cells = t[1:-1].split("|")
        if masked is None:  # the header row of a new table
            masked = {j for j, c in enumerate(cells) if _volatile_name(c)}
            continue
        if set(t) <= set("|:- "):
            continue
        if _volatile_name(cells[0]):  # a row of timings in a transposed table ("| time [s] | 4.18 | 1.26 |")
            lines[i] = "|" + cells[0] + "|" + "|".join(" <T> " for _ in cells[1:]) + "|"
        elif masked:
            lines[i] = "|" + "|".join(" <T> " if j in masked else c for j, c in enumerate(cells)) + "|"
    return "\n".join(lines)


_TABLE = re.compile(r"<table\b.*?</table>", re.S | re.I)
_ROW = re.compile(r"<tr\b[^>]*>(.*?)</tr>", re.S | re.I)
_CELL = re.compile(r"(<t[hd]\b[^>]*>)(.*?)(</t[hd]>)", re.S | re.I)


def _mask_html_columns(s: str) -> str:
    """HTML tables: the cells of a column whose header (the first row) names a timing replaced by ``<T>``."""
    if "<table" not in s:
        return s

    def table(m: re.Match[str]) -> str:
        t = m.group(0)
        rows = list(_ROW.finditer(t))
        if not rows:
            return t
        head = [re.sub(r"<[^>]+>", "", c.group(2)) for c in _CELL.finditer(rows[0].group(1))]
        masked = {j for j, c in enumerate(head) if _volatile_name(c)}

        def row(r: re.Match[str]) -> str:
            cells = list(_CELL.finditer(r.group(1)))
            # a row of timings in a transposed table (its first cell names them), or the cells of a timing column
            cols = set(range(1, len(cells))) if cells and _volatile_name(re.sub(r"<[^>]+>", "", cells[0].group(2))) \
                else masked
            if not cols:
                return r.group(0)
            k = iter(range(10 ** 6))
            return _CELL.sub(lambda c: c.group(1) + "<T>" + c.group(3) if next(k) in cols else c.group(0), r.group(0))
        return t[:rows[0].end()] + _ROW.sub(row, t[rows[0].end():])
    return _TABLE.sub(table, s)


def cmp_text(a: str, b: str, w: Worst, where: str, rtol: float) -> None:
    ta, tb = NUM.split(a), NUM.split(b)
    na, nb = NUM.findall(a), NUM.findall(b)
    if len(na) != len(nb) or ta != tb:
        # locate the first textual difference
        la, lb = a.splitlines(), b.splitlines()
        for i, (x, y) in enumerate(zip(la, lb)):
            if NUM.split(x) != NUM.split(y) or len(NUM.findall(x)) != len(NUM.findall(y)):
                w.fail(f"{where} line {i + 1}".strip() + f": text differs: {x[:120]!r} vs {y[:120]!r}")
                return
        w.fail(f"{where}: {len(la)} vs {len(lb)} lines")
        return
    for i, (x, y) in enumerate(zip(na, nb)):
        fx, fy = _f(x), _f(y)
        if fx is None or fy is None:
            if x != y:
                w.fail(f"{where}: {x!r} vs {y!r}")
            continue
        if fx != fy:
            line = a.count("\n", 0, _nth_pos(a, i)) + 1
            w.num(fx, fy, f"{where} line {line}".strip(), rtol)


def _nth_pos(s: str, n: int) -> int:
    for i, m in enumerate(NUM.finditer(s)):
        if i == n:
            return m.start()
    return 0


def _f(tok: str) -> float | None:
    t = re.sub(r"[fFlLuU]+$", "", tok) if not re.search(r"(?i)inf|nan", tok) else tok
    try:
        return float(t)
    except ValueError:
        return None


def cmp_json(a: Any, b: Any, w: Worst, where: str, rtol: float, norm: Normaliser) -> None:
    if isinstance(a, dict) and isinstance(b, dict):
        ka = {k for k in a if not _volatile_name(k)}
        kb = {k for k in b if not _volatile_name(k)}
        if ka != kb:
            w.fail(f"{where}: keys only in A {sorted(ka - kb)[:5]}, only in B {sorted(kb - ka)[:5]}")
        for k in sorted(ka & kb):
            cmp_json(a[k], b[k], w, f"{where}.{k}", rtol, norm)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            w.fail(f"{where}: length {len(a)} vs {len(b)}")
        for i, (x, y) in enumerate(zip(a, b)):
            cmp_json(x, y, w, f"{where}[{i}]", rtol, norm)
    elif isinstance(a, bool) or isinstance(b, bool) or a is None or b is None:
        if a != b:
            w.fail(f"{where}: {a!r} vs {b!r}")
    elif isinstance(a, (int, float)) and isinstance(b, (int, float)):
        w.num(float(a), float(b), where, rtol)
    elif isinstance(a, str) and isinstance(b, str):
        cmp_text(norm.a(a), norm.b(b), w, where, rtol)
    else:
        w.fail(f"{where}: {type(a).__name__} vs {type(b).__name__}")


def _load_json(p: Path) -> Any:
    # NaN / Infinity as Python's json writes them
    return json.loads(p.read_text())


def cmp_frames(fa, fb, w: Worst, rtol: float, norm_a: Callable[[str], str], norm_b: Callable[[str], str]) -> None:
    import numpy as np
    import pandas as pd
    ca, cb = [str(c) for c in fa.columns], [str(c) for c in fb.columns]
    if ca != cb:
        w.fail(f"columns differ: only in A {[c for c in ca if c not in cb][:5]}, only in B {[c for c in cb if c not in ca][:5]}"
                if set(ca) != set(cb) else "columns in another order")
        return
    if len(fa) != len(fb):
        w.fail(f"{len(fa)} vs {len(fb)} rows")
        return
    for c in fa.columns:
        if _volatile_name(c):
            continue  # a timing column: present in both, values not compared
        x, y = fa[c], fb[c]
        nx = pd.api.types.is_numeric_dtype(x) and not pd.api.types.is_bool_dtype(x)
        ny = pd.api.types.is_numeric_dtype(y) and not pd.api.types.is_bool_dtype(y)
        if nx and ny:
            xa, ya = x.to_numpy(dtype=float), y.to_numpy(dtype=float)
            both_nan = np.isnan(xa) & np.isnan(ya)
            with np.errstate(invalid="ignore", over="ignore"):
                d = np.abs(xa - ya)
                scale = np.maximum(np.abs(xa), np.abs(ya))
                bad = ~both_nan & (xa != ya) & ~(d <= rtol * scale + ATOL)
            for i in np.flatnonzero(bad)[:1000]:
                w.num(float(xa[i]), float(ya[i]), f"column {c} row {i}", rtol)
            extra = int(bad.sum()) - min(int(bad.sum()), 1000)
            w.count += extra
        else:
            for i, (u, v) in enumerate(zip(x.astype(str), y.astype(str))):
                if u != v:
                    cmp_text(norm_a(u), norm_b(v), w, f"column {c} row {i}", rtol)


def _read_csv(p: Path):
    """A CSV with every float parsed exactly (Python's strtod through numpy, not pandas' own parser): a column
    whose every cell parses as a number (empty cells NaN) is numeric, any other column text."""
    import numpy as np
    import pandas as pd
    raw = pd.read_csv(p, dtype=str, keep_default_na=False, low_memory=False)
    out = {}
    for c in raw.columns:
        v = raw[c].to_numpy(dtype=object)
        try:
            out[c] = np.where(v == "", "nan", v).astype(float)
        except ValueError:
            out[c] = v
    return pd.DataFrame(out, columns=raw.columns)


def cmp_file(pa: Path, pb: Path, rel: str, rtol: float, na: Normaliser, nb: Normaliser) -> Worst:
    w = Worst()
    ext = pa.suffix.lower()
    try:
        if ext == ".png" or ext in (".pdf", ".mcap", ".db3", ".bag", ".svg"):
            return w  # existence only
        if ext == ".csv":
            cmp_frames(_read_csv(pa), _read_csv(pb), w, rtol, na, nb)
        elif ext == ".parquet":
            import pandas as pd
            cmp_frames(pd.read_parquet(pa), pd.read_parquet(pb), w, rtol, na, nb)
        elif ext == ".npz":
            import numpy as np
            with np.load(pa, allow_pickle=False) as A, np.load(pb, allow_pickle=False) as B:
                if sorted(A.files) != sorted(B.files):
                    w.fail(f"arrays {sorted(A.files)} vs {sorted(B.files)}")
                for k in sorted(set(A.files) & set(B.files)):
                    x, y = A[k], B[k]
                    if x.shape != y.shape:
                        w.fail(f"{k}: shape {x.shape} vs {y.shape}")
                    elif x.dtype.kind in "fciu" and y.dtype.kind in "fciu":
                        for i, (u, v) in enumerate(zip(x.ravel().astype(float), y.ravel().astype(float))):
                            w.num(float(u), float(v), f"{k}[{i}]", rtol)
                    elif not (x == y).all():
                        w.fail(f"{k}: differs")
        elif ext == ".json":
            norm = argparse.Namespace(a=na, b=nb)
            cmp_json(_load_json(pa), _load_json(pb), w, "$", rtol, norm)  # type: ignore[arg-type]
        else:
            try:
                ta, tb = pa.read_text(), pb.read_text()
            except UnicodeDecodeError:
                return w  # binary: existence only
            cmp_text(na(ta), nb(tb), w, "", rtol)
    except Exception as exc:  # an unreadable file is a difference, named
        w.fail(f"cannot compare: {type(exc).__name__}: {exc}")
    return w


def _walk(root: Path) -> Iterator[str]:
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames.sort()
        for f in sorted(filenames):
            rel = os.path.relpath(os.path.join(dirpath, f), root)
            if not any(p.search(rel) for p in VOLATILE_FILES):
                yield rel


class Normaliser:
    """A tree's text made comparable: its checkout path and its own root replaced, volatile text masked."""

    def __init__(self, root: Path) -> None:
        taken = root / "_outdir"  # where the snapshot was taken: it may have been moved since
        roots = {str(root), str(root.resolve())} | ({taken.read_text().strip()} if taken.is_file() else set())
        self.roots = sorted(roots, key=len, reverse=True)
        co = root / "_checkout"
        self.checkout = co.read_text().strip() if co.is_file() else None

    def __call__(self, s: str) -> str:
        s = _mask_html_columns(_mask_table_columns(s))
        if self.checkout:
            s = s.replace(self.checkout, "<CHECKOUT>")
        for r in self.roots:
            s = s.replace(r, "<OUT>")
        for pat, rep in VOLATILE_TEXT:
            s = pat.sub(rep, s)
        return s


def _cases(root: Path) -> set[str]:
    return {p.name for p in root.iterdir() if p.is_dir() and not p.name.startswith("_")}


def compare(a: Path, b: Path, rtol: float, common: bool = False) -> int:
    fa, fb = set(_walk(a)), set(_walk(b))
    if common:  # only the cases both snapshots hold (a --quick snapshot against a full one)
        keep = _cases(a) & _cases(b)
        skipped = sorted((_cases(a) | _cases(b)) - keep)
        if skipped:
            print(f"cases in one snapshot only, not compared: {', '.join(skipped)}")
        fa = {f for f in fa if f.split("/")[0] in keep}
        fb = {f for f in fb if f.split("/")[0] in keep}
    fa -= {"_checkout", "_outdir"}
    fb -= {"_checkout", "_outdir"}
    na, nb = Normaliser(a), Normaliser(b)
    ndiff = 0
    for rel in sorted(fa - fb):
        print(f"ONLY IN A {rel}")
        ndiff += 1
    for rel in sorted(fb - fa):
        print(f"ONLY IN B {rel}")
        ndiff += 1
    both = sorted(fa & fb)
    for rel in both:
        w = cmp_file(a / rel, b / rel, rel, rtol, na, nb)
        if w:
            print(w.line(rel), flush=True)
            ndiff += 1
    print(f"compared {len(both)} files (rtol {rtol:g}, atol {ATOL:g}): "
          + ("equal" if not ndiff else f"{ndiff} file(s) differ or are missing"))
    return 1 if ndiff else 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="snapshot.py", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    t = sub.add_parser("take", help="run the cases into OUTDIR")
    t.add_argument("outdir", type=Path)
    t.add_argument("--quick", action="store_true", help="the shared samples only (no BigAnt, no sweeps)")
    t.add_argument("--sweeps", action="store_true", help="also the hexapod validation sweep (~20 min on 2 idle cores)")
    t.add_argument("--only", nargs="+", metavar="CASE", help=f"these cases only: {', '.join(c.name for c in CASES)}")
    t.add_argument("--force", action="store_true", help="replace case folders that exist")
    c = sub.add_parser("compare", help="compare two snapshots")
    c.add_argument("a", type=Path)
    c.add_argument("b", type=Path)
    c.add_argument("--rtol", type=float, default=1e-12)
    c.add_argument("--common", action="store_true", help="compare only the cases both snapshots hold")
    args = ap.parse_args(argv)
    if args.cmd == "take":
        if args.quick and args.sweeps:
            ap.error("--quick and --sweeps exclude each other")
        args.outdir.mkdir(parents=True, exist_ok=True)
        (args.outdir / "_checkout").write_text(str(Path.cwd().resolve()) + "\n")
        (args.outdir / "_outdir").write_text(str(args.outdir.resolve()) + "\n")
        return take(args.outdir, args.quick, args.sweeps, args.only, args.force)
    return compare(args.a, args.b, args.rtol, args.common)


if __name__ == "__main__":
    sys.exit(main())
