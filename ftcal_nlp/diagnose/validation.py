"""The withheld-effect validation of the diagnosis, for both kinds of evidence: simulate datasets with known effects
hidden (or none), calibrate with the diagnosis on, and score what it says against what a correct diagnosis should say.
Part 1 is the hexapod sweep (and issue 7's random design), part 2 the free-load sweep (``design = "free"``); they share
the config's name checks (:func:`config_names`), the joblib runner (:func:`_parallel`), the goals and the confusion
table. ``python -m ftcal_nlp.run <config>`` runs any config with a ``[validation]`` table (``run_validation``, with
:func:`ftcal_nlp.calibrate` passed in).

Part 1, the hexapod sweep: ``python -m ftcal_nlp.run problems/diagnose_validation.toml``. Config::

    [validation]
    design = "sweep"           # "sweep" (issue 13, below) or "random" (issue 7: n_datasets drawn at random);
                               # without it: "random" when the table has a random-only key, else "sweep"
    seed = 0                   # dataset i uses simulator (and injector) seed seed * 1000 + i
    n_clean = 6                # clean datasets (sweep)
    effects = [...]            # library effects to withhold (default: the whole library)
    variants = [...]           # off-face injectors (ftcal_nlp.sim.variants.VARIANTS: the effect units' shapes and the
                               # faults outside the library; default: all of them; sweep)
    sizes = "realistic"        # sweep: "realistic" -> each effect's realistic low and high end;
                               #        "test" -> its test size and half of it
    tolerance = 1.5            # shrinkage goal: after / clean twin's floor <= this, every component
    model = "full"             # calibration error model (no model selection, for speed)
    folds = 5
    workers = 1                # joblib n_jobs (-1: every core; the machine's cores are shared: keep 1-2)
    backend = "loky"           # joblib backend; "loky" = local processes
    pairs = ["a+b", ...]       # sweep: pairs of library effects injected together (default: those of PAIRS
                               # whose effects are both in `effects`; [] none)
    n_datasets = 24            # random design only: datasets, share of clean ones, "realistic" | "test"
    clean_share = 0.15
    magnitude = "realistic"

    [validation.simulate]      # SimConfig overrides: reduced sizes keep a run short
    n_poses = 200
    hanging_cycles = 3.0
    walk_cycles = 1.0

    [output]
    dir = "../reports/diagnose_validation"

The sweep (issue 13, item 5) runs (a) ``n_clean`` clean datasets, (b) every library
effect at two sizes, (c) every off-face variant at two sizes (effects whose realistic
range is one value, the all-or-nothing faults and ``moving_com``, run that value twice,
on two seeds), each on its own seed, and (d) for every dataset of (b) and (c) its clean
twin: the same seed without the effect, and (e) the pairs of ``PAIRS`` (issue 23, item 2), each effect at the
high end of its realistic range, one dataset each (after the twins; no twin). What a correct diagnosis says: the effect's
name for library effects; for a variant its ``expect`` (a library effect for a drift or
casing load of another shape, ``unexplained`` on ``expect_legs`` for a fault outside the
library, ``none`` for pure measurement noise). An effect outside the library counts as
found when it is called ``unexplained`` or placed on exactly its leg(s). Shrinkage is
scored against the clean twin's noise floor on the recording kind the diagnosis reports
it on (``diagnosis.kinds``): after the named effect, held-out RMS within ``tolerance`` x
that floor on every component, for each library effect (of either shape) named right.
``moving_com`` datasets are exact physics calibrated with the report's fixed-CoM balance
(eq. 9); every other dataset, twins included, uses the exact balance. A pair is found when both of its effects are
in the diagnosis' chain (``effects`` of ``diagnosis.json``, ``diagnose/hexchain.py``); a dataset with one library
effect (of either shape) has a false second when the chain names more than one effect.

Outputs in the output folder: ``validation.md`` (the table of issue 13: what | measured
| goal), ``datasets.csv`` (one row per run, twins included), ``scores.csv`` (one row
per dataset with an effect: expected and named labels and legs, verdict, before / after
/ floor against the twin's floor per component, time), ``confusion.csv``/``.md`` and
``summary.json``. The random design writes the confusion matrix and summary of issue 7.

Parallel runs go through joblib: ``Parallel(n_jobs=workers)(delayed(run_one)(...))``,
by default on local processes (loky). Without a ``backend`` key a surrounding
``joblib.parallel_config`` decides, so a large sweep can run on a Dask cluster::

    from dask.distributed import Client
    import joblib
    client = Client("tcp://scheduler:8786")
    with joblib.parallel_config(backend="dask"):
        run_validation({**cfg, "workers": -1}, "reports/sweep")

(or ``backend = "dask"`` in the table, with a client connected). Datasets are
independent and every seed is explicit, so the rows do not depend on the backend.

Part 2, the free-load sweep (issue 23, item 5): payload and URDF (leg4) datasets of the section-5 simulator
(``ftcal_nlp/sim/free/``), each with known effects injected:
``python -m ftcal_nlp.run problems/diagnose_validation_free.toml`` (a ``[validation]`` table with
``design = "free"``). Config::

    [validation]
    design = "free"
    seed = 0                   # dataset i uses simulator (and injector) seed seed * 1000 + i
    kinds = ["payload", "urdf_leg"]
    n_clean = 6                # clean datasets per kind
    effects = [...]            # default: every unit with a free face whose injector works on a free load
    shapes = [...]             # off-face shapes (default: every shape of those effects)
    sizes = "realistic"        # each effect at its realistic low and high end; "test": half its test size and it
    pairs = [[a, b], ...]      # pairs injected together at their test sizes (default: every pair of ``effects``)
    tolerance = 1.5            # shrinkage goal: after / simulated noise sd <= this, every component
    folds = 5
    workers = 1
    backend = "loky"

    [validation.simulate.payload]      # PayloadConfig overrides (not seed, effects)
    [validation.simulate.urdf_leg]     # UrdfLegConfig overrides

The plan, per kind: ``n_clean`` clean datasets; every effect at two sizes (its own injector, the face's
shape); every off-face shape (``Effect.shapes``: another shape of the same effect, injected at its test
size; ``offset_drift_step``, whose default step is in the middle of a hexapod's standing recording, steps in the
middle of the recording); every pair, both at their test sizes. Each dataset is simulated beside its clean twin (same
seed, no effect; the simulator's random streams are apart), and ``injected_noise`` states what was injected beyond a
constant (worst component's sd over the noise sd): a miss of a signal the noise hides says so. An effect (or shape) whose injector cannot work on a kind
(``joint_limit_contact`` on a payload: no joints) is left out of that kind, and the summary lists it.

What a correct diagnosis says and how it is scored (``scores.csv``):

* clean: verdict ``none`` (neither an effect nor ``unexplained``);
* one effect (either shape): ``named`` when the chain (``diagnosis.effects``) contains it; ``first`` when it is
  the first of the chain; ``false second`` when the chain names more than one effect;
* shrunk to the floor: named, and after the chain the held-out RMS within ``tolerance`` x the simulated
  noise sd on every component (the noise is known here; the diagnosis' own floor, from held still
  stretches, is in ``datasets.csv`` beside it);
* pair: ``named`` when both are in the chain; ``false third`` when the chain names another effect beside them.

Outputs (the hexapod sweep's): ``datasets.csv`` (one row per run), ``scores.csv`` (one row per dataset: the
scores above), ``confusion.csv``/``.md`` (expected -> the first effect named, or none / unexplained; single
effects and clean data), ``validation.md`` (the table: what | payload | URDF | goal, and the misses) and
``summary.json``. The goals are issue 23's (pairs >= 80 %, false second <= 1 in 10, clean all) and, for
naming and shrinkage, the hexapod sweep's (>= 90 %, >= 80 %); no threshold of the diagnosis is set here.
"""

from __future__ import annotations

import itertools
import json
import logging
import math
import tempfile
import time
from collections.abc import Callable, Mapping
from typing import Protocol
from dataclasses import fields
from pathlib import Path

import numpy as np
import pandas as pd
from joblib import Parallel, delayed

from ..core.data import WRENCH_COMPONENTS, read_dataset
from ..effects import EFFECTS, EXPECT_NONE, EXPECT_UNEXPLAINED, Effect, applies_to
from ..effects.injection import EffectInjector, Magnitude
from ..core.errors import DataFormatError, MisSignedChannel
from ..core.settings import CalibrationSettings, DiagnoseSettings, HangingSettings, StandingSettings
from ..sim import SimConfig, simulate
from ..sim.free.config import CONFIG_OF_KIND, FREE_SIM_KINDS
from ..sim.effects import EFFECTS as INJECTORS
from ..sim.variants import VARIANTS
from .result import DiagnosisResult


