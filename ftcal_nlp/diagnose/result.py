"""The diagnosis as a result object: ``diagnosis.json`` (``OUTPUT_FORMAT.md``), a terminal
summary and labelled tables. Every number was computed by ``attribute`` and ``localise``;
the report's section and figures are drawn by ``ftcal_nlp.report.diagnosis``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from ..core.data import WRENCH_COMPONENTS

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
    effect_fit: Any = None  # the named effect's standing fit (results protocol: params, bse, cov_params, summary)
    perleg: Any = None      # the library-free per-leg checks (perleg.PerLegFindings) or None
    noise_model: dict | None = None  # the standing noise floor's parts (floor.py): readings, motion capture, fit
    joint: Any = None       # the joint refit with the named effect (joint.JointRefit) or None
    effects: list | None = None  # the chain of named effects (free loads, ``chain.py``); None: the single named effect
    free: dict | None = None     # free loads: transducer -> free.FreeLegDiagnosis
    chain: Any = None            # hexapods: the chain after the first effect, swaps included (hexchain.HexChain) or None
    thresholds: Any = None       # the chain's thresholds it ran with (settings.ChainThresholds: the report quotes them)

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
                 "status": r.get("status", "ok"), **({"note": r["note"]} if r.get("note") else {}),
                 **({"variant": r["variant"]} if r.get("variant") else {})}
                for r in self.ranking
            ],
            "statement": list(self.statement),
            "gaps": {k: float(v) for k, v in self.gaps.items()},
            "kinds": self.kinds,
            "model": self.model,
            "balance": self.balance,
        }
        out["effects"] = self.effects_list()
        if self.free is not None:
            out["free_loads"] = {k: d.to_json_dict() for k, d in self.free.items()}
        if self.design is not None:
            d = self.design
            out["design_check"] = {"common_tilt_deg": _lst(d["tilt_deg"]), "tilt_se_deg": float(d["tilt_se_deg"]),
                                   "delta_bic": float(d["delta_bic"]), "scatter_deg": float(d["scatter_deg"])}
        if self.effect_fit is not None:
            p, se = self.effect_fit.effect_params, self.effect_fit.effect_bse
            out["effect_parameters"] = {n: {"value": float(v), "se": float(e) if np.isfinite(e) else None} for n, v, e in zip(p.index, p, se)}
        if self.noise_model is not None:
            out["noise_floor_parts"] = self.noise_model
        if self.perleg is not None:
            out["per_leg_checks"] = [{"leg": f.leg, "check": f.kind, "components": list(f.components), "statement": f.statement,
                                      "size": float(f.size), "z": float(f.z) if np.isfinite(f.z) else None, "shared": bool(f.shared)}
                                     for f in self.perleg.findings]
        if self.joint is not None:
            out["joint_refit"] = self.joint.to_json_dict()
        if self.chain is not None:
            out["chain"] = self.chain.to_json_dict()
        if self.notes:
            out["notes"] = list(self.notes)
        return out

    def effects_list(self) -> list[dict]:
        """``effects`` of ``diagnosis.json``: the chain in the order the effects were added, each with its parameters
        (value, se) and the held-out RMS after it. Hexapod datasets: the first is the single-effect diagnosis' (the
        standing face's parameters, the held-out RMS after its joint refit on the shrinkage's kind); the links the
        chain added after it (``hexchain.py``) carry the joint refit of every effect named so far: the link's own
        parameters, the held-out RMS after it, the paired z and the share of the excess it removed. After a swap
        (``hexchain.try_swaps``) the swapped-out effect is gone and the swapped-in one is last; when it took the
        ranking's first out, the first is the next that stands (its attribution's parameters, its refit alone), and
        a link tested beside effects that are no longer before it says which (``tested_beside``)."""
        if self.effects is not None:
            return list(self.effects)
        if self.effect is None:
            return []
        pars = {}
        if self.effect_fit is not None:
            p, se = self.effect_fit.effect_params, self.effect_fit.effect_bse
            pars = {n: {"value": float(v), "se": float(e) if np.isfinite(e) else None} for n, v, e in zip(p.index, p, se)}
        links = self.chain.links if self.chain is not None else []
        first_after = self.shrinkage["heldout_rms_after"]
        if links and self.joint is not None and self.shrinkage.get("kind_key") in self.joint.kinds:
            first_after = self.joint.kinds[self.shrinkage["kind_key"]].rms_after   # the shrinkage is the chain's end
        out = [{"name": self.effect, "parameters": pars, "heldout_rms_after": _lst(first_after), "explains": self.where.get("explains")}]
        first = self.chain.first if self.chain is not None else None
        if first is not None:   # a swap took the ranking's first out: the first attribution's numbers for the new first
            out[0].update(_test_fields(first))
        for link in links:
            out.append({"name": link.name, "parameters": {n: {"value": float(v), "se": float(e) if np.isfinite(e) else None}
                                                          for n, (v, e) in link.parameters.items()},
                        "heldout_rms_after": _lst(link.rms_after), "explains": link.unit.explains, **_test_fields(link)})
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
        """Every candidate, best first (rows labelled by effect): delta BIC, the fraction of the gap it
        explains, its held-out RMS per component (N, N*m) and its status."""
        rows, names = [], []
        for r in self.ranking:
            row = {"delta BIC": r["delta_bic"] if r["delta_bic"] is not None else float("nan"), "explained": r.get("explained", 0.0)}
            for c, v in zip(WRENCH_COMPONENTS, np.asarray(r["heldout_rms_after"], float)):
                row[f"{c} after [{_unit(c)}]"] = v
            status, note = r.get("status", "ok"), r.get("note") or ""
            # notes often restate the status ("not applicable: ..."): say it once
            row["status"] = note if note.startswith(status) else (f"{status} ({note})" if note else status)
            rows.append(row)
            v = r.get("variant") or {}
            names.append(r["effect"] + (" (" + ", ".join(f"{k} {x}" for k, x in v.items()) + ")" if v else ""))
        return pd.DataFrame(rows, index=pd.Index(names, name="effect"))

    def kinds_table(self) -> pd.DataFrame:
        """Per recording kind (rows): gap yes/no, RMS and noise floor per component (N, N*m), the share of the
        residual that is constant and the measured variable it follows best."""
        rows, names = [], []
        for kind, loc in self.localisation.items():
            row: dict[str, str | float] = {"gap": "yes" if kind in self.gaps else "no"}
            for c, v, fl in zip(WRENCH_COMPONENTS, loc.rms, loc.floor):
                row[f"{c} RMS [{_unit(c)}]"] = float(v)
                row[f"{c} floor [{_unit(c)}]"] = float(fl)
            row["constant share"] = float(loc.constant_share)
            row["follows"] = loc.top or "-"
            rows.append(row)
            names.append(kind)
        return pd.DataFrame(rows, index=pd.Index(names, name="recordings"))


def _test_fields(link) -> dict:
    """An ``effects`` entry's fields from a chain link (``hexchain.Link``): its variant and the test that named it."""
    return {"variant": dict(link.unit.variant), "kind": link.kind or None,
            "paired_z": float(link.z) if np.isfinite(link.z) else None, "explained": float(link.explained),
            "found_by": link.via, **({"tested_beside": list(link.beside)} if link.beside else {})}


def _unit(component: str) -> str:
    return "N" if component.startswith("f") else "N*m"
