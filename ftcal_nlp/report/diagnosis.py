"""The sim-to-real gap diagnosis in the report: its section, tables and figures.

Drawn from a :class:`~ftcal_nlp.diagnose.DiagnosisResult` only (no solving):
the plain-language statement, the held-out RMS before / after the named effect
beside the noise floor, every candidate effect, the residual per recording
kind, and two figures (shrinkage; the strongest dependence of the residual).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from ..core.data import WRENCH_COMPONENTS
from ..diagnose.chain import MIN_EXCESS_SHARE
from ..core.settings import FreeLoadChain
from ..core.results import PM
from .render import Figure, Section, Table, Text

if TYPE_CHECKING:
    from ..diagnose import DiagnosisResult

__all__ = ["diagnosis_section", "fig_shrinkage", "fig_dependence", "shrinkage_table", "ranking_view", "kinds_view",
           "chain_view", "correlates_view", "fig_free_residual", "free_diagnosis_section"]


def _unit(component: str) -> str:
    return "N" if component.startswith("f") else "N*m"


def _g(v: float, digits: int = 3) -> str:
    return f"{v:.{digits}g}" if np.isfinite(v) else "n/a"


def shrinkage_table(d: "DiagnosisResult") -> pd.DataFrame:
    """Held-out RMS per component before and after the named effect, and the noise floor."""
    sh = d.shrinkage
    rows = {"held-out RMS, calibrated model": sh["heldout_rms_before"]}
    if d.effect:
        rows[f"held-out RMS with {' + '.join(_named(d))}"] = sh["heldout_rms_after"]
    rows["noise floor"] = sh["noise_floor"]
    cols = [f"{c} [{_unit(c)}]" for c in WRENCH_COMPONENTS]
    df = pd.DataFrame({k: [_g(v) for v in np.asarray(r, float)] for k, r in rows.items()}, index=cols).T
    df.index.name = f"{sh.get('kind', 'standing')} recordings"
    return df


def _named(d: "DiagnosisResult") -> list[str]:
    """The effects named, in the order added (one name once: free loads list them per transducer)."""
    return list(dict.fromkeys(e["name"] for e in d.effects_list())) or ([d.effect] if d.effect else [])


def joint_view(d: "DiagnosisResult") -> pd.DataFrame | None:
    """The joint refit with the named effect: per recording kind and component, held-out RMS
    before / after and the joint model's floor (``diagnose/refit.py``)."""
    j = d.joint
    if j is None:
        return None
    rows = {}
    for kind, k in j.kinds.items():
        rows[kind] = {f"{c} before / after / floor [{_unit(c)}]": f"{_g(b)} / {_g(a)} / {_g(f, 2)}"
                      for c, b, a, f in zip(WRENCH_COMPONENTS, k.rms_before, k.rms_after, k.floor)}
    out = pd.DataFrame(rows).T
    out.index.name = "recordings"
    return out


def ranking_view(d: "DiagnosisResult") -> pd.DataFrame:
    """Every candidate, best first: delta BIC, share of the gap explained, held-out RMS after (forces, torques), status."""
    t = d.ranking_table()
    f_cols = [f"{c} after [N]" for c in WRENCH_COMPONENTS[:3]]
    t_cols = [f"{c} after [N*m]" for c in WRENCH_COMPONENTS[3:]]
    out = pd.DataFrame(index=t.index)
    out["delta BIC"] = [f"{v:.1f}" if np.isfinite(v) else "n/a" for v in t["delta BIC"]]
    out["explains [%]"] = [f"{100 * v:.0f}" for v in t["explained"]]
    out["held-out RMS fx fy fz [N]"] = [" ".join(_g(v) for v in r) for r in t[f_cols].to_numpy(float)]
    out["held-out RMS tx ty tz [N*m]"] = [" ".join(_g(v) for v in r) for r in t[t_cols].to_numpy(float)]
    out["status"] = t["status"]
    return out


def kinds_view(d: "DiagnosisResult") -> pd.DataFrame:
    """Per recording kind: gap, RMS / floor per component, constant share and what the residual follows."""
    t = d.kinds_table()
    out = pd.DataFrame(index=t.index)
    out["gap"] = t["gap"]
    for c in WRENCH_COMPONENTS:
        u = _unit(c)
        out[f"{c} RMS / floor [{u}]"] = [f"{_g(a)} / {_g(b, 2)}" for a, b in zip(t[f"{c} RMS [{u}]"], t[f"{c} floor [{u}]"])]
    out["constant share"] = [f"{v:.2f}" for v in t["constant share"]]
    out["follows"] = t["follows"]
    return out