class DiagnosedRun(Protocol):
    """What the validation reads of a calibration run (:class:`~ftcal_nlp.calibration_run.CalibrationRun`, above
    the diagnosis: a Protocol keeps the import out): its diagnosis, stage times and notes."""

    @property
    def diagnosis(self) -> DiagnosisResult | None: ...
    @property
    def timings(self) -> Mapping[str, float]: ...
    @property
    def notes(self) -> tuple[str, ...]: ...


#: :func:`ftcal_nlp.calibrate` (dataset, settings) -> a calibration run with its ``diagnosis``
Calibrate = Callable[..., DiagnosedRun]


def _magnitude(name: str) -> Magnitude:
    """The magnitude of the simulator's injector ``name`` (every one in its registry an :class:`EffectInjector` class)."""
    cls = INJECTORS[name]
    assert isinstance(cls, type) and issubclass(cls, EffectInjector), f"{name}: the simulator's registry holds injector classes"
    return cls.magnitude

log = logging.getLogger(__name__)

DEFAULTS = {"design": "sweep", "seed": 0, "n_clean": 6, "effects": None, "variants": None, "sizes": "realistic",
            "tolerance": 1.5, "model": "full", "folds": 5, "workers": 1, "backend": "loky", "pairs": None,
            "n_datasets": 24, "clean_share": 0.15, "magnitude": "realistic"}
SIM_DEFAULTS = {"n_poses": 200, "hanging_cycles": 3.0, "walk_cycles": 1.0}
DESIGNS = ("sweep", "random")
RANDOM_KEYS = ("n_datasets", "clean_share", "magnitude")        # design "random" only
SWEEP_KEYS = ("n_clean", "variants", "sizes", "tolerance", "pairs")   # design "sweep" only
SIZES = ("realistic", "test")
GOAL_LIBRARY = 0.9     # issue 13: >= 18/20 library effects named right (the free-load sweep's too)
GOAL_SHRINKAGE = 0.8   # issue 13: >= 13/16 within the twin's floor (free loads: within the simulated noise)
GOAL_PAIRS = 0.8       # issue 23: two effects injected together both named in >= 80 % of cases
GOAL_FALSE_SECOND = 0.1   # issue 23: a single effect grows a false second in <= 1 case in 10
#: the pairs of the sweep (issue 23, item 2): library effects whose faces follow different things, each at the high
#: end of its realistic range: time / shaft angle, weighed mass / a common tilt, load / pose history, shaft angle /
#: a cable, time / shaft speed, pose history / mass, load tilt / shaft angle, load nonlinearity / time, a cable / time
PAIRS = (("offset_drift", "casing_load"), ("robot_mass", "mocap_bias"), ("gain_crosstalk", "hysteresis"),
         ("casing_load", "tether_force"), ("offset_drift", "leg_inertia"), ("hysteresis", "robot_mass"),
         ("chassis_flex", "casing_load"), ("sensor_nonlinearity", "offset_drift"), ("tether_force", "offset_drift"))
COMPONENTS = tuple(WRENCH_COMPONENTS)
REJECTED = "rejected"   # ``named`` of a dataset an input check refused naming a leg's column (run_one)


# ============================================================================= part 1: hexapods, plans


def plan(cfg: dict) -> list[dict]:
    """The random design (issue 7): ``index``, ``seed``, ``effect`` (or "none"), ``scale``; datasets cycle
    through ``[none] + effects`` (clean ones as ``clean_share`` asks), shuffled by ``seed``."""
    effects = config_names(cfg.get("effects"), EFFECTS, "effects", HEXAPOD_EFFECTS)
    n = int(cfg["n_datasets"])
    rng = np.random.default_rng(int(cfg["seed"]))
    n_clean = int(round(cfg["clean_share"] * n))
    labels = ["none"] * n_clean + [effects[i % len(effects)] for i in range(n - n_clean)]
    labels = [labels[i] for i in rng.permutation(n)]
    out = []
    for i, lab in enumerate(labels):
        scale = None
        if lab != "none":
            mag = EFFECTS[lab].magnitude
            scale = float(mag.test) if cfg["magnitude"] == "test" else float(rng.uniform(*mag.realistic))
        out.append({"index": i, "seed": int(cfg["seed"]) * 1000 + i, "effect": lab, "scale": scale})
    return out


#: the hexapod sweep's defaults: the effects with hexapod faces, the shapes a hexapod simulation takes whose
#: expectation a hexapod diagnosis can meet (the free-load effects of issue 23 have their own sweep)
HEXAPOD_EFFECTS = tuple(n for n, u in EFFECTS.items() if "hexapod" in u.diagnosed_on)
HEXAPOD_VARIANTS = tuple(n for n, c in VARIANTS.items() if "hexapod" in applies_to(n)
                         and (c.expect not in EFFECTS or c.expect in HEXAPOD_EFFECTS))


def effect_sizes(name: str, sizes: str) -> tuple[tuple[str, float], tuple[str, float]]:
    """Two ``(label, scale)`` of effect ``name``: its realistic low and high end, or half its test size and
    the test size; an all-or-nothing effect (realistic range one value) runs that value twice."""
    mag = _magnitude(name)
    lo, hi = (float(v) for v in mag.realistic)
    if lo == hi:
        return ("lo", lo), ("hi", hi)
    if sizes == "realistic":
        return ("lo", lo), ("hi", hi)
    return ("half", float(mag.test) / 2.0), ("test", float(mag.test))


def expectation(name: str, scale: float | None, seed: int) -> tuple[str, tuple[str, ...]]:
    """What a correct diagnosis says about effect ``name`` (injected with ``scale``, ``seed``): its label and legs."""
    if name == "none":
        return EXPECT_NONE, ()
    if name in EFFECTS:
        return name, ()
    inj = VARIANTS[name](scale=scale, seed=seed)
    return inj.expect, tuple(inj.expect_legs)


def sweep_plan(cfg: dict) -> list[dict]:
    """The sweep (issue 13): clean datasets, every library effect and off-face variant at two sizes, each on its
    own seed, then one clean twin (same seed, no effect) per dataset with an effect. Items: ``index``, ``seed``,
    ``role`` (clean | library | variant | twin), ``effect``, ``size``, ``scale``, ``expect``, ``expect_legs``,
    ``twin`` (the twin's index; twins: the index of their dataset)."""
    effects = config_names(cfg.get("effects"), EFFECTS, "effects", HEXAPOD_EFFECTS)
    variants = config_names(cfg.get("variants"), VARIANTS, "variants", HEXAPOD_VARIANTS)
    base = int(cfg["seed"]) * 1000
    rows: list[tuple[str, str, str, float | None]] = [("clean", "none", "", None) for _ in range(int(cfg["n_clean"]))]
    for role, names in (("library", effects), ("variant", variants)):
        for name in names:
            rows += [(role, name, label, scale) for label, scale in effect_sizes(name, cfg["sizes"])]
    items = []
    for i, (role, name, size, scale) in enumerate(rows):
        expect, legs = expectation(name, scale, base + i)
        items.append({"index": i, "seed": base + i, "role": role, "effect": name, "size": size, "scale": scale,
                      "expect": expect, "expect_legs": " ".join(legs), "twin": None})
    for it in [x for x in items if x["role"] != "clean"]:
        twin = {"index": len(items), "seed": it["seed"], "role": "twin", "effect": "none", "size": "", "scale": None,
                "expect": EXPECT_NONE, "expect_legs": "", "twin": it["index"]}
        it["twin"] = twin["index"]
        items.append(twin)
    pairs = pair_names(cfg.get("pairs"))
    if cfg.get("pairs") is None:   # the default pairs among the effects withheld
        pairs = [p for p in pairs if set(p) <= set(effects)]
    for a, b in pairs:
        i = len(items)
        scales = [float(_magnitude(n).realistic[1]) for n in (a, b)]
        items.append({"index": i, "seed": base + i, "role": "pair", "effect": f"{a}+{b}", "size": "hi", "scale": None,
                      "scales": " ".join(f"{v:g}" for v in scales), "expect": f"{a}+{b}", "expect_legs": "", "twin": None})
    return items


def pair_names(value) -> list[tuple[str, str]]:
    """``[validation].pairs`` (``"a+b"`` strings; None: :data:`PAIRS`) as name pairs, checked (hexapod library effects
    that need no other balance, two different ones)."""
    if value is None:
        return list(PAIRS)
    if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
        raise ValueError(f"[validation].pairs: expected a list of \"effect+effect\" strings, got {value!r}")
    out = []
    for v in value:
        pair = tuple(v.split("+"))
        bad = [n for n in pair if n not in HEXAPOD_EFFECTS or EFFECTS[n].needs_report_balance]
        if len(pair) != 2 or pair[0] == pair[1] or bad:
            raise ValueError(f"[validation].pairs: {v!r} is not two different hexapod library effects joined by '+' "
                             f"(known: {sorted(n for n in HEXAPOD_EFFECTS if not EFFECTS[n].needs_report_balance)})")
        out.append(pair)
    return out


