#!/usr/bin/env python3
"""The tool on the converted iCub leg recording (``convert_icub_insitu.py``): calibration, diagnosis, Table III.

Usage (the data are not redistributable: keep the converted folders outside the repository)::

    python data/external/icub_insitu_tables.py FULL A B [--json OUT.json] [--no-diagnosis]

``FULL``, ``A``, ``B``: converted dataset folders of one sensor (``--window`` of the converter: the whole swing, its
first part, its second part). Prints, with the package's defaults (nothing tuned to these data):

1. the free-load fit of FULL with ``sensor_matrix`` none / force / full (``fit_free_loads``; the API, because
   ``python -m ftcal_nlp run`` stops at the fit's plausibility check on these data: see REAL_DATA.md): offsets,
   load mass, mounting rotation, each with se, residual RMS, the matrix's ridge choice and determined parts;
2. the diagnosis (``diagnose_free``) of the ``"none"`` fit: verdict, the chain's effects with their parameters,
   held-out RMS before / after against the noise floor;
3. their Table III (Andrade Chavez et al. 2016) both ways: calibrated on A, per-axis RMS error on B's quasi-static
   samples (``sensor_matrix.validate_across_sessions``: B's own offset, A's load, tilt and mount), the matrix's in %
   of the factory matrix's (factory = 100 %);
4. with ``--write-calibration DIR``: A's and B's ``"none"`` fits as ``DIR/{A,B}/calibration.json`` (+ covariance), as
   ``run`` would write them, so that the tool's own command for a later session runs on them:
   ``python -m ftcal_nlp holdout DIR/A/calibration.json B/<leg>.csv -o OUT``.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from ftcal_nlp.core.data import read_dataset
from ftcal_nlp.core.settings import DiagnoseSettings, FreeLoadSettings
from ftcal_nlp.estimate.freeload import fit_free_loads
from ftcal_nlp.estimate.freeload.sensor_matrix import WRENCH, validate_across_sessions

MODES = ("none", "force", "full")


def fmt(v, d=3) -> str:
    return " ".join(f"{x:.{d}g}" if np.isfinite(x) else "inf" for x in np.asarray(v, float))


def describe(mode: str, res) -> dict:
    r = res.legs[next(iter(res.legs))]
    rep = r.load_report()
    se_o, se_m = r.se[:6], np.rad2deg(r.se[-3:])
    ang = float(np.rad2deg(np.linalg.norm(r.mount_rotvec)))
    urdf_mass = sum(r.load.tree.bodies[lk].mass_kg for lk in r.load.tree.below(r.load.ft_link) if lk in r.load.tree.bodies) \
        if hasattr(r.load, "tree") else float("nan")
    mass_combo = [c for c in r.determined if all(f".{g}.mass_kg" in c["combination"] for g in ("fixed",))
                  and c["combination"].count("mass_kg") > 1]
    out = {"mode": mode, "samples": int(r.n_used), "offset": r.offset.tolist(), "offset_se": se_o.tolist(),
           "load_mass_kg": rep.get("load_mass_kg"), "load_mass_se_kg": rep.get("load_mass_se_kg"), "urdf_mass_kg": urdf_mass,
           "mount_rotvec_deg": np.rad2deg(r.mount_rotvec).tolist(), "mount_angle_deg": ang, "mount_rotvec_se_deg": se_m.tolist(),
           "residual_rms": r.rms.tolist(), "noise_sd": r.sigma.tolist(),
           "mass_combination": [{k: c[k] for k in ("combination", "value", "se")} for c in mass_combo]}
    print(f"\n### sensor_matrix = \"{mode}\": {r.n_used} quasi-static samples")
    print(f"- offsets fx..tz: {fmt(r.offset, 5)} (se {fmt(se_o, 2)})")
    print(f"- load mass {rep.get('load_mass_kg'):.4f} kg (se {rep.get('load_mass_se_kg'):.3g}; inf = not determined); URDF {urdf_mass:.4f} kg")
    for c in mass_combo:
        print(f"  determined: {c['combination']} = {c['value']:.4f} +- {c['se']:.4f}")
    print(f"- mount rotation vector {fmt(np.rad2deg(r.mount_rotvec))} deg ({ang:.2f} deg; se {fmt(se_m, 2)} deg)")
    if r.tilt is not None:
        print(f"- world tilt {fmt(np.rad2deg(r.tilt))} deg")
    print(f"- residual RMS fx..tz {fmt(r.rms)}")
    sm = r.sensor_matrix
    if sm is not None:
        h = sm.ridge
        print(f"- ridge kept {h.chosen:g}; held-out score per weight: " +
              ", ".join(f"{g:g}: {s:.3g}" for g, s in zip(h.grid, h.score)))
        det = [c for c in sm.combinations if c["determined"] and c["se"] > 0]
        print("- determined parts: " + ("; ".join(f"{c['combination'].split('.C.')[-1]} {c['value']:+.4f} +- {c['se']:.4f}"
                                                  for c in det) or "none"))
        und = [c["combination"].split(".C.")[-1] for c in sm.combinations if not c["determined"]]
        print(f"- undetermined: {len(und)} parts" + (f" ({', '.join(und[:9])}{', ...' if len(und) > 9 else ''})" if und else ""))
        print(f"- C diagonal {fmt(np.diag(sm.C), 4)}; residual RMS with the factory matrix {fmt(sm.rms_factory)}")
        out.update(ridge=float(h.chosen), C=sm.C.tolist(), rms_factory=sm.rms_factory.tolist(),
                   determined=[{k: c[k] for k in ("combination", "value", "se")} for c in det])
    return out


def diagnosis(ds, res) -> dict:
    from ftcal_nlp.diagnose.free import diagnose_free

    t = time.perf_counter()
    d = diagnose_free(ds, res, DiagnoseSettings())
    out = {"verdict": d.verdict, "seconds": time.perf_counter() - t, "legs": {}}
    for leg, fd in d.free.items():
        j = fd.to_json_dict()
        eff = fd.effects_json()
        print(f"\n## Diagnosis of {leg}: verdict {fd.verdict} ({out['seconds']:.0f} s; {fd.n_still} quasi-static of {fd.n}, "
              f"{fd.blocks} cv blocks)")
        print(f"- noise floor fx..tz {fmt(fd.floor)} ({j['noise_floor_source']}, {fd.floor_samples} samples)")
        print(f"- held-out RMS before {fmt(fd.before)}  ({fmt(fd.before / fd.floor, 3)} x floor)")
        print(f"- held-out RMS after  {fmt(fd.after)}  ({fmt(fd.after / fd.floor, 3)} x floor)")
        for e in eff:
            pars = "; ".join(f"{k} {v['value']:.4g} +- {v['se']:.2g}" if v["se"] is not None else f"{k} {v['value']:.4g}"
                             for k, v in list(e["parameters"].items())[:12])
            print(f"- effect {e['name']} shape {e['shape']}: paired z {e['paired_z']:.3g}, explained {e['explained']:.2f}, "
                  f"held-out after {fmt(e['heldout_rms_after'])}; {pars}")
        for rd_i, rd in enumerate(j["chain"]):
            print(f"  round {rd_i + 1}: " + ", ".join(
                f"{c['effect']} ({c['status']}, z {c['paired_z']:.2g})" if c["paired_z"] is not None else f"{c['effect']} ({c['status']})"
                for c in rd["candidates"]))
        print(f"- stop: {j['stop']}")
        for n in fd.notes[:8]:
            print(f"  note: {n[:300]}")
        out["legs"][leg] = {"json": j, "effects": eff}
    return out


def write_calibration(ds, res, out: Path) -> None:
    """``calibration.json`` and its covariance file of a free-load fit, as ``python -m ftcal_nlp run`` writes them (the
    run itself stops at its plausibility check on these data)."""
    import dataclasses

    from ftcal_nlp.estimate.freeload import free_load_calibration
    from ftcal_nlp.run import COVARIANCE_FILE, free_load_covariance

    out.mkdir(parents=True, exist_ok=True)
    cal = free_load_calibration(res, ds.robot, ds.hanging)
    cov = free_load_covariance(res)
    meta = {**cal.meta, "config": "data/external/icub_insitu_tables.py (API; run stops at the plausibility check)"}
    if cov is not None:
        meta["covariance_file"] = COVARIANCE_FILE
        cov.save(out / COVARIANCE_FILE)
    dataclasses.replace(cal, meta=meta).save(out / "calibration.json")
    print(f"wrote {out / 'calibration.json'}")


def table3(fa: dict, dsB, s, label: str) -> dict:
    out = {}
    print(f"\n## Table III, {label} (per-axis RMS on the other part's quasi-static samples; factory = 100 %)\n")
    print("| mode | " + " | ".join(f"{a} %" for a in WRENCH) + " | factory RMS fx..tz (N, N*m) | mode RMS fx..tz |")
    print("|---" * 9 + "|")
    base = fa["none"].legs[next(iter(fa["none"].legs))]
    for m in MODES[1:]:
        r = fa[m].legs[next(iter(fa[m].legs))]
        df = validate_across_sessions(base, r, dsB, s)
        pct = df.iloc[:, 2].to_numpy()
        print(f"| {m} | " + " | ".join(f"{v:.0f}" for v in pct) + f" | {fmt(df['factory_rms'])} | {fmt(df.iloc[:, 1])} |")
        out[m] = {"percent": pct.tolist(), "factory_rms": df["factory_rms"].tolist(), "rms": df.iloc[:, 1].tolist()}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("full", type=Path)
    ap.add_argument("A", type=Path)
    ap.add_argument("B", type=Path)
    ap.add_argument("--json", type=Path)
    ap.add_argument("--no-diagnosis", action="store_true")
    ap.add_argument("--write-calibration", type=Path, help="write A's and B's calibration.json here (for holdout)")
    a = ap.parse_args(argv)
    ds = {k: read_dataset(p / "dataset.toml") for k, p in (("full", a.full), ("A", a.A), ("B", a.B))}
    out: dict = {}
    print("# 1. Fits of the whole swing")
    fits = {m: fit_free_loads(ds["full"], FreeLoadSettings(sensor_matrix=m)) for m in MODES}
    out["fits"] = {m: describe(m, fits[m]) for m in MODES}
    if not a.no_diagnosis:
        out["diagnosis"] = diagnosis(ds["full"], fits["none"])
    s = FreeLoadSettings()
    fa = {m: fit_free_loads(ds["A"], FreeLoadSettings(sensor_matrix=m)) for m in MODES}
    fb = {m: fit_free_loads(ds["B"], FreeLoadSettings(sensor_matrix=m)) for m in MODES}
    print("\n# 2. Fits of the parts")
    out["fits_A"] = {m: describe(m, fa[m]) for m in MODES}
    out["fits_B"] = {m: describe(m, fb[m]) for m in MODES}
    out["table3_A_to_B"] = table3(fa, ds["B"], s, "calibrated on A, evaluated on B")
    out["table3_B_to_A"] = table3(fb, ds["A"], s, "calibrated on B, evaluated on A")
    if a.write_calibration:
        write_calibration(ds["A"], fa["none"], a.write_calibration / "A")
        write_calibration(ds["B"], fb["none"], a.write_calibration / "B")
    if a.json:
        a.json.write_text(json.dumps(out, indent=1, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
