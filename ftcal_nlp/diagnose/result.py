"""The diagnosis as a result object: ``diagnosis.json`` (``OUTPUT_FORMAT.md``), a terminal
summary and a report section. Renders only; every number was computed by ``attribute``
and ``localise``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from ..data import WRENCH_COMPONENTS

VERDICTS = ("none", "effect", "unexplained")


def _lst(a) -> list:
    return [float(v) for v in np.asarray(a, float).ravel()]


@dataclass(frozen=True)
class DiagnosisResult:
    """Verdict, where the gap lies, how far the named effect shrinks it, and every candidate.

    ``where``: recordings (kinds with a gap, largest first), legs (empty: common
    to all or not separable), components, explains (a family of ``localise.py`` or
    None). ``shrinkage``: held-out RMS per component (6,) before / after the
    named effect and the noise floor, on the recording kind ``kind``.
    ``ranking``: dicts ``effect``, ``delta_bic``, ``heldout_rms_after``, best first
    (plus ``explained``, ``status``, ``note``). ``localisation``: kind ->
    :class:`~.localise.KindLocal`. ``statement``: plain-language lines.
    """

    verdict: str
    effect: str | None
    where: dict
    shrinkage: dict
    ranking: list
    localisation: dict = field(default_factory=dict)
    statement: tuple = ()
    design: dict | None = None
    gaps: dict = field(default_factory=dict)
    kinds: dict = field(default_factory=dict)
    model: str = ""
    balance: str = "exact"
    time_s: float = float("nan")
    notes: tuple = ()

    def __post_init__(self):
        if self.verdict not in VERDICTS:
            raise ValueError(f"verdict must be one of {VERDICTS}, got {self.verdict!r}")
        if (self.verdict == "effect") != (self.effect is not None):
            raise ValueError("an effect is named exactly when the verdict is 'effect'")

    # ------------------------------------------------------------------ outputs
    def to_json_dict(self) -> dict:
        """``diagnosis.json`` in the layout of ``OUTPUT_FORMAT.md`` (extra keys after the contract's)."""
        sh = self.shrinkage
        out = {
            "verdict": self.verdict,
            "effect": self.effect,
            "where": {
                "recordings": list(self.where.get("recordings", [])),
                "legs": list(self.where.get("legs", [])),
                "components": list(self.where.get("components", [])),
                "explains": self.where.get("explains"),
            },
            "shrinkage": {
                "heldout_rms_before": _lst(sh["heldout_rms_before"]),
                "heldout_rms_after": _lst(sh["heldout_rms_after"]),
                "noise_floor": _lst(sh["noise_floor"]),
                "kind": sh.get("kind"),
                "kind_detail": sh.get("kind_key"),
            },
            "ranking": [
                {"effect": r["effect"], "delta_bic": None if not np.isfinite(r["delta_bic"]) else float(r["delta_bic"]),
                 "heldout_rms_after": _lst(r["heldout_rms_after"]), "explained": float(r.get("explained", 0.0)),
                 "status": r.get("status", "ok"), **({"note": r["note"]} if r.get("note") else {})}
                for r in self.ranking
            ],
            "statement": list(self.statement),
            "gaps": {k: float(v) for k, v in self.gaps.items()},
            "kinds": self.kinds,
            "model": self.model,
            "balance": self.balance,
        }
        if self.design is not None:
            d = self.design
            out["design_check"] = {"common_tilt_deg": _lst(d["tilt_deg"]), "tilt_se_deg": float(d["tilt_se_deg"]),
                                   "delta_bic": float(d["delta_bic"]), "scatter_deg": float(d["scatter_deg"])}
        if self.notes:
            out["notes"] = list(self.notes)
        return out

    def summary(self) -> str:
        """A short terminal summary."""
        sh = self.shrinkage
        lines = [f"sim-to-real gap: {self.verdict}" + (f" -> {self.effect}" if self.effect else "")]
        if self.where.get("recordings"):
            w = self.where
            lines.append(f"  where: {', '.join(w['recordings'])}; legs {', '.join(w['legs']) or 'all'}; "
                         f"components {', '.join(w['components']) or '-'}; follows {w.get('explains') or 'nothing measured'}")
        b, a, f = (np.asarray(sh[k], float) for k in ("heldout_rms_before", "heldout_rms_after", "noise_floor"))
        lines.append(f"  held-out RMS on {sh.get('kind')} (fx fy fz [N] tx ty tz [N*m]):")
        lines.append("    before " + " ".join(f"{v:.3g}" for v in b))
        lines.append("    after  " + " ".join(f"{v:.3g}" for v in a))
        lines.append("    floor  " + " ".join(f"{v:.3g}" for v in f))
        top = [r for r in self.ranking if r.get("status", "ok") == "ok" and r["delta_bic"] is not None and np.isfinite(r["delta_bic"])][:3]
        if top:
            lines.append("  best candidates: " + ", ".join(f"{r['effect']} (dBIC {r['delta_bic']:.0f})" for r in top))
        return "\n".join(lines)

    def ranking_table(self) -> pd.DataFrame:
        rows = []
        for r in self.ranking:
            row = {"effect": r["effect"], "delta BIC": r["delta_bic"], "explained": r.get("explained", 0.0)}
            for c, v in zip(WRENCH_COMPONENTS, np.asarray(r["heldout_rms_after"], float)):
                row[f"{c} after"] = v
            row["status"] = r.get("status", "ok") + (f" ({r['note']})" if r.get("note") else "")
            rows.append(row)
        return pd.DataFrame(rows)

    def kinds_table(self) -> pd.DataFrame:
        rows = []
        for kind, loc in self.localisation.items():
            row = {"recordings": kind, "gap": "yes" if kind in self.gaps else "no"}
            for c, v, fl in zip(WRENCH_COMPONENTS, loc.rms, loc.floor):
                row[f"{c} RMS / floor"] = f"{v:.3g} / {fl:.2g}"
            row["constant share"] = round(loc.constant_share, 2)
            row["follows"] = loc.top or "-"
            rows.append(row)
        return pd.DataFrame(rows)

    def report_section(self, folder: str | Path):
        """A :class:`ftcal_nlp.report.Section`; draws its figures into ``folder``."""
        from ..report import Section
        from .figures import fig_dependence, fig_shrinkage

        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        text = list(self.statement)
        text.append("Candidates are ranked by the change of BIC on the recordings where the gap lies; every held-out "
                    "number comes from cross-validation folds (standing) or contiguous time blocks (hanging, walking) "
                    "that the candidate was not fitted to. Noise floors come from the data: within-pose scatter, "
                    "high-frequency scatter and the part of the residual no measured variable predicts.")
        sec = Section("Sim-to-real gap diagnosis", text, [("candidate effects", self.ranking_table()),
                                                          ("residual by recording kind", self.kinds_table())])
        sec.figures.append(("diagnosis_shrinkage.png", fig_shrinkage(self, folder / "diagnosis_shrinkage.png")))
        dep = fig_dependence(self, folder / "diagnosis_dependence.png")
        if dep is not None:
            sec.figures.append(("diagnosis_dependence.png", dep))
        return sec