# ============================================================================= one dataset


def _settings(cfg: dict, balance: str) -> CalibrationSettings:
    return CalibrationSettings(
        hanging=HangingSettings(compare_baseline=False),
        standing=StandingSettings(model=cfg["model"], balance=balance, compare_baseline=False),
        diagnose=DiagnoseSettings(folds=int(cfg["folds"]), seed=0))


def _diagnosis_fields(d) -> dict:
    """The row fields of a diagnosis: verdict, named, legs, shrinkage per component, floors per kind."""
    sh = d.shrinkage
    b, a, f = (np.asarray(sh[k], float) for k in ("heldout_rms_before", "heldout_rms_after", "noise_floor"))
    kind_key = sh.get("kind_key") or sh.get("kind")
    kinds = {k: {"floor": [float(x) for x in v["noise_floor"]], "rms": [float(x) for x in v["heldout_rms"]]}
             for k, v in (d.kinds or {}).items() if "noise_floor" in v}
    if kind_key not in kinds:  # the reported kind's floor is in the shrinkage itself
        kinds[kind_key] = {"floor": [float(x) for x in f], "rms": [float(x) for x in b]}
    design = getattr(d, "design", None)
    row = {"verdict": d.verdict, "named": d.effect or d.verdict, "legs": " ".join(d.where.get("legs", [])),
           "components": " ".join(d.where.get("components", [])), "kind": sh.get("kind"), "kind_key": kind_key,
           "gaps": ";".join(d.gaps), "explains": d.where.get("explains"),
           "best": d.ranking[0]["effect"] if d.ranking else "", "second": d.ranking[1]["effect"] if len(d.ranking) > 1 else "",
           "effects": " ".join(e["name"] for e in d.effects_list()),
           "rms_ratio_before": float(np.mean(b / f)), "rms_ratio_after": float(np.mean(a / f)),
           "shrinkage_error": float(np.mean(a / f) - 1.0), "kinds_json": json.dumps(kinds),
           "design_tilt_deg": float(np.linalg.norm(design["tilt_deg"])) if design is not None else float("nan"),
           "design_dbic": float(design["delta_bic"]) if design is not None else float("nan"), "diag_s": d.time_s}
    for name, v in (("before", b), ("after", a), ("floor", f)):
        row.update({f"{name}_{c}": float(x) for c, x in zip(COMPONENTS, v)})
    return row


def rejected_leg(exc: DataFormatError, legs) -> str | None:
    """The leg of a mis-signed channel the input check named (``errors.MisSignedChannel``, ``checks.leg_sign_fixes_it``),
    or None: any other input error is an error of the run, not the fault found."""
    leg = getattr(exc, "leg", None) if isinstance(exc, MisSignedChannel) else None
    return leg if leg in legs else None


def run_one(item: dict, cfg: dict, sim_over: dict, calibrate: Calibrate) -> dict:
    """Simulate one dataset and put it through :func:`ftcal_nlp.calibrate` with the diagnosis on; returns its row.
    A failure is recorded in the row (``named`` "error"), never raised: it is a finding of the validation; a dataset
    an input check refuses with an error naming a leg's column is ``named`` "rejected" with that leg (a fault outside
    the library found before the calibration: a mis-signed channel)."""
    t0 = time.perf_counter()
    lab = item["effect"]
    # an effect whose gap exists only under the report's fixed-CoM balance (moving_com) is exact physics: no injector
    report = lab in EFFECTS and EFFECTS[lab].needs_report_balance
    spec = [] if lab == "none" or report else [{"name": lab, "scale": item["scale"], "seed": item["seed"]}]
    if item.get("role") == "pair":   # two effects together, each with the dataset's seed
        spec = [{"name": n, "scale": float(v), "seed": item["seed"]} for n, v in zip(lab.split("+"), str(item["scales"]).split())]
    balance = "report" if report else "exact"
    row = {**item, "balance": balance}
    sim = None
    try:
        sim = simulate(SimConfig.from_dict({**sim_over, "seed": item["seed"], "effects": spec}))
        run = calibrate(sim.dataset, _settings(cfg, balance))
        row.update(_diagnosis_fields(run.diagnosis))
        row["calib_s"] = sum(v for k, v in run.timings.items() if k != "diagnosis")
    except DataFormatError as exc:
        leg = rejected_leg(exc, sim.dataset.robot.legs if sim is not None else ())
        if leg is None:
            log.exception("dataset %s (%s) failed", item["index"], lab)
            row.update(verdict="error", named="error", error=f"{type(exc).__name__}: {exc}")
        else:   # the input check refused the dataset and named the leg's column: the fault found, not a crash
            log.info("dataset %s (%s): rejected by an input check naming %s", item["index"], lab, exc.column)
            row.update(verdict=REJECTED, named=REJECTED, legs=leg, error=f"{type(exc).__name__}: {exc}")
    except Exception as exc:  # one failed dataset is a finding of the validation, not a reason to stop it
        log.exception("dataset %s (%s) failed", item["index"], lab)
        row.update(verdict="error", named="error", error=f"{type(exc).__name__}: {exc}")
    row["time_s"] = time.perf_counter() - t0
    return row


def _parallel(workers: int, backend: str | None) -> Parallel:
    try:
        return Parallel(n_jobs=workers, backend=backend, return_as="generator")
    except ValueError as exc:
        raise ValueError(f"[validation].backend: {exc}") from exc


def backend_name(par: Parallel) -> str:
    """The joblib backend a ``Parallel`` runs on (e.g. ``LokyBackend``, ``DaskDistributedBackend``)."""
    return type(getattr(par, "_backend", None)).__name__


def run_datasets(items: list[dict], cfg: dict, sim_over: dict, calibrate: Calibrate, workers: int = 1,
                 backend: str | None = None) -> list[dict]:
    """Every item through :func:`run_one` with joblib (``n_jobs=workers``; ``backend`` None: the active one, loky
    unless a ``joblib.parallel_config`` says otherwise); rows in the items' order."""
    par = _parallel(workers, backend)
    log.info("%d datasets on %d worker(s), joblib backend %s", len(items), workers, backend_name(par))
    rows = []
    for row in par(delayed(run_one)(it, cfg, sim_over, calibrate) for it in items):
        rows.append(row)
        log.info("dataset %d (%s %s %s): -> %s%s (%.0f s)", row["index"], row.get("role", ""), row["effect"], row.get("size", ""),
                 row["named"], f" legs {row['legs']}" if row.get("legs") else "", row["time_s"])
    return rows


# ============================================================================= scoring


def _vec(row, prefix: str) -> np.ndarray:
    return np.array([row.get(f"{prefix}_{c}", np.nan) for c in COMPONENTS], float)


def twin_floor(twin: pd.Series | None, kind_key) -> np.ndarray:
    """The clean twin's noise floor (6,) on recording kind ``kind_key`` (NaN when it has none)."""
    if twin is None or twin.get("named") == "error" or not isinstance(twin.get("kinds_json"), str):
        return np.full(6, np.nan)
    kinds = json.loads(twin["kinds_json"])
    return np.asarray(kinds[kind_key]["floor"], float) if kind_key in kinds else np.full(6, np.nan)


def is_right(named: str, legs: str, expect: str, expect_legs: str) -> bool:
    """A correct diagnosis: the expected label; outside the library, ``unexplained`` or exactly the affected leg(s)."""
    if named == "error":
        return False
    if expect == EXPECT_UNEXPLAINED:
        return named == EXPECT_UNEXPLAINED or right_leg(legs, expect_legs)
    return named == expect


def right_leg(legs: str, expect_legs: str) -> bool:
    """The legs named are exactly the affected legs (both non-empty)."""
    a, b = set(str(legs or "").split()), set(str(expect_legs or "").split())
    return bool(b) and a == b


def score(rows: pd.DataFrame, tolerance: float = 1.5) -> pd.DataFrame:
    """One row per dataset with an effect (sweep): outcome, and before / after / own floor against the clean
    twin's floor per component on the kind the diagnosis reports (``*_ratio_<c>``); ``shrink_ok`` for library
    effects named right (NaN otherwise)."""
    by_index = {int(r["index"]): r for _, r in rows.iterrows()}
    out = []
    for _, r in rows[rows["role"].isin(["library", "variant"])].iterrows():
        twin = by_index.get(int(r["twin"])) if pd.notna(r.get("twin")) else None
        f = twin_floor(twin, r.get("kind_key"))
        s = {k: r.get(k) for k in ("index", "seed", "role", "effect", "size", "scale", "expect", "expect_legs",
                                   "named", "legs", "verdict", "kind", "time_s", "error")}
        s["twin"] = None if twin is None else int(twin["index"])
        s["twin_named"] = None if twin is None else twin["named"]
        s["right"] = is_right(r["named"], r.get("legs"), r["expect"], r.get("expect_legs"))
        s["right_leg"] = right_leg(r.get("legs"), r.get("expect_legs")) if r.get("expect_legs") else np.nan
        for name in ("before", "after", "floor"):
            s.update({f"{name}_ratio_{c}": float(v) for c, v in zip(COMPONENTS, _vec(r, name) / f)})
        s.update({f"twin_floor_{c}": float(v) for c, v in zip(COMPONENTS, f)})
        after = _vec(r, "after") / f
        lib = r["expect"] in EFFECTS
        s["shrink_ok"] = bool(np.all(after <= tolerance)) if (lib and s["right"]) else np.nan
        s["worst_after_force"] = float(np.nanmax(after[:3])) if np.isfinite(after[:3]).any() else np.nan
        s["worst_after_torque"] = float(np.nanmax(after[3:])) if np.isfinite(after[3:]).any() else np.nan
        out.append(s)
    return pd.DataFrame(out)