def chain_view(d: "DiagnosisResult") -> pd.DataFrame | None:
    """The effects named in order (free loads; hexapods when the chain named more than one): transducer, shape,
    paired block z, share of the excess then left that it removes, held-out RMS after it (forces, torques), and its
    parameters with se."""
    effects = d.effects_list()
    if not effects or (d.free is None and len(effects) < 2):
        return None
    rows = {}
    for i, e in enumerate(effects):
        pars = "; ".join(f"{k} = {v['value']:.4g}" + (f" {PM} {v['se']:.2g}" if v.get("se") is not None else "")
                         for k, v in list(e.get("parameters", {}).items())[:8])
        more = len(e.get("parameters", {})) - 8
        r = np.asarray(e["heldout_rms_after"], float)
        rows[f"{i + 1}. {e['name']}"] = {
            "transducer": e.get("transducer", ""),
            "shape": ", ".join(f"{k} {v}" for k, v in (e.get("shape") or e.get("variant") or {}).items()) or "-",
            "found by": e.get("found_by") or ("the ranking" if i == 0 else "-"),
            "paired z": f"{e['paired_z']:.1f}" if e.get("paired_z") is not None else "-",
            "explains [%]": f"{100 * e['explained']:.0f}" if e.get("explained") is not None else "-",
            "held-out RMS fx fy fz [N]": " ".join(_g(v) for v in r[:3]), "held-out RMS tx ty tz [N*m]": " ".join(_g(v) for v in r[3:]),
            "parameters": pars + (f"; ... ({more} more in diagnosis.json)" if more > 0 else "")}
    out = pd.DataFrame(rows).T
    if d.free is None:   # one transducer set: no column for it
        out = out.drop(columns="transducer")
    else:                # the free-load chain has one way to name an effect
        out = out.drop(columns="found by")
    out.index.name = "effect (in the order added)"
    return out


def correlates_view(d: "DiagnosisResult") -> pd.DataFrame | None:
    """Free loads: per transducer, the share of the held-out excess over the floor each correlate explains."""
    if not d.free:
        return None
    rows = {}
    for leg, f in d.free.items():
        for c in f.correlates:
            rows[f"{leg}: {c.name}"] = {"explains [%]": f"{100 * c.explained:.0f}",
                                        "held-out RMS fx fy fz [N]": " ".join(_g(v) for v in c.heldout_rms[:3]),
                                        "held-out RMS tx ty tz [N*m]": " ".join(_g(v) for v in c.heldout_rms[3:])}
    if not rows:
        return None
    out = pd.DataFrame(rows).T
    out.index.name = "transducer: correlate"
    return out


def fig_free_residual(d: "DiagnosisResult", path: Path) -> Path | None:
    """Free loads: the held-out residual of the channel with the largest gap against the correlate it follows best
    (binned median, the floor as a band): where a gap lies, whatever it is."""
    f = next((x for x in (d.free or {}).values() if x.plot), None)
    if f is None:
        return None
    p = f.plot
    x, y = np.asarray(p["x"], float), np.asarray(p["y"], float)
    fig, ax = plt.subplots(figsize=(7, 3.8))
    fl = float(p["floor"])
    ax.axhspan(-fl, fl, color="0.8", alpha=0.6, label=f"{PM} noise floor", zorder=0)
    _scatter_binned_median(ax, x, y, n_bins=20)
    unit = _unit(p["component"])
    ax.set_xlabel(p["xlabel"])
    ax.set_ylabel(f"residual {p['component']} ({p['leg']}) [{unit}]")
    ax.set_title(f"{p['leg']}: the residual against {p['correlate']} (verdict {f.verdict})", fontsize=10)
    return _finish(fig, ax, path)


def _scatter_binned_median(ax, x: np.ndarray, y: np.ndarray, n_bins: int, min_count: int = 1) -> None:
    """The held-out residual against a correlate (at most 6000 points drawn, seeded: a readable scatter of long
    recordings) and its median in quantile bins of ``x`` (bins with fewer than ``min_count`` samples left blank)."""
    n = len(x)
    idx = np.random.default_rng(0).choice(n, 6000, replace=False) if n > 6000 else np.arange(n)
    ax.plot(x[idx], y[idx], ".", ms=2.5, alpha=0.5, color="tab:blue", label="held-out residual")
    if np.ptp(x) > 0 and n >= 20:
        edges = np.unique(np.quantile(x, np.linspace(0, 1, n_bins + 1)))
        mid = 0.5 * (edges[:-1] + edges[1:])
        which = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(mid) - 1)
        counts = np.bincount(which, minlength=len(mid))
        med = [np.median(y[which == i]) if counts[i] >= min_count else np.nan for i in range(len(mid))]
        ax.plot(mid, med, "-", color="tab:red", lw=2, label="binned median")


