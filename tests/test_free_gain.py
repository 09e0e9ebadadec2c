"""The sensor matrix as an effect of free loads (issue 33, item 3; ``effects/gain_crosstalk.py``'s free face): readings
``o + (I + E) w`` named ``gain_crosstalk``, the gap closed to the floor, the matrix's parts recovered within 3 se of
the truth (what the data determine of it: with a rigid payload the force block's scale is the load's mass, so the
other parts are relative to it); a force block named as such (the full matrix only when the torques need it). Our
simulator's injector, and an independent generator: the shared samples (someone else's simulator) with their
readings mapped by a 6x6 matrix about their true offsets, of the force block or all of it."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ftcal_nlp.core.data import read_dataset
from ftcal_nlp.diagnose.chain import GAP_REL
from ftcal_nlp.diagnose.free import diagnose_free
from ftcal_nlp.effects.gain_crosstalk import GainCrosstalkInjector, matrix_parts
from ftcal_nlp.estimate.freeload import fit_free_loads
from ftcal_nlp.estimate.freeload.sensor_matrix import block_values
from ftcal_nlp.sim.free import PayloadConfig, UrdfLegConfig, simulate_payload, simulate_urdf_leg, write_free_load

SHARED = Path(__file__).resolve().parents[2] / "shared"
WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")


def _diagnose(manifest: Path):
    ds = read_dataset(manifest)
    d = diagnose_free(ds, fit_free_loads(ds))
    return d, next(iter(d.free.values()))


def _truth(E6: np.ndarray, block: str, scale_determined: bool) -> dict[str, float]:
    """The face's parameters (%) of the reading matrix ``I + E6``: its own parts when the data determine the scale,
    else the parts of ``(I + E6) / s`` (``block_values``: the force rows over their scale, which the load's mass
    takes)."""
    names, M = matrix_parts(block)
    if scale_determined:
        v = 100 * np.linalg.lstsq(M.reshape(len(names), -1).T, E6.ravel(), rcond=None)[0]
        return dict(zip(names, v))
    bv = block_values(np.eye(6) + E6, block)
    return {n: 100 * bv[n.split(" ")[0][2:]] for n in names if n.split(" ")[0][2:] in bv}


def _check_parts(effect: dict, E6: np.ndarray, k: float = 3.0) -> int:
    """Every determined part within ``k`` se of the truth; returns how many were determined."""
    pars = effect["parameters"]
    block = effect["shape"]["block"]
    scale = pars["E.force.scale [%]"]
    truth = _truth(E6, block, scale["se"] is not None)
    n = 0
    for name, t in truth.items():
        p = pars[name]
        if p["se"] is None:
            continue
        n += 1
        assert abs(p["value"] - t) <= k * p["se"], (name, p, t)
    return n


@pytest.mark.parametrize("kind,seed", [("payload", 3), ("urdf", 3)])
def test_a_gain_matrix_is_named_closed_and_recovered(kind, seed, tmp_path):
    eff = ({"name": "gain_crosstalk", "scale": 0.02},)
    if kind == "payload":
        res = simulate_payload(PayloadConfig(seed=seed, n_orientations=12, hold_s=6.0, move_s=3.0, effects=eff))
    else:
        res = simulate_urdf_leg(UrdfLegConfig(seed=seed, n_orientations=6, poses_per_orientation=3, hold_s=4.0, move_s=2.0,
                                              effects=eff))
    d, leg = _diagnose(write_free_load(res, tmp_path / "d"))
    assert [e["name"] for e in d.effects] == ["gain_crosstalk"], d.effects
    (e,) = d.effects
    assert e["shape"] == {"block": "force"}            # the torques read true: the force block, not all 36
    assert np.max(leg.before / leg.floor) > 3.0         # a gap, and the named matrix closes it to the floor
    assert np.all(leg.after / leg.floor < 1.0 + GAP_REL), leg.after / leg.floor
    E6 = np.zeros((6, 6))
    E6[:3, :3] = GainCrosstalkInjector(0.02, 0).matrices(1)[0]
    n = _check_parts(e, E6)
    # a rigid payload: the force block's scale is the load's mass (no se: undetermined); the URDF leg's links fix it
    assert (e["parameters"]["E.force.scale [%]"]["se"] is None) == (kind == "payload")
    assert n == (8 if kind == "payload" else 9)


# --------------------------------------------------------------------------- an independent generator


def _shared_with_matrix(sample: str, csv: str, E6: np.ndarray, tmp: Path) -> Path:
    """The shared sample ``sample`` copied with its readings mapped by ``I + E6`` about its true offsets."""
    src = SHARED / sample
    for f in src.iterdir():
        shutil.copy(f, tmp / f.name)
    fr = pd.read_csv(src / csv)
    leg = next(c[:-3] for c in fr.columns if c.endswith("_fx"))
    cols = [f"{leg}_{c}" for c in WRENCH]
    o = np.asarray(json.loads((src / "truth.json").read_text())["offset"], float)
    fr[cols] = o + (fr[cols].to_numpy() - o) @ (np.eye(6) + E6).T
    fr.to_csv(tmp / csv, index=False, float_format="%.17g")
    return tmp / "dataset.toml"


def _matrix(block: str, seed: int, size: float = 0.02) -> np.ndarray:
    """A reading matrix error unlike the injector's draw: the force block, and for "full" the torques reading
    themselves (2 %), the forces (~2 mm of lever) and the forces reading the torques (4 % per metre)."""
    rng = np.random.default_rng(seed)
    E = np.zeros((6, 6))
    E[:3, :3] = rng.normal(0, size, (3, 3))
    if block == "full":
        E[3:, 3:] = rng.normal(0, size, (3, 3))
        E[3:, :3] = rng.normal(0, 0.1 * size, (3, 3))
        E[:3, 3:] = rng.normal(0, 2.0 * size, (3, 3))
    return E


@pytest.mark.parametrize("sample,csv,block,seed", [
    ("sample_payload", "wrist.csv", "force", 0),
    ("sample_payload", "wrist.csv", "full", 1),
    ("sample_urdf", "leg.csv", "force", 2),
    ("sample_urdf", "leg.csv", "full", 3),
])
def test_shared_samples_with_a_matrix(sample, csv, block, seed, tmp_path):
    E6 = _matrix(block, seed)
    d, leg = _diagnose(_shared_with_matrix(sample, csv, E6, tmp_path))
    assert [e["name"] for e in d.effects] == ["gain_crosstalk"], d.effects
    (e,) = d.effects
    assert e["shape"] == {"block": block}
    assert np.max(leg.before / leg.floor) > 3.0
    # closed to the floor within the chain's own gap (the URDF leg's full matrix: up to 1.25x on tx, ty after it, its
    # 36 parts linearised about a fit that took part of them; measured 1.14-1.21 on seed 0 of the scratch run)
    tol = 1.0 + GAP_REL if block == "force" else 1.3
    assert np.all(leg.after / leg.floor < tol), leg.after / leg.floor
    if block == "force" and sample == "sample_payload":
        assert _check_parts(e, E6) == 8
    # the shared URDF leg leaves its force scale undetermined beside four combinations of its links' masses and first
    # moments: the other parts are then relative to where the refit put the load along those directions (found 0.5-1 %
    # off the payload's normalisation, up to 8 se): their values are not checked there, only that the gap closes


@pytest.mark.parametrize("sample,csv", [("sample_payload", "wrist.csv"), ("sample_urdf", "leg.csv")])
def test_shared_samples_clean_name_no_matrix(sample, csv, tmp_path):
    d, _ = _diagnose(_shared_with_matrix(sample, csv, np.zeros((6, 6)), tmp_path))
    assert d.verdict == "none" and d.effects == []