def confusion(rows: pd.DataFrame, labels: list[str]) -> pd.DataFrame:
    """Withheld (rows) x named (columns) counts."""
    withheld = ["none"] + [l for l in dict.fromkeys(labels) if l != "none"]
    cols = withheld + [EXPECT_UNEXPLAINED, "error"]
    M = pd.DataFrame(0, index=withheld, columns=cols)
    for _, r in rows.iterrows():
        M.loc[r["effect"], r["named"] if r["named"] in cols else "error"] += 1
    M = M.loc[:, (M.sum(axis=0) > 0) | M.columns.isin(["none", EXPECT_UNEXPLAINED] + list(EFFECTS))]
    M.index.name = "withheld"
    return M


def summarise(rows: pd.DataFrame, wall_s: float) -> dict:
    """The random design's summary (issue 7): accuracy, false alarms on clean data, shrinkage error, runtime."""
    ok = rows[rows["named"] != "error"]
    correct = ok["named"] == ok["effect"]
    clean = ok[ok["effect"] == "none"]
    eff = ok[(ok["effect"] != "none") & correct]
    per = {}
    for lab, g in ok.groupby("effect"):
        per[lab] = {"n": len(g), "correct": int((g["named"] == lab).sum()),
                    "named": {k: int(v) for k, v in g["named"].value_counts().items()}}
    return {
        "n_datasets": len(rows), "n_errors": int((rows["named"] == "error").sum()),
        "accuracy": float(correct.mean()) if len(ok) else float("nan"),
        "accuracy_effects": float(correct[ok["effect"] != "none"].mean()) if (ok["effect"] != "none").any() else float("nan"),
        "false_alarm_rate_clean": float((clean["named"] != "none").mean()) if len(clean) else float("nan"),
        "n_clean": len(clean),
        "shrinkage_error_median": float(eff["shrinkage_error"].median()) if len(eff) else float("nan"),
        "shrinkage_error_max": float(eff["shrinkage_error"].max()) if len(eff) else float("nan"),
        "per_effect": per, "wall_time_s": float(wall_s),
        "mean_time_per_dataset_s": float(rows["time_s"].mean()) if len(rows) else float("nan"),
    }


def _count(mask) -> tuple[int, int]:
    m = np.asarray(mask, bool)
    return int(m.sum()), int(m.size)


def _role(rows: pd.DataFrame, role: str) -> pd.DataFrame:
    return rows[rows["role"] == role] if "role" in rows else rows.iloc[:0]


def n_named(row) -> int:
    """How many effects the diagnosis' chain named (``effects`` column; a failed run: 0)."""
    e = row.get("effects")
    return len(str(e).split()) if isinstance(e, str) and row.get("named") != "error" else 0


def both_named(row) -> bool:
    """A pair's effects are both in the chain."""
    e = row.get("effects")
    return isinstance(e, str) and row.get("named") != "error" and set(str(row["effect"]).split("+")) <= set(e.split())


def single_library(rows: pd.DataFrame) -> pd.DataFrame:
    """The finished datasets with one library effect (either shape): what a false second is counted on."""
    if "role" not in rows:
        return rows.iloc[:0]
    return rows[rows["role"].isin(["library", "variant"]) & rows["expect"].isin(list(EFFECTS)) & (rows["named"] != "error")]


def sweep_summary(rows: pd.DataFrame, scores: pd.DataFrame, wall_s: float, tolerance: float) -> dict:
    """Counts of the sweep (issue 13's table): each ``[right, n]``, plus the misses that explain them."""
    sc = scores if len(scores) else pd.DataFrame(columns=["role", "expect", "right", "right_leg", "shrink_ok", "effect", "named"])
    lib = sc[sc["role"] == "library"]
    shape = sc[(sc["role"] == "variant") & sc["expect"].isin(list(EFFECTS))]
    outside = sc[sc["expect"] == EXPECT_UNEXPLAINED]
    noise = sc[(sc["role"] == "variant") & (sc["expect"] == EXPECT_NONE)]
    named_right = sc[sc["expect"].isin(list(EFFECTS)) & (sc["right"] == True)]  # noqa: E712 (object column)
    clean = rows[rows["role"] == "clean"]
    twins = rows[rows["role"] == "twin"]
    return {
        "library": _count(lib["right"].astype(bool)),
        "library_shape": _count(shape["right"].astype(bool)),
        "clean": _count(clean["named"] == "none"),
        "twins_clean": _count(twins["named"] == "none"),
        "outside": _count(outside["right"].astype(bool)),
        "outside_unexplained": _count(outside["named"] == EXPECT_UNEXPLAINED),
        "outside_right_leg": _count(outside["right_leg"] == True),  # noqa: E712
        "shrinkage": _count(named_right["shrink_ok"] == True),  # noqa: E712
        "shrinkage_exact_shape": _count(named_right[named_right["role"] == "library"]["shrink_ok"] == True),  # noqa: E712
        "noise_none": _count(noise["named"] == EXPECT_NONE),
        "pairs": _count([both_named(r) for _, r in _role(rows, "pair").iterrows()]),
        "false_second": _count([n_named(r) > 1 for _, r in single_library(rows).iterrows()]),
        "finished": _count(rows["named"] != "error"),
        "tolerance": tolerance, "n_runs": len(rows), "wall_time_s": float(wall_s),
        "mean_time_per_run_s": float(rows["time_s"].mean()) if len(rows) else float("nan"),
    }


# ============================================================================= the table


def _goal(n: int, share: float = 1.0) -> str:
    k = math.ceil(share * n - 1e-9)
    return f"{n}/{n}" if k >= n else f">= {k}/{n}"


def _misses(df: pd.DataFrame, show_legs: bool = False, limit: int = 6) -> str:
    """``effect -> named`` of the misses in ``df``, grouped, most frequent first."""
    miss = df[~df["right"].astype(bool)]
    if not len(miss):
        return ""
    keys = []
    for _, r in miss.iterrows():
        leg = f" ({r['expect_legs']})" if show_legs and r.get("expect_legs") else ""
        got = "error" if r["named"] == "error" else f"`{r['named']}`"
        where = ""
        if show_legs and r["named"] != "error":
            where = f", legs {r['legs']}" if r.get("legs") else ", no leg"
        keys.append(f"{r['effect']}{leg}: {got}{where}")
    counts = pd.Series(keys).value_counts()
    parts = [k + (f" x{v}" if v > 1 else "") for k, v in counts.items()]
    return "; ".join(parts[:limit]) + ("; ..." if len(parts) > limit else "")


def _frac(pair) -> str:
    return f"{pair[0]}/{pair[1]}"


def _shrinkage_detail(named_right: pd.DataFrame, rows: pd.DataFrame) -> str:
    if not len(named_right):
        return "no library effect named right"
    f = named_right["worst_after_force"].median()
    t = named_right["worst_after_torque"].median()
    twins = rows[(rows["role"] == "twin") & (rows["named"] != "error")]
    tf = float(np.nanmedian(twins[[f"floor_{c}" for c in COMPONENTS[3:]]].to_numpy(float))) if len(twins) else float("nan")
    ff = float(np.nanmedian(twins[[f"floor_{c}" for c in COMPONENTS[:3]]].to_numpy(float))) if len(twins) else float("nan")
    return (f"worst component after / twin floor, median: forces {f:.2g}x, torques {t:.2g}x "
            f"(twin floors ~{ff:.2g} N, ~{tf:.2g} N*m)")


def _label_list(df: pd.DataFrame, unit: str) -> str:
    parts = []
    for _, r in df.iterrows():
        s = f"{r['scale']:g} {unit}: `{r['named']}`"
        if r["named"] == EXPECT_UNEXPLAINED and r.get("legs"):
            s += f" (legs {r['legs']})"
        parts.append(s)
    return ", ".join(parts) or "-"