def _finish(fig, ax, path: Path) -> Path:
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _add_shrinkage(sec: Section, d: "DiagnosisResult", folder: Path, model: str) -> None:
    """The held-out RMS table and its figure (``model``: what was scored, for the caption), both dataset kinds."""
    sec.add(Table("Held-out RMS per component and the noise floor", shrinkage_table(d)))
    sec.add(Figure("diagnosis_shrinkage.png", fig_shrinkage(d, folder / "diagnosis_shrinkage.png"),
                   f"Held-out RMS of {model} and the noise floor, per component (log scale)."))


def free_diagnosis_section(d: "DiagnosisResult", folder: Path) -> Section:
    """The diagnosis section of a free-load dataset (``diagnose/free.py``): verdict, the chain of effects, the held-out
    RMS per component beside the floor, where the gap lies (correlates) and its figure."""
    sec = Section("Sim-to-real gap diagnosis")
    t = d.thresholds if d.thresholds is not None else FreeLoadChain()   # a result built by hand: the defaults
    sec.add(Text(f"**Verdict: {d.verdict}**" + (f" (first effect **{d.effect}**)." if d.effect else ".")))
    for line in d.statement:
        sec.add(Text(line))
    sec.add(Text("Free loads: the free-load model, linearised around its fit, is scored on every sample (moving ones "
                 "included) by blocked cross-validation (each quasi-static hold with the move after it is a block). The "
                 "noise floor is the readings' scatter within short windows of held, still stretches (no fit enters it). "
                 "Effects are added one at a time, the strongest by held-out evidence first, and refit jointly; the chain "
                 "stops when the next adds nothing significant (paired block-wise z of the log held-out sums of squares "
                 f"below {t.z_min:g}, or a saving under {100 * t.min_floor_share:g} % of the floor's variance or "
                 f"{100 * MIN_EXCESS_SHARE:g} % of the remaining excess)."))
    _add_shrinkage(sec, d, folder, "the free-load model" + (", after the named effects," if d.effect else ""))
    cv = chain_view(d)
    if cv is not None:
        sec.add(Table("The effects named, in the order added (each refit jointly with those before it; "
                      "`calibration_with_effect.json`, which `correct` applies to a new recording, holds the free loads "
                      "refit jointly with all of them)", cv))
    co = correlates_view(d)
    if co is not None:
        sec.add(Table("Where the gap lies: the share of the held-out excess each correlate explains", co))
    fig = fig_free_residual(d, folder / "diagnosis_residual.png")
    if fig is not None:
        sec.add(Figure("diagnosis_residual.png", fig, "The held-out residual of the component with the largest gap against "
                       f"the correlate it follows best; the grey band is {PM} the noise floor."))
    if d.ranking:
        sec.add(Table("Candidate effects of the first step, best first", ranking_view(d)))
    return sec


