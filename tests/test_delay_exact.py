"""clock_offset's exact delay (issue 32, item 3) on the simulated 4R arm of ``test_arm.py`` (joints only, a payload),
with readings that lag the joints by 0.17-0.24 s applied by LINEAR interpolation (not the injector's spline): a
delay alone is named alone within 5 % and its se covers the truth; a creep alone is named alone; a delay beside a
slow creep both; clean data nothing; a step of the delay halfway is said, with its time within one block."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tomli_w
from test_arm import URDF, WRENCH, _arm_frame

from ftcal_nlp.core.data import read_dataset
from ftcal_nlp.core.kinematics import load_tree
from ftcal_nlp.diagnose.free import diagnose_free
from ftcal_nlp.effects.creep import creep_term
from ftcal_nlp.estimate.freeload import fit_free_loads


def _arm(folder: Path, seed: int, delay: float = 0.0, step: float | None = None, creep: float = 0.0):
    """The arm's readings (16 holds) lagging the joints by ``delay`` s (``step``: from halfway on), a creep of gain
    ``creep`` (tau 4 s) under it; diagnosed as a free load."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "arm4.urdf").write_text(URDF)
    fr = _arm_frame(load_tree(folder / "arm4.urdf"), seed, 16)
    t = fr["t"].to_numpy()
    cols = [f"wrist_{c}" for c in WRENCH]
    w = fr[cols].to_numpy()
    if creep:
        w = w + creep_term(t, w, creep, (4.0,))
    d = np.full(len(t), delay)
    if step is not None:
        d[t >= t[0] + 0.5 * np.ptp(t)] = step
    fr[cols] = np.stack([np.interp(t - d, t, w[:, i]) for i in range(6)], axis=1)
    fr.to_csv(folder / "wrist.csv", index=False, float_format="%.17g")
    (folder / "robot.toml").write_bytes(tomli_w.dumps({"name": "arm4", "g": 9.81, "legs": ["wrist"], "urdf": "arm4.urdf",
                                                       "transducers": {"wrist": {"link": "ft_sensor"}}}).encode())
    (folder / "dataset.toml").write_bytes(tomli_w.dumps({"robot": "robot.toml", "recording": [
        {"file": "wrist.csv", "kind": "hanging", "gravity_body": [0.0, 0.0, -1.0]}]}).encode())
    ds = read_dataset(folder / "dataset.toml")
    return diagnose_free(ds, fit_free_loads(ds)), np.ptp(t)


def _names(d) -> list[str]:
    return [e["name"] for e in d.effects]


@pytest.mark.parametrize("seed,true", [(1, 0.2), (2, 0.17), (3, 0.24)])
def test_a_delay_alone_is_named_alone_with_its_se(seed, true, tmp_path):
    d, _ = _arm(tmp_path, seed, true)
    assert _names(d) == ["clock_offset"], d.statement
    p = d.effects[0]["parameters"]["delay_s [s]"]
    assert abs(p["value"] - true) < 0.05 * true, p
    assert abs(p["value"] - true) < 3 * p["se"], p
    leg = next(iter(d.free.values()))
    assert np.all(leg.after / leg.floor < 1.1), leg.after / leg.floor      # the exact shift leaves the floor
    assert not leg.delay_blocks["changes"], leg.delay_blocks


def test_a_creep_alone_is_named_alone(tmp_path):
    d, _ = _arm(tmp_path, 3, creep=0.01)
    assert _names(d) == ["creep"], d.statement


def test_a_delay_beside_a_slow_creep_both(tmp_path):
    d, _ = _arm(tmp_path, 4, 0.2, creep=0.01)
    assert set(_names(d)) == {"clock_offset", "creep"}, d.statement
    p = d.effects[_names(d).index("clock_offset")]["parameters"]["delay_s [s]"]
    assert abs(p["value"] - 0.2) < 0.05 * 0.2, p


def test_clean_arm_names_nothing(tmp_path):
    d, _ = _arm(tmp_path, 5)
    assert d.verdict == "none" and d.effects == [], d.statement


def test_a_step_of_the_delay_is_said_with_its_time(tmp_path):
    d, span = _arm(tmp_path, 2, 0.17, step=0.24)
    assert _names(d)[0] == "clock_offset", d.statement
    blocks = next(iter(d.free.values())).delay_blocks
    assert blocks["changes"], blocks
    width = max(b["t_end"] - b["t_start"] for b in blocks["blocks"])
    assert abs(blocks["largest_jump"]["t_s"] - 0.5 * span) < width, blocks["largest_jump"]
    assert any("clock offset changes over the recording" in line for line in d.statement), d.statement