def validation_table(rows: pd.DataFrame, scores: pd.DataFrame, summary: dict) -> str:
    """Issue 13's table (what | measured | goal) from the sweep's rows and scores."""
    sc = scores
    tol = summary["tolerance"]
    lines = ["| what | measured | goal |", "|---|---|---|"]

    def add(what: str, pair, detail: str, goal: str) -> None:
        lines.append(f"| {what} | {_frac(pair)}" + (f" ({detail})" if detail else "") + f" | {goal} |")

    if len(sc):
        lib = sc[sc["role"] == "library"]
        shape = sc[(sc["role"] == "variant") & sc["expect"].isin(list(EFFECTS))]
        outside = sc[sc["expect"] == EXPECT_UNEXPLAINED]
        named_right = sc[sc["expect"].isin(list(EFFECTS)) & sc["right"].astype(bool)]
    else:
        lib = shape = outside = named_right = sc
    s = summary
    if s["library"][1]:
        add("library effects named right", s["library"], _misses(lib), _goal(s["library"][1], GOAL_LIBRARY))
    if s["library_shape"][1]:
        add("library effects of another shape (drift ramp / step / fast warm-up, casing load 3rd + 5th harmonics) named right",
            s["library_shape"], _misses(shape), _goal(s["library_shape"][1], GOAL_LIBRARY))
    clean = rows[rows["role"] == "clean"]
    cmiss = clean[clean["named"] != "none"]["named"].value_counts()
    cdetail = ", ".join(f"{v} called `{k}`" for k, v in cmiss.items())
    if s["twins_clean"][1]:
        cdetail = (cdetail + "; " if cdetail else "") + f"clean twins called clean {_frac(s['twins_clean'])}"
    add("clean data called clean", s["clean"], cdetail, _goal(s["clean"][1]))
    if s["outside"][1]:
        det = f"`unexplained` {_frac(s['outside_unexplained'])}, right leg {_frac(s['outside_right_leg'])}"
        rej = outside[outside["named"] == REJECTED]
        if len(rej):
            det += "; " + ", ".join(f"{r['effect']} {r.get('size') or ''} ({r['legs']}) rejected by the input check naming its leg"
                                    for _, r in rej.iterrows())
        m = _misses(outside, show_legs=True)
        add("outside the library: `unexplained`, or placed on the right leg", s["outside"], det + (f"; misses: {m}" if m else ""),
            _goal(s["outside"][1]))
    if s["shrinkage"][1] or s["library"][1]:
        det = (f"of the library effects named right; exact shape {_frac(s['shrinkage_exact_shape'])}; "
               + _shrinkage_detail(named_right, rows))
        add(f"after the named effect, held-out RMS within {tol:g}x the floor of a clean twin, every component", s["shrinkage"], det,
            _goal(s["shrinkage"][1], GOAL_SHRINKAGE))
    if s.get("pairs", (0, 0))[1]:
        pr = _role(rows, "pair")
        miss = [f"{r['effect']}: " + (" then ".join(f"`{n}`" for n in str(r.get("effects") or "").split()) or f"`{r['named']}`")
                for _, r in pr.iterrows() if not both_named(r)]
        add("two effects injected together (each at the high end of its realistic range): both named", s["pairs"],
            "; ".join(miss), f">= {100 * GOAL_PAIRS:.0f}%")
    if s.get("false_second", (0, 0))[1]:
        sl = single_library(rows)
        extra = [f"{r['effect']} {r.get('size') or ''}: " + " then ".join(f"`{n}`" for n in str(r["effects"]).split())
                 for _, r in sl.iterrows() if n_named(r) > 1]
        add("one library effect (either shape): a false second named", s["false_second"], "; ".join(extra),
            f"<= {100 * GOAL_FALSE_SECOND:.0f}%")
    err = rows[rows["named"] == "error"]
    edet = "; ".join(f"{r['effect']} {r.get('size') or ''}: {str(r.get('error', ''))[:80]}" for _, r in err.head(4).iterrows())
    add("runs that finish", s["finished"], edet, _goal(s["finished"][1]))
    tilt = rows[(rows["role"] == "library") & (rows["effect"] == "mocap_bias")]
    if len(tilt):
        parts = []
        for _, r in tilt.iterrows():
            p = f"{r['scale']:g} deg: `{r['named']}`"
            if r["named"] == "none" and np.isfinite(r.get("design_tilt_deg", np.nan)):
                p += f" (design check tilt {r['design_tilt_deg']:.2f} deg, dBIC {r['design_dbic']:.0f})"
            parts.append(p)
        lines.append(f"| a common motion-capture tilt | {', '.join(parts)} | `mocap_bias`, or `none` with the design check saying why |")
    noise = sc[(sc["role"] == "variant") & (sc["expect"] == EXPECT_NONE)] if len(sc) else sc
    if len(noise):
        parts = []
        for _, r in noise.iterrows():
            p = f"{r['scale']:g} deg: `{r['named']}`"
            fr = np.array([r[f"floor_ratio_{c}"] for c in COMPONENTS], float)
            if np.isfinite(fr).any():
                p += f" (floor {np.nanmin(fr):.2g}-{np.nanmax(fr):.2g}x the twin's)"
            parts.append(p)
        lines.append(f"| larger per-pose motion-capture noise (simulator 0.05 deg per pose) | {', '.join(parts)} | "
                     "`none` (measurement noise, with its size) |")
    return "\n".join(lines) + "\n"


def _markdown(M: pd.DataFrame, summary: dict) -> str:
    """The random design's confusion matrix and summary line."""
    cols = [M.index.name or "withheld"] + [str(c) for c in M.columns]
    lines = ["| " + " | ".join(cols) + " |", "|" + "|".join(["---"] + ["---:"] * len(M.columns)) + "|"]
    for idx, r in M.iterrows():
        lines.append("| " + " | ".join([str(idx)] + [(f"**{v}**" if c == idx and v else str(v)) for c, v in r.items()]) + " |")
    if "accuracy" in summary:
        lines += ["", f"accuracy {summary['accuracy']:.2f} ({summary['n_datasets']} datasets, {summary['n_errors']} errors); "
                  f"false-alarm rate on clean data {summary['false_alarm_rate_clean']:.2f} ({summary['n_clean']} clean); "
                  f"shrinkage error (mean held-out RMS / floor - 1, correctly named) median {summary['shrinkage_error_median']:.2f}, "
                  f"max {summary['shrinkage_error_max']:.2f}; wall time {summary['wall_time_s']:.0f} s"]
    return "\n".join(lines) + "\n"


# ============================================================================= running


def check_config(cfg: dict) -> tuple[dict, dict]:
    """``(settings, simulator overrides)`` of a ``[validation]`` table; errors name the key."""
    unknown = sorted(set(cfg) - set(DEFAULTS) - {"simulate"})
    if unknown:
        raise ValueError(f"[validation]: unknown key(s) {unknown}; known keys: {sorted(DEFAULTS) + ['simulate']}")
    c = {**DEFAULTS, **{k: v for k, v in cfg.items() if k != "simulate"}}
    if "design" not in cfg:  # a table of issue 7's keys keeps meaning what it meant
        c["design"] = "random" if any(k in cfg for k in RANDOM_KEYS) else "sweep"
    for key in (RANDOM_KEYS if c["design"] == "sweep" else SWEEP_KEYS):
        if key in cfg:
            raise ValueError(f"[validation].{key}: only for design = {'random' if c['design'] == 'sweep' else 'sweep'!r} "
                             f"(this table's design is {c['design']!r})")
    for key, choices in (("design", DESIGNS), ("sizes", SIZES), ("magnitude", SIZES)):
        if c[key] not in choices:
            raise ValueError(f"[validation].{key}: expected one of {list(choices)}, got {c[key]!r}")
    check_numbers(c, (("n_clean", 0), ("folds", 2), ("n_datasets", 1), ("seed", 0)), " (joblib n_jobs; -1: every core)")
    if c["design"] == "sweep":
        pair_names(c["pairs"])   # bad pairs fail here, naming the key
    if not isinstance(c["backend"], str):
        raise ValueError(f"[validation].backend: expected a joblib backend name such as 'loky' or 'dask', got {c['backend']!r}")
    if not isinstance(c["model"], str):
        raise ValueError(f"[validation].model: expected a model name, got {c['model']!r}")
    sim = cfg.get("simulate", {})
    if not isinstance(sim, dict):
        raise ValueError("[validation.simulate]: expected a table of SimConfig settings")
    if "seed" in sim or "effects" in sim:
        raise ValueError("[validation.simulate]: 'seed' and 'effects' are set per dataset by the validation; remove them")
    sim_over = {**SIM_DEFAULTS, **sim}
    SimConfig.from_dict(sim_over, where="[validation.simulate]")  # bad keys fail here, not in every worker
    return c, sim_over


