"""``plan`` runs the run's checks (issue 30, second round): a pilot dataset is checked before and after its fit as
``run`` checks it (x, y, z, w quaternions, a left-handed force frame, forces in mN are refused), and planned joint
poses beyond the URDF's limits (degrees) are refused naming the hold and the joint; clean pilots and holds plan."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ftcal_nlp.core.data import read_dataset
from ftcal_nlp.core.errors import ConfigError, DataFormatError, ImplausibleLoadFit
from ftcal_nlp.plan.free_load import plan_from_dataset, plan_from_robot
from ftcal_nlp.sim.free import PayloadConfig, UrdfLegConfig, simulate_free, write_free_load


@pytest.fixture(scope="module")
def payload():
    return simulate_free(PayloadConfig(seed=8, n_orientations=6, hold_s=3.0, move_s=1.5))


def _pilot(res, folder: Path, frame: pd.DataFrame | None = None):
    return read_dataset(write_free_load(res if frame is None else replace(res, frame=frame), folder))


def test_a_clean_pilot_plans(payload, tmp_path) -> None:
    plan = plan_from_dataset(_pilot(payload, tmp_path / "ok"))
    assert np.isfinite(plan.loads["wrist"].groups()["load_mass"][0])


@pytest.mark.parametrize("how, error, pattern", [
    ("xyzw", DataFormatError, r"columns qw, qx, qy, qz: .*x, y, z, w order\?"),
    ("negate_fz", DataFormatError, r"form a left-handed frame.*wrist_fz negated\?"),
    ("mN", ImplausibleLoadFit, r"centre of mass .*forces wrist_fx\.\.wrist_fz in mN"),
])
def test_a_pilot_the_run_refuses_is_refused(payload, tmp_path, how, error, pattern) -> None:
    df = payload.frame.copy()
    if how == "xyzw":
        df[["qw", "qx", "qy", "qz"]] = df[["qx", "qy", "qz", "qw"]].to_numpy()
    elif how == "negate_fz":
        df["wrist_fz"] *= -1
    else:
        df[["wrist_fx", "wrist_fy", "wrist_fz"]] *= 1000.0
    with pytest.raises(error, match=pattern):
        plan_from_dataset(_pilot(payload, tmp_path / how, df))


def test_holds_beyond_the_joint_limits_are_refused(tmp_path) -> None:
    res = simulate_free(UrdfLegConfig(seed=5, n_orientations=2, poses_per_orientation=2, hold_s=2.0, move_s=1.0))
    robot = write_free_load(res, tmp_path / "u").parent / "robot.toml"
    joints = [c[2:] for c in res.frame.columns if c.startswith("q_")]
    ok = [{"q": {j: float(res.frame[f"q_{j}"].iloc[i]) for j in joints}} for i in (0, len(res.frame) - 1)]
    table = {"gravity_body": [0, 0, -1], "hold_s": 2.0, "holds": ok}
    plan_from_robot(table, tmp_path / "holds.toml", robot)        # within the limits: plans
    deg = [{"q": {j: float(np.degrees(v)) for j, v in h["q"].items()}} for h in ok]
    j = next(j for j in joints if any(abs(np.degrees(h["q"][j])) > 3.0 for h in ok))
    with pytest.raises(ConfigError, match=r"holds\[\d\]\.q\.\w+ = -?\d+(\.\d+)?.*beyond the URDF's limits of joint '\w+' "
                                          r"\[.*\] rad; expected radians"):
        plan_from_robot({**table, "holds": deg}, tmp_path / "holds.toml", robot)
    far = [{"q": {**ok[0]["q"], j: 10.0}}]
    with pytest.raises(ConfigError, match=rf"holds\[0\]\.q\.{j} = 10: beyond the URDF's limits"):
        plan_from_robot({**table, "holds": far}, tmp_path / "holds.toml", robot)