def diagnosis_section(d: "DiagnosisResult", folder: str | Path) -> Section:
    """The report's diagnosis section; draws its figures into ``folder``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    if d.free is not None:
        return free_diagnosis_section(d, folder)
    sec = Section("Sim-to-real gap diagnosis")
    verdict = {"none": "no gap above the noise floor", "effect": f"the gap is explained by **{d.effect}**",
               "unexplained": "a gap that no candidate effect explains"}[d.verdict]
    sec.add(Text(f"**Verdict: {d.verdict}**" + ("." if d.statement else f" ({verdict}).")))
    for line in d.statement:
        sec.add(Text(line))
    sec.add(Text("Candidates are ranked by the change of BIC (delta BIC, negative: better than the calibrated model) on the "
                 "recordings where the gap lies; every held-out number comes from cross-validation folds (standing) or "
                 "contiguous time blocks (hanging, walking) that the candidate was not fitted to. Noise floors come from what "
                 "cannot be the gap: for the standing poses the within-run scatter of the readings plus a per-pose "
                 "motion-capture tilt error fitted as a variance component on the training residuals; for hanging and "
                 "walking the high-frequency scatter."))
    _add_shrinkage(sec, d, folder, "the calibrated model" + (f", with {d.effect} added," if d.effect else ""))
    dep = fig_dependence(d, folder / "diagnosis_dependence.png")
    if dep is not None:
        sec.add(Figure("diagnosis_dependence.png", dep,
                       "The residual component with the largest gap against the measured variable that explains it best; "
                       f"the grey band is {PM} the noise floor."))
    cv = chain_view(d)
    if cv is not None:
        sec.add(Table("The effects named, in the order added (each after the first scored with those before it in the model, "
                      "added when its paired held-out test passed, and refit jointly with them and the whole calibration; "
                      "a swapped-out effect is gone, the one swapped in for it last)", cv))
    jv = joint_view(d)
    if jv is not None:
        links = d.chain.links if d.chain is not None else []
        assert d.effect is not None, "a joint refit is made for the named effect only (diagnose/core.py)"
        held = (f"`calibration_with_effect.json`, which `correct` applies, holds the chain's last joint refit: "
                f"{', '.join([d.effect] + [lk.name for lk in links])} fitted together with the calibration" if links else
                "`calibration_with_effect.json`, which `correct` applies")
        sec.add(Table(f"Joint refit: the whole calibration refit with {d.effect} (hanging, standing and walking swing "
                      f"together, cross-validated; {held})", jv))
        for line in d.joint.notes:
            sec.add(Text(line))
    sec.add(Table("Candidate effects, best first", ranking_view(d)))
    sec.add(Table("Residual by recording kind (held-out RMS / noise floor)", kinds_view(d)))
    if d.perleg is not None:
        rows = {f"{f.leg}: {'free linear map (standing)' if f.kind == 'linear_map' else 'swing refit (walking)'}":
                {"components": " ".join(f.components), "size": f"{f.size:.3g}", "z": f"{f.z:.1f}" if np.isfinite(f.z) else "n/a",
                 "on most legs": "yes" if f.shared else "no", "finding": f.statement} for f in d.perleg.findings}
        if rows:
            tab = pd.DataFrame(rows).T
            tab.index.name = "leg: check"
            sec.add(Table("Per-leg checks without the effect library (a free linear map of each leg's readings; each leg's "
                          "weight and moment refit on its own swing phases)", tab))
        else:
            sec.add(Text("Per-leg checks without the effect library (a free linear map of each leg's readings on the standing "
                         "poses; each leg's weight and moment refit on its own swing phases): no leg stands out."))
    return sec


def fig_shrinkage(d: "DiagnosisResult", path: Path) -> Path:
    """Held-out RMS per component before and after the named effect, beside the noise floor (log scale)."""
    sh = d.shrinkage
    before, after, floor = (np.asarray(sh[k], float) for k in ("heldout_rms_before", "heldout_rms_after", "noise_floor"))
    bars = [(before, "tab:blue", "held-out, calibrated model")]
    if d.effect:
        bars.append((after, "tab:orange", f"held-out, with {' + '.join(_named(d))}"))
    bars.append((floor, "0.6", "noise floor"))
    w = 0.8 / len(bars)
    fig, axes = plt.subplots(1, 2, figsize=(9.5, 3.8))
    for ax, sl, unit in ((axes[0], slice(0, 3), "N"), (axes[1], slice(3, 6), "N*m")):
        x = np.arange(3)
        for i, (vals, color, label) in enumerate(bars):
            ax.bar(x + (i - (len(bars) - 1) / 2) * w, vals[sl], w, color=color, label=label)
        ax.set_xticks(x, WRENCH_COMPONENTS[sl])
        ax.set_yscale("log")
        ax.set_ylabel(f"RMS [{unit}]")
        ax.grid(axis="y", which="both", alpha=0.3)
    h, l = axes[0].get_legend_handles_labels()
    fig.legend(h, l, loc="upper center", ncol=len(bars), fontsize=8, bbox_to_anchor=(0.5, 0.93), frameon=False)
    fig.suptitle(f"Gap in the {sh.get('kind', 'standing')} recordings: verdict {d.verdict}" + (f" ({d.effect})" if d.effect else ""),
                 fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.88))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def fig_dependence(d: "DiagnosisResult", path: Path) -> Path | None:
    """The residual component with the largest gap against the variable that explains it best."""
    loc = d.localisation.get(d.shrinkage.get("kind_key", d.shrinkage.get("kind", "standing")))
    if loc is None or not loc.plot or "x" not in loc.plot:
        return None
    p = loc.plot
    x, y = np.asarray(p["x"], float), np.asarray(p["y"], float)
    fig, ax = plt.subplots(figsize=(7, 3.8))
    fl = float(p.get("floor", np.nan))
    if np.isfinite(fl):
        ax.axhspan(-fl, fl, color="0.8", alpha=0.6, label=f"{PM} noise floor", zorder=0)
    _scatter_binned_median(ax, x, y, n_bins=15, min_count=3)
    comp = p.get("component", "")
    unit = _unit(comp) if comp else ""
    leg = f" (leg {p['leg']})" if "leg" in p else ""
    ax.set_xlabel(p.get("xlabel", ""))
    ax.set_ylabel(f"{loc.kind} residual {comp}{leg} [{unit}]")
    ax.set_title(f"Strongest dependence: {loc.top or 'none above the threshold'}", fontsize=10)
    return _finish(fig, ax, path)