def run_items(items: list[dict], c: dict, sim_over: dict, out_dir: str | Path, calibrate: Calibrate,
              backend: str | None = None) -> dict:
    """Run ``items`` (a plan), score them as ``c["design"]`` asks and write the outputs into ``out_dir``;
    returns the summary."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    rows = pd.DataFrame(run_datasets(items, c, sim_over, calibrate, int(c["workers"]), backend))
    wall = time.perf_counter() - t0
    rows.to_csv(out / "datasets.csv", index=False)
    if c["design"] == "random":
        labels = ["none"] + config_names(c.get("effects"), EFFECTS, "effects")
        M = confusion(rows, labels)
        summary = summarise(rows, wall)
        M.to_csv(out / "confusion.csv")
        (out / "confusion.md").write_text(_markdown(M, summary))
        (out / "summary.json").write_text(json.dumps(summary, indent=1))
        print(_markdown(M, summary))
        return summary
    scores = score(rows, float(c["tolerance"]))
    summary = sweep_summary(rows, scores, wall, float(c["tolerance"]))
    summary.update(backend=backend_name(_parallel(int(c["workers"]), backend)), workers=int(c["workers"]),
                   simulate=sim_over, seed=int(c["seed"]), sizes=c["sizes"])
    table = validation_table(rows, scores, summary)
    head = (f"Withheld-effect validation: {summary['n_runs']} runs ({int((rows['role'] == 'twin').sum())} clean twins), "
            f"sizes {c['sizes']}, seed {c['seed']}, simulator {sim_over}; wall time {wall:.0f} s on {c['workers']} worker(s).\n\n")
    scores.to_csv(out / "scores.csv", index=False)
    single = rows[~rows["role"].isin(["twin", "pair"])]   # the pairs have their own row of the table
    M = confusion(single, ["none"] + list(dict.fromkeys(single["effect"])))
    M.to_csv(out / "confusion.csv")
    (out / "confusion.md").write_text(_markdown(M, {}))
    (out / "validation.md").write_text(head + table)
    (out / "summary.json").write_text(json.dumps(summary, indent=1, default=str))
    print(head + table)
    return summary


def run_validation(cfg: dict, out_dir: str | Path, calibrate: Calibrate) -> dict:
    """Run the validation of ``cfg`` (the ``[validation]`` table, optionally with a ``simulate``
    sub-table) and write its outputs into ``out_dir``; returns the summary. ``design = "free"``: the free-load
    sweep of issue 23 (:func:`run_free_validation`). ``calibrate``: :func:`ftcal_nlp.calibrate` (passed in: the
    diagnosis sits below the pipeline that runs it)."""
    if cfg.get("design") == "free":
        return run_free_validation(cfg, out_dir, calibrate)
    c, sim_over = check_config(cfg)
    items = sweep_plan(c) if c["design"] == "sweep" else plan(c)
    # No backend key: joblib's active backend (loky, or that of a surrounding joblib.parallel_config).
    return run_items(items, c, sim_over, out_dir, calibrate, backend=cfg.get("backend"))


# ============================================================================= both: the config's names


def config_names(value, known, key: str, default=None, noun: str = "effect") -> list[str]:
    """The names of ``[validation].<key>`` (None: ``default``, or every name of ``known``), checked against
    ``known`` (``noun``: what they name, for the error)."""
    if value is None:
        return list(known if default is None else default)
    if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
        raise ValueError(f"[validation].{key}: expected a list of {noun} names, got {value!r}")
    unknown = [v for v in value if v not in known]
    if unknown:
        raise ValueError(f"[validation].{key}: unknown {noun}(s) {unknown}; known {noun}s: {sorted(known)}")
    return list(value)


def check_numbers(c: dict, integers: tuple, workers_note: str) -> None:
    """The numbers of a ``[validation]`` table, both sweeps': ``integers`` as ``(key, least value)``, ``workers`` a
    non-zero integer (``workers_note``: what it is, for the error), ``tolerance`` a positive factor."""
    for key, lo in integers:
        if not (isinstance(c[key], int) and not isinstance(c[key], bool) and c[key] >= lo):
            raise ValueError(f"[validation].{key}: expected an integer >= {lo}, got {c[key]!r}")
    if not (isinstance(c["workers"], int) and not isinstance(c["workers"], bool) and c["workers"] != 0):
        raise ValueError(f"[validation].workers: expected a non-zero integer{workers_note}, got {c['workers']!r}")
    if not (isinstance(c["tolerance"], (int, float)) and c["tolerance"] > 0):
        raise ValueError(f"[validation].tolerance: expected a positive factor, got {c['tolerance']!r}")


# ============================================================================= part 2: free loads

FREE_KIND_LABEL = {"payload": "payload", "urdf_leg": "URDF (leg4)"}
FREE_DEFAULTS = {"design": "free", "seed": 0, "kinds": list(FREE_SIM_KINDS), "n_clean": 6, "effects": None, "shapes": None,
                 "sizes": "realistic", "pairs": None, "tolerance": 1.5, "folds": 5, "workers": 1, "backend": "loky"}
#: shapes whose default timing is a hexapod session's (a step in the middle of the standing recording: none in a
#: free-load recording): the sweep puts that keyword in the middle of the recording (written in ``injectors``)
AT_MIDDLE = {"offset_drift_step": "t_step_s"}


def free_effects() -> list[str]:
    """The library's effects the free-load diagnosis can name (a free face: ``free_shapes`` overridden) whose
    injector works on a free load (``applies_to`` "free"), in registry order."""
    return [n for n, u in EFFECTS.items()
            if "free" in u.applies_to and type(u).free_shapes is not Effect.free_shapes]


def shapes_of(effects: list[str]) -> list[str]:
    """Every off-face shape of ``effects`` (``Effect.shapes``) that a free-load simulator takes."""
    return [s.name for n in effects for s in EFFECTS[n].shapes if "free" in applies_to(s.name)]


def _shape_class(name: str):
    for u in EFFECTS.values():
        for s in u.shapes:
            if s.name == name:
                return s
    raise ValueError(f"[validation].shapes: unknown shape {name!r}; known: {shapes_of(free_effects())}")


# ============================================================================= config


def free_check_config(cfg: dict) -> tuple[dict, dict]:
    """``(settings, {kind: simulator overrides})`` of a ``[validation]`` table with ``design = "free"``;
    errors name the key."""


    unknown = sorted(set(cfg) - set(FREE_DEFAULTS) - {"simulate"})
    if unknown:
        raise ValueError(f"[validation] (design 'free'): unknown key(s) {unknown}; known keys: {sorted(FREE_DEFAULTS) + ['simulate']}")
    c = {**FREE_DEFAULTS, **{k: v for k, v in cfg.items() if k != "simulate"}}
    c["kinds"] = config_names(c["kinds"], list(FREE_SIM_KINDS), "kinds", noun="kind")
    lib = free_effects()
    c["effects"] = lib if c["effects"] is None else config_names(c["effects"], lib, "effects")
    all_shapes = shapes_of(lib)
    c["shapes"] = shapes_of(c["effects"]) if c["shapes"] is None else config_names(c["shapes"], all_shapes, "shapes", noun="shape")
    if c["pairs"] is None:
        c["pairs"] = [list(p) for p in itertools.combinations(c["effects"], 2)]
    elif not (isinstance(c["pairs"], (list, tuple)) and all(isinstance(p, (list, tuple)) and len(p) == 2 for p in c["pairs"])):
        raise ValueError(f"[validation].pairs: expected a list of [effect, effect] pairs, got {c['pairs']!r}")
    else:
        c["pairs"] = [config_names(list(p), lib, "pairs") for p in c["pairs"]]
        if any(a == b for a, b in c["pairs"]):
            raise ValueError("[validation].pairs: a pair names two different effects")
    if c["sizes"] not in ("realistic", "test"):
        raise ValueError(f"[validation].sizes: expected 'realistic' or 'test', got {c['sizes']!r}")
    check_numbers(c, (("n_clean", 0), ("folds", 2), ("seed", 0)), " (joblib n_jobs)")
    sim = cfg.get("simulate", {})
    if not isinstance(sim, dict) or not all(isinstance(v, dict) for v in sim.values()):
        raise ValueError("[validation.simulate]: expected sub-tables [validation.simulate.payload] / [validation.simulate.urdf_leg]")
    bad = sorted(set(sim) - set(FREE_SIM_KINDS))
    if bad:
        raise ValueError(f"[validation.simulate]: unknown kind(s) {bad}; kinds: {list(FREE_SIM_KINDS)}")
    over = {}
    for kind in c["kinds"]:
        o = dict(sim.get(kind, {}))
        if "seed" in o or "effects" in o or "kind" in o:
            raise ValueError(f"[validation.simulate.{kind}]: 'seed', 'effects' and 'kind' are set per dataset; remove them")
        known = {f.name for f in fields(CONFIG_OF_KIND[kind])}
        if set(o) - known:
            raise ValueError(f"[validation.simulate.{kind}]: unknown key(s) {sorted(set(o) - known)}; known: {sorted(known)}")
        over[kind] = o
    return c, over


# ============================================================================= plan


def free_effect_sizes(name: str, sizes: str) -> list[tuple[str, float]]:
    """Two ``(label, scale)`` of effect ``name``: its realistic low and high end, or half its test size and it."""
    mag = EFFECTS[name].magnitude
    lo, hi = (float(v) for v in mag.realistic)
    if sizes == "realistic":
        return [("lo", lo), ("hi", hi)]
    return [("half", float(mag.test) / 2.0), ("test", float(mag.test))]


def _works_on(injector: str, kind: str, over: dict, cache: dict) -> bool:
    """Whether ``injector`` works on a dataset of ``kind`` (a small simulation with it does not raise ValueError)."""
    from ..sim.free import config_from_dict, simulate_free

    key = (injector, kind)
    if key not in cache:
        small = {"n_orientations": 2, "hold_s": 1.0, "move_s": 0.5}
        if kind == "urdf_leg":
            small["poses_per_orientation"] = 2
        try:
            simulate_free(config_from_dict({"kind": kind, **over, **small, "effects": [{"name": injector}]}))
            cache[key] = True
        except ValueError as exc:
            log.info("%s does not apply to %s datasets: %s", injector, kind, exc)
            cache[key] = False
    return cache[key]


def free_plan(c: dict, over: dict) -> tuple[list[dict], list[str]]:
    """The datasets (module docstring) and the ``effect on kind`` combinations left out. Items: ``index``,
    ``seed``, ``kind``, ``role`` (clean | effect | shape | pair), ``label``, ``injectors`` (JSON list of
    ``{name, scale, seed}``), ``size``, ``scale``, ``expect`` (effect names joined by "+"; "" for clean)."""
    base = int(c["seed"]) * 1000
    # (kind, role, label, injectors (name, scale), size, scale, expected names)
    rows: list[tuple[str, str, str, list[tuple[str, float]], str, float | None, list[str]]] = []
    skipped: list[str] = []
    cache: dict[tuple[str, str], bool] = {}
    for kind in c["kinds"]:
        o = over[kind]
        ok = lambda name: _works_on(name, kind, o, cache)  # noqa: E731
        rows += [(kind, "clean", "none", [], "", None, []) for _ in range(int(c["n_clean"]))]
        for name in c["effects"]:
            if not ok(name):
                skipped.append(f"{name} on {kind}")
                continue
            rows += [(kind, "effect", name, [(name, s)], lab, s, [name]) for lab, s in free_effect_sizes(name, c["sizes"])]
        for shape in c["shapes"]:
            if not ok(shape):
                skipped.append(f"{shape} on {kind}")
                continue
            cls = _shape_class(shape)
            s = float(cls.magnitude.test)
            rows.append((kind, "shape", shape, [(shape, s)], "test", s, [cls.expect]))
        for a, b in c["pairs"]:
            if not (ok(a) and ok(b)):
                skipped.append(f"{a}+{b} on {kind}")
                continue
            sa, sb = float(EFFECTS[a].magnitude.test), float(EFFECTS[b].magnitude.test)
            rows.append((kind, "pair", f"{a}+{b}", [(a, sa), (b, sb)], "test", None, [a, b]))
    items = []
    for i, (kind, role, label, inj, size, scale, expect) in enumerate(rows):
        seed = base + i
        items.append({"index": i, "seed": seed, "kind": kind, "role": role, "label": label,
                      "injectors": json.dumps([{"name": n, "scale": s, "seed": seed} for n, s in inj]),
                      "size": size, "scale": scale, "expect": "+".join(expect)})
    return items, skipped


# ============================================================================= one dataset


def _free_settings(c: dict) -> CalibrationSettings:
    return CalibrationSettings(diagnose=DiagnoseSettings(enabled=True, folds=int(c["folds"]), seed=0))


def free_run_one(item: dict, c: dict, over: dict, calibrate: Calibrate) -> dict:
    """Simulate one dataset, write it in the interchange format, read it and put it through
    :func:`ftcal_nlp.calibrate` with the diagnosis on; returns its row. A failure is recorded in the row
    (``verdict`` "error"), never raised: it is a finding of the validation."""
    from ..sim.free import config_from_dict, simulate_free, write_free_load

    t0 = time.perf_counter()
    row = dict(item)
    try:
        table = {"kind": item["kind"], **over[item["kind"]], "seed": int(item["seed"])}
        # the clean twin: the same seed without the effects (the simulator's streams are apart: the same motion and
        # noise), for the injected signal's size and the recording's clock
        twin = simulate_free(config_from_dict({**table, "effects": []}))
        injectors = json.loads(item["injectors"])
        for inj in injectors:
            if inj["name"] in AT_MIDDLE and AT_MIDDLE[inj["name"]] not in inj:
                t = twin.frame["t"].to_numpy()
                inj[AT_MIDDLE[inj["name"]]] = float(0.5 * (t[0] + t[-1]))
        row["injectors"] = json.dumps(injectors)
        cfg = config_from_dict({**table, "effects": injectors})
        res = simulate_free(cfg)
        wcols = [f"{cfg.transducer}_{k}" for k in COMPONENTS]
        diff = res.frame[wcols].to_numpy() - twin.frame[wcols].to_numpy()
        with tempfile.TemporaryDirectory(prefix="ftcal_vfree_") as tmp:
            ds = read_dataset(write_free_load(res, Path(tmp) / "data"))
        t1 = time.perf_counter()
        run = calibrate(ds, _free_settings(c))
        d = run.diagnosis
        if d is None:
            raise RuntimeError("no diagnosis: " + "; ".join(run.notes))
        if d.free is None or d.effects is None:
            raise RuntimeError(f"not a free-load diagnosis (verdict {d.verdict}): no per-transducer result")
        noise = np.array([cfg.noise_force_N] * 3 + [cfg.noise_torque_Nm] * 3)
        leg = next(iter(d.free.values()))
        names = [e["name"] for e in d.effects]
        row.update(verdict=d.verdict, first=d.effect or d.verdict, named=" ".join(names), n_named=len(names),
                   explains=d.where.get("explains"), components=" ".join(d.where.get("components", [])),
                   n_samples=int(leg.n), floor_known=bool(leg.floor_known),
                   calib_s=float(sum(v for k, v in run.timings.items() if k != "diagnosis")),
                   diag_s=float(run.timings.get("diagnosis", np.nan)), run_s=time.perf_counter() - t1)
        for name, v in (("before", leg.before), ("after", leg.after), ("floor", leg.floor), ("noise", noise)):
            row.update({f"{name}_{k}": float(x) for k, x in zip(COMPONENTS, v)})
        row["worst_after_noise"] = float(np.max(np.asarray(leg.after) / noise))
        # what was injected, beyond a constant (the offsets absorb that): worst component's sd x the noise sd
        row["injected_noise"] = float(np.max(np.std(diff, axis=0) / noise))
        row["worst_before_noise"] = float(np.max(np.asarray(leg.before) / noise))
    except Exception as exc:  # one failed dataset is a finding of the validation, not a reason to stop it
        log.exception("dataset %s (%s %s) failed", item["index"], item["kind"], item["label"])
        row.update(verdict="error", first="error", named="", n_named=0, error=f"{type(exc).__name__}: {exc}")
    row["time_s"] = time.perf_counter() - t0
    return row


def free_run_datasets(items: list[dict], c: dict, over: dict, calibrate: Calibrate) -> list[dict]:
    """Every item through :func:`free_run_one` with joblib (``workers``, ``backend``); rows in the items' order."""
    par = _parallel(int(c["workers"]), c.get("backend"))
    rows = []
    for row in par(delayed(free_run_one)(it, c, over, calibrate) for it in items):
        rows.append(row)
        log.info("dataset %d (%s %s %s %s): -> %s [%s] (%.1f s)", row["index"], row["kind"], row["role"], row["label"],
                 row["size"], row["verdict"], row["named"], row["time_s"])
    return rows


