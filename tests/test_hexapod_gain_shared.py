"""Issue 33 (the hexapod) on someone else's simulator: the shared hexapod sample with each leg's force readings mapped
by its own matrix ``(I + E_k)`` about its true offsets (E_k entries N(0, 2 %)), calibrated with the diagnosis.

Before (session 12) the joint refit left the swing legs' torques 1.4-2.1x their floor on the draw of seed 0: the
standing fit's offset shift (a constant force in B) turned with a rotation common to every transducer, so the joint
rotations were 0.15-0.5 deg off together; and the draw of seed 1 was not named (the attribution's diagonal gains
explained 35 % of the gap). Held now: named, and every kind within the issue's 1.5x of its floor (measured 0.98-1.15x
on seeds 0-3)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ftcal_nlp import CalibrationSettings, HangingSettings, StandingSettings, calibrate
from ftcal_nlp.core.data import read_dataset

from conftest import SAMPLE, requires_sample

SHRINK_MAX = 1.5     # the criterion: the joint refit's held-out RMS within 1.5x the floor on every kind
SIZE = 0.02          # rms of the matrices' entries (the issue's "E of 1.5-2 %")


def _mapped_sample(seed: int, out: Path) -> tuple[Path, np.ndarray]:
    """The shared sample copied to ``out`` with leg k's forces read as ``o_k + (I + E_k) (f - o_k)`` (true offsets)."""
    truth = json.loads((SAMPLE / "truth.json").read_text())
    legs = list(truth["legs"])
    E = np.random.default_rng(seed).normal(0.0, SIZE, (len(legs), 3, 3))
    for f in SAMPLE.iterdir():
        if f.is_file():
            shutil.copy(f, out / f.name)
        if f.suffix not in (".csv", ".parquet") or f.name == "walk_truth.csv":
            continue
        fr = pd.read_csv(f) if f.suffix == ".csv" else pd.read_parquet(f)
        for k, leg in enumerate(legs):
            cols = [f"{leg}_{c}" for c in ("fx", "fy", "fz")]
            if cols[0] in fr:
                o = np.asarray(truth["legs"][leg]["offset"][:3], float)
                fr[cols] = o + (fr[cols].to_numpy() - o) @ (np.eye(3) + E[k]).T
        if f.suffix == ".csv":
            fr.to_csv(out / f.name, index=False, float_format="%.17g")
        else:
            fr.to_parquet(out / f.name)
    return out / "dataset.toml", E


@requires_sample
@pytest.mark.parametrize("seed", [0, 1])
def test_a_gain_matrix_on_the_shared_sample_is_named_and_closed_on_every_kind(seed, tmp_path):
    path, _ = _mapped_sample(seed, tmp_path)
    settings = CalibrationSettings(hanging=HangingSettings(compare_baseline=False),
                                   standing=StandingSettings(model="full", compare_baseline=False))
    d = calibrate(read_dataset(path), settings).diagnosis
    assert d.effect == "gain_crosstalk", (d.verdict, d.ranking[:2])
    kinds = d.joint.kinds
    assert set(kinds) == {"hanging", "standing", "walking swing"}
    for kind, k in kinds.items():
        assert np.all(k.rms_after <= SHRINK_MAX * k.floor), (kind, k.rms_after / k.floor)
    # a gap first on the kinds that carry the matrix's load (standing ~25-80x, swing torques 2.8-6.6x)
    assert np.max(kinds["standing"].rms_before / kinds["standing"].floor) > 10.0
    assert np.max(kinds["walking swing"].rms_before / kinds["walking swing"].floor) > 2.0
