"""Figures of the diagnosis, drawn from a :class:`~.result.DiagnosisResult` only (no solving)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from ..data import WRENCH_COMPONENTS


def fig_shrinkage(res, path: Path) -> Path:
    """Held-out RMS per component before and after the named effect, beside the noise floor (log scale)."""
    sh = res.shrinkage
    before, after, floor = (np.asarray(sh[k], float) for k in ("heldout_rms_before", "heldout_rms_after", "noise_floor"))
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4))
    label_after = f"with {res.effect}" if res.effect else "after (no effect named)"
    for ax, sl, unit in ((axes[0], slice(0, 3), "N"), (axes[1], slice(3, 6), "N*m")):
        x = np.arange(3)
        ax.bar(x - 0.27, before[sl], 0.27, label="held-out, calibrated model")
        ax.bar(x, after[sl], 0.27, label=label_after)
        ax.bar(x + 0.27, floor[sl], 0.27, label="noise floor", color="0.6")
        ax.set_xticks(x, WRENCH_COMPONENTS[sl])
        ax.set_yscale("log")
        ax.set_ylabel(f"RMS [{unit}]")
    axes[0].legend(fontsize=7)
    fig.suptitle(f"Gap in the {sh.get('kind', 'standing')} recordings: verdict {res.verdict}" + (f" ({res.effect})" if res.effect else ""),
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def fig_dependence(res, path: Path) -> Path | None:
    """The residual component with the largest gap against the variable that explains it best."""
    loc = res.localisation.get(res.shrinkage.get("kind_key", res.shrinkage.get("kind", "standing")))
    if loc is None or not loc.plot or "x" not in loc.plot:
        return None
    p = loc.plot
    x, y = np.asarray(p["x"], float), np.asarray(p["y"], float)
    n = len(x)
    if n > 6000:  # a readable scatter of long recordings
        idx = np.random.default_rng(0).choice(n, 6000, replace=False)
        xs, ys = x[idx], y[idx]
    else:
        xs, ys = x, y
    fig, ax = plt.subplots(figsize=(6.5, 3.6))
    ax.plot(xs, ys, ".", ms=2.5, alpha=0.5, label="residual")
    if np.ptp(x) > 0 and n >= 20:
        edges = np.quantile(x, np.linspace(0, 1, 16))
        mid, med = [], []
        for a, b in zip(edges[:-1], edges[1:]):
            sel = (x >= a) & (x <= b)
            if sel.sum() >= 3:
                mid.append(0.5 * (a + b))
                med.append(np.median(y[sel]))
        ax.plot(mid, med, "-", color="C3", lw=2, label="binned median")
    fl = float(p.get("floor", np.nan))
    if np.isfinite(fl):
        ax.axhspan(-fl, fl, color="0.8", alpha=0.6, label="+- noise floor")
    comp = p.get("component", "")
    unit = "N" if comp.startswith("f") else "N*m"
    leg = f" (leg {p['leg']})" if "leg" in p else ""
    ax.set_xlabel(p.get("xlabel", ""))
    ax.set_ylabel(f"{loc.kind} residual {comp}{leg} [{unit}]")
    ax.set_title(f"Strongest dependence: {loc.top or 'none above the threshold'}", fontsize=10)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