# ============================================================================= scores


def free_score(rows: pd.DataFrame, tolerance: float) -> pd.DataFrame:
    """One row per dataset: ``right`` (module docstring), ``first_right``, ``false_second``, ``shrunk``."""
    out = []
    for _, r in rows.iterrows():
        expect = [e for e in str(r["expect"] or "").split("+") if e] if isinstance(r["expect"], str) else []
        named = str(r["named"]).split() if isinstance(r["named"], str) else []
        err = r["verdict"] == "error"
        if r["role"] == "clean":
            right = (not err) and r["verdict"] == "none"
        else:
            right = (not err) and set(expect) <= set(named)
        single = r["role"] in ("effect", "shape")
        worst = r.get("worst_after_noise", np.nan)
        out.append({"index": r["index"], "seed": r["seed"], "kind": r["kind"], "role": r["role"], "label": r["label"],
                    "size": r["size"], "scale": r["scale"], "expect": r["expect"], "verdict": r["verdict"],
                    "named": " ".join(named), "right": bool(right),
                    "first_right": bool(single and not err and r["first"] in expect),
                    "false_second": bool(single and not err and len(named) > 1),
                    "false_third": bool(r["role"] == "pair" and not err and len(set(named) - set(expect)) > 0),
                    "extra": " ".join(n for n in named if n not in expect),
                    "injected_noise": r.get("injected_noise", np.nan),
                    "worst_before_noise": r.get("worst_before_noise", np.nan), "worst_after_noise": worst,
                    "shrunk": bool(single and right and np.isfinite(worst) and worst <= tolerance),
                    "time_s": r["time_s"]})
    return pd.DataFrame(out)


