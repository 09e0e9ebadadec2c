"""Bad input of section 5 through the command line (issue 22 item 8): ``python -m ftcal_nlp run`` on a simulated
leg4 dataset with a URDF that does not parse, a sensor link or a joint column not in it, joint angles in degrees:
one ``error:`` line naming the file and key or column, exit status 2, nothing written; a payload hung only in
orientations about the vertical: the run finishes and says what the orientations leave undetermined (se null in
``calibration.json``, the directions named in the log and in the calibration), never a silent number."""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ftcal_nlp.run import main as run_main
from ftcal_nlp.sim.free import PayloadConfig, UrdfLegConfig, simulate_payload, simulate_urdf_leg, write_free_load


def _one_error(rc: int, err: str) -> str:
    lines = [line for line in err.splitlines() if line.startswith("error: ")]
    assert rc == 2 and len(lines) == 1 and "Traceback" not in err, (rc, err[-2000:])
    return lines[0]


def _config(folder: Path) -> Path:
    cfg = folder / "run.toml"
    cfg.write_text('[data]\nmanifest = "data/dataset.toml"\n[output]\ndir = "out"\n[diagnose]\nenabled = false\n')
    return cfg


CASES = {
    "urdf_broken": r"robot\.toml key 'urdf': .*robot\.urdf cannot be parsed as a URDF \(malformed XML",
    "link_missing": r"robot\.toml \[transducers\.r_leg\]: key 'link' = 'r_leg_sensor' is not a link of the URDF 'leg4'",
    "joint_unknown": r"leg\.csv: column 'q_r_kne': the URDF .*robot\.urdf has no joint 'r_kne'",
    "degrees": r"leg\.csv: column 'q_r_knee' reaches .* beyond the URDF limits .* rad by .*; expected radians \(degrees\?\)",
}


@pytest.fixture(scope="module")
def leg4():
    return simulate_urdf_leg(UrdfLegConfig(seed=5, n_orientations=5, poses_per_orientation=2, hold_s=3.0, move_s=2.0))


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_urdf_input_gets_one_clear_error_and_writes_nothing(case, leg4, tmp_path, capsys) -> None:
    d = tmp_path / "data"
    write_free_load(leg4, d)
    if case == "urdf_broken":
        text = (d / "robot.urdf").read_text()
        (d / "robot.urdf").write_text(text[: len(text) // 2])
    elif case == "link_missing":
        (d / "robot.toml").write_text((d / "robot.toml").read_text().replace('link = "r_leg_ft"', 'link = "r_leg_sensor"'))
    else:
        df = pd.read_csv(d / "leg.csv")
        if case == "joint_unknown":
            df = df.rename(columns={"q_r_knee": "q_r_kne"})
        else:
            df["q_r_knee"] = np.degrees(df["q_r_knee"])
        df.to_csv(d / "leg.csv", index=False)
    line = _one_error(run_main([str(_config(tmp_path))]), capsys.readouterr().err)
    assert re.search(CASES[case], line), line
    assert not (tmp_path / "out").exists()


def _readings_for_orientations(res, df: pd.DataFrame) -> pd.DataFrame:
    """``df`` with the simulated payload's readings recomputed for its columns qw..qz (its truth, the same noise)."""
    from ftcal_nlp.core.geometry import quat_to_rotation
    from ftcal_nlp.sim.free.physics import gravity_in_ft, payload_readings, true_rotation
    from ftcal_nlp.sim.free.simulate import rpy_to_rotation

    cfg = res.config
    R_ft = true_rotation(rpy_to_rotation(cfg.rotation_rpy), np.asarray(res.truth["mount_rotvec"], float))
    cols = [f"{cfg.transducer}_{c}" for c in ("fx", "fy", "fz", "tx", "ty", "tz")]

    def clean(frame: pd.DataFrame) -> np.ndarray:
        g_ft = gravity_in_ft(quat_to_rotation(frame[["qw", "qx", "qy", "qz"]].to_numpy()), R_ft, cfg.g)
        return payload_readings(g_ft, cfg.mass_kg, np.asarray(cfg.com_m), np.asarray(res.truth["offset"]))

    out = df.copy()
    out[cols] = clean(df) + (res.frame[cols].to_numpy() - clean(res.frame))     # the simulated noise kept
    return out


@pytest.mark.parametrize("axis", ["vertical", "horizontal"])
def test_orientations_about_one_axis_are_named_by_the_run(axis, tmp_path, capsys) -> None:
    """Turns about the vertical only (one gravity direction in ft): 7 of the 13 directions undetermined (as the
    estimator's own test) and the world tilt's 2 (held at 0), their se null in calibration.json and the run says
    so. Turns about one horizontal axis (gravity sweeps a plane) determine every parameter of a payload (f = m g +
    f_o, t = h x g + t_o with g spanning two dimensions): only the world tilt is named (gravity spans fewer than
    three directions: held at 0), every other se finite -- no false alarm. The readings are the payload's in the
    orientations given (readings of other orientations are no load at all: the plausibility checks refuse them)."""
    res = simulate_payload(PayloadConfig(seed=8, n_orientations=6, hold_s=4.0, move_s=2.0))
    df = res.frame.copy()
    q = df[["qw", "qx", "qy", "qz"]].to_numpy()
    ang = 2 * np.arctan2(np.linalg.norm(q[:, 1:], axis=1), q[:, 0])     # each orientation's angle, about one axis now
    e = np.array([0.0, 0.0, 1.0]) if axis == "vertical" else np.array([1.0, 0.0, 0.0])
    df[["qw", "qx", "qy", "qz"]] = np.column_stack([np.cos(ang / 2), np.sin(ang / 2)[:, None] * e])
    df = _readings_for_orientations(res, df)      # the load's readings in these orientations (else no load at all)
    write_free_load(replace(res, frame=df), tmp_path / "data")
    assert run_main([str(_config(tmp_path))]) == 0
    text = "".join(capsys.readouterr())
    leg = json.loads((tmp_path / "out" / "calibration.json").read_text())["legs"]["wrist"]
    se = [*leg["offset_se"], leg["load_mass_se_kg"], *leg["load_com_se_m"], *leg["mount_rotvec_se"]]
    tilt = [u for u in leg["undetermined"] if ".tilt.r" in u]
    assert len(tilt) == 2 and leg["gravity_tilt_rad"] == [0.0, 0.0] and leg["gravity_tilt_se_rad"] == [None, None]
    if axis == "vertical":   # 7 + the world tilt's 2 (held at 0)
        assert len(leg["undetermined"]) == 9 and "not determined by the data" in text and "one direction" in text
        assert leg["load_mass_se_kg"] is None and sum(s is None for s in se) >= 7
    else:                    # only the world tilt (a turn about a horizontal axis moves it like the mount and offsets)
        assert leg["undetermined"] == tilt and "one direction" not in text
        assert all(s is not None and np.isfinite(s) for s in se)