def _count_list(mask) -> list[int]:
    return list(_count(mask))


def free_summarise(scores: pd.DataFrame, wall_s: float, c: dict, skipped: list[str]) -> dict:
    """Per kind the counts of the table, each ``[k, n]``."""
    per = {}
    for kind in c["kinds"]:
        s = scores[scores["kind"] == kind]
        single = s[s["role"].isin(["effect", "shape"])]
        per[kind] = {
            "named": _count_list(s[s["role"] == "effect"]["right"]),
            "named_shape": _count_list(s[s["role"] == "shape"]["right"]),
            "first": _count_list(single["first_right"]),
            "shrunk": _count_list(single[single["right"]]["shrunk"]),
            "pairs": _count_list(s[s["role"] == "pair"]["right"]),
            "clean": _count_list(s[s["role"] == "clean"]["right"]),
            "false_second": _count_list(single[single["verdict"] != "error"]["false_second"]),
            "false_third": _count_list(s[(s["role"] == "pair") & (s["verdict"] != "error")]["false_third"]),
            "finished": _count_list(s["verdict"] != "error"),
        }
    return {"per_kind": per, "tolerance": float(c["tolerance"]), "n_runs": int(len(scores)), "wall_time_s": float(wall_s),
            "mean_time_per_run_s": float(scores["time_s"].mean()) if len(scores) else float("nan"),
            "skipped": skipped, "seed": int(c["seed"]), "sizes": c["sizes"], "workers": int(c["workers"])}


def free_confusion(scores: pd.DataFrame) -> pd.DataFrame:
    """Expected (single effects by effect, clean as "none") -> the first effect named (or none / unexplained)."""
    s = scores[scores["role"].isin(["clean", "effect", "shape"])].copy()
    s["expected"] = s["expect"].replace("", "none")
    first = []
    for _, r in s.iterrows():
        first.append(r["named"].split()[0] if r["named"] else r["verdict"])
    s["first named"] = first
    M = pd.crosstab(s["expected"], s["first named"])
    M.index.name = "expected"
    return M


# ============================================================================= the table


def _free_misses(df: pd.DataFrame, col: str = "right", limit: int = 8) -> str:
    miss = df[~df[col].astype(bool)]
    if not len(miss):
        return ""
    keys = []
    for _, r in miss.iterrows():
        got = "error" if r["verdict"] == "error" else (f"`{r['named'].replace(' ', ', ')}`" if r["named"] else f"`{r['verdict']}`")
        size = f" {r['size']}" if r["role"] == "effect" else ""
        # the gap's size before any effect (worst component, x the simulated noise): a miss at ~1x had nothing to see
        gap = (f" (injected sd {r['injected_noise']:.2g}x the noise, gap {r['worst_before_noise']:.2g}x)"
               if np.isfinite(r.get("worst_before_noise", np.nan)) else "")
        keys.append(f"{r['label']}{size}: {got}{gap}")
    counts = pd.Series(keys).value_counts()
    parts = [k + (f" x{v}" if v > 1 else "") for k, v in counts.items()]
    return "; ".join(parts[:limit]) + ("; ..." if len(parts) > limit else "")


def free_validation_table(scores: pd.DataFrame, summary: dict) -> str:
    """The free-load rows: what | payload | URDF (leg4) | goal (goals per kind, as ``payload / URDF``), then the
    misses of each row."""
    kinds = list(summary["per_kind"])
    per = summary["per_kind"]
    tol = summary["tolerance"]
    lines = ["| what | " + " | ".join(FREE_KIND_LABEL[k] for k in kinds) + " | goal |", "|---" * (len(kinds) + 2) + "|"]
    rows = [("each effect at two sizes (realistic low and high end) named", "named", GOAL_LIBRARY, False),
            ("an off-face shape of each effect named", "named_shape", GOAL_LIBRARY, False),
            ("one effect (either shape): named first in the chain", "first", GOAL_LIBRARY, False),
            (f"named and shrunk to the floor (held-out RMS after the chain <= {tol:g}x the simulated noise, every component)",
             "shrunk", GOAL_SHRINKAGE, False),
            ("two effects injected together: both named", "pairs", GOAL_PAIRS, False),
            ("clean kept clean (verdict `none`)", "clean", 1.0, False),
            ("one effect: a false second effect named", "false_second", GOAL_FALSE_SECOND, True),
            ("two effects: a false third named (no goal in the issue; the single effect's rate for scale)", "false_third",
             GOAL_FALSE_SECOND, True),
            ("runs that finish", "finished", 1.0, False)]
    for what, key, share, is_false in rows:
        if not any(per[k][key][1] for k in kinds):
            continue
        cells = [f"{per[k][key][0]}/{per[k][key][1]}" for k in kinds]
        goal = ("<= " if is_false else ("all" if share >= 1 else ">= ")) + ("" if share >= 1 else f"{share:.0%}")
        lines.append(f"| {what} | " + " | ".join(cells) + f" | {goal} |")
    out = "\n".join(lines) + "\n"
    miss_lines = []
    for kind in kinds:
        s = scores[scores["kind"] == kind]
        single = s[s["role"].isin(["effect", "shape"]) & (s["verdict"] != "error")]
        parts = [("named", _free_misses(s[s["role"] == "effect"])), ("shapes", _free_misses(s[s["role"] == "shape"])),
                 ("pairs", _free_misses(s[s["role"] == "pair"])), ("clean", _free_misses(s[s["role"] == "clean"])),
                 ("false second", "; ".join(f"{r['label']} {r['size']}: + `{r['extra'] or r['named']}`"
                                            for _, r in single[single["false_second"]].iterrows())),
                 ("false third", "; ".join(f"{r['label']}: + `{r['extra']}`" for _, r in s[s["false_third"]].iterrows())),
                 ("not shrunk", "; ".join(f"{r['label']} {r['size']}: {r['worst_after_noise']:.2g}x"
                                          for _, r in single[single["right"] & ~single["shrunk"]].iterrows()))]
        txt = "; ".join(f"{k}: {v}" for k, v in parts if v)
        if txt:
            miss_lines.append(f"* {FREE_KIND_LABEL[kind]}: {txt}")
    if summary["skipped"]:
        miss_lines.append("* not applicable (the injector needs what the kind lacks): " + ", ".join(summary["skipped"]))
    return out + ("\nMisses:\n\n" + "\n".join(miss_lines) + "\n" if miss_lines else "")


# ============================================================================= running


def run_free_validation(cfg: dict, out_dir: str | Path, calibrate: Calibrate) -> dict:
    """Run the free-load sweep of ``cfg`` (a ``[validation]`` table with ``design = "free"``), write its
    outputs into ``out_dir``; returns the summary."""
    c, over = free_check_config(cfg)
    items, skipped = free_plan(c, over)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    log.info("free-load sweep: %d datasets on %d worker(s)", len(items), c["workers"])
    t0 = time.perf_counter()
    rows = pd.DataFrame(free_run_datasets(items, c, over, calibrate))
    wall = time.perf_counter() - t0
    rows.to_csv(out / "datasets.csv", index=False)
    scores = free_score(rows, float(c["tolerance"]))
    scores.to_csv(out / "scores.csv", index=False)
    summary = free_summarise(scores, wall, c, skipped)
    summary["simulate"] = over
    M = free_confusion(scores)
    M.to_csv(out / "confusion.csv")
    (out / "confusion.md").write_text(_markdown(M, {}))
    head = (f"Free-load validation: {len(rows)} runs ({', '.join(FREE_KIND_LABEL[k] for k in c['kinds'])}), sizes {c['sizes']}, "
            f"seed {c['seed']}, simulator overrides {over}; wall time {wall:.0f} s on {c['workers']} worker(s), "
            f"{summary['mean_time_per_run_s']:.1f} s per run.\n\n")
    table = free_validation_table(scores, summary)
    (out / "validation.md").write_text(head + table + "\nFirst effect named (single effects and clean data):\n\n" + _markdown(M, {}))
    (out / "summary.json").write_text(json.dumps(summary, indent=1, default=str))
    print(head + table)
    return summary
