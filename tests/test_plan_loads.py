"""``plan`` for free loads (plan/free_load.py, issue 22 item 5): the Cramer-Rao bound of crb.free_load on a section-5
dataset (the pilot's own samples and noise) or on a protocol of held orientations, against the se the estimator
reports on simulated data (white noise: the weighted fit attains the bound, so they agree to the few per cent the
noise's own estimate moves them), the undetermined parameters named, and the errors of what does not apply."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ftcal_nlp import plan as plan_cli
from ftcal_nlp.core.data import read_dataset
from ftcal_nlp.estimate.freeload import fit_free_load
from ftcal_nlp.core.geometry import rotation_to_quat
from ftcal_nlp.plan.free_load import plan_from_protocol
from ftcal_nlp.sim.free import PayloadConfig, UrdfLegConfig, simulate_payload, simulate_urdf_leg, write_free_load

REL = 0.05   # the fit's se rest on its estimated noise sd (~1 % from 5000 samples) and first-order weights


def fitted_payload(tmp: Path, seed: int):
    """A simulated payload (10 holds of 6 s) written to ``tmp/p``: ``(tmp, simulation, manifest, fit)``."""
    res = simulate_payload(PayloadConfig(seed=seed, n_orientations=10, hold_s=6.0, move_s=3.0))
    manifest = write_free_load(res, tmp / "p")
    return tmp, res, manifest, fit_free_load(read_dataset(manifest), "wrist")


@pytest.fixture(scope="module")
def payload(tmp_path_factory):
    return fitted_payload(tmp_path_factory.mktemp("plan_payload"), seed=3)


def _fit_se(fit) -> dict[str, float]:
    """The fit's se under crb.free_load's names (a payload's CoM se from the load report)."""
    rep = fit.load_report()
    out = {f"offset_{c}": s for c, s in zip(("fx", "fy", "fz", "tx", "ty", "tz"), fit.se[:6])}
    out["mass_kg"] = rep["load_mass_se_kg"]
    out.update({f"com_{c}": s for c, s in zip("xyz", rep["load_com_se_m"])})
    out.update({f"mount_r{c}": s for c, s in zip("xyz", fit.se[-3:])})
    return out


def test_plan_of_a_payload_dataset_is_the_fits_se(payload, tmp_path, capsys) -> None:
    _, _, manifest, fit = payload
    out = tmp_path / "plan.json"
    assert plan_cli.main([str(manifest), "-o", str(out)]) == 0
    js = json.loads(out.read_text())
    assert js["kind"] == "free_load" and js["transducers"]["wrist"]["undetermined"] == []
    se = js["transducers"]["wrist"]["se"]
    for n, s in _fit_se(fit).items():
        assert abs(se[n] / s - 1) < REL, (n, se[n], s)
    assert "load_mass" in capsys.readouterr().out
    assert plan_cli.main([str(manifest), "-o", str(out), "--force", "--search"]) == 2
    assert "--search plans a hexapod session" in capsys.readouterr().err


def test_protocol_of_held_orientations(payload, tmp_path) -> None:
    """The simulation's own held orientations as a protocol: the fit's se; twice the hold: se / sqrt(2);
    orientations all about the vertical: the offsets, mass and a CoM component named, their se null."""
    _, res, _, fit = payload
    quats = []
    for k in range(res.config.n_orientations):
        idx = np.flatnonzero(res.hold_index == k)
        quats.append(rotation_to_quat(res.R_WB[idx[len(idx) // 2]]).tolist())
    base = {"kind": "payload", "orientations": quats, "hold_s": 6.0, "rate_hz": 100.0, "noise_force_N": 0.02,
            "noise_torque_Nm": 0.0006, "mass_kg": res.truth["mass_kg"], "com_m": res.truth["com_m"],
            "rotation_rpy": [0.0, 0.0, np.pi / 2]}                     # the simulator's nominal ft in B
    assert np.allclose(res.truth["nominal_rotation"], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)
    se = plan_from_protocol(base, tmp_path / "p.toml").loads["payload"].se()
    for n, s in _fit_se(fit).items():
        assert abs(se[n] / s - 1) < REL, (n, se[n], s)
    se2 = plan_from_protocol({**base, "hold_s": 12.0}, tmp_path / "p.toml").loads["payload"].se()
    assert all(abs(se2[n] * np.sqrt(2) / se[n] - 1) < 1e-6 for n in se)
    yaw = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    flat = plan_from_protocol({**base, "orientations": [[np.cos(a / 2), 0, 0, np.sin(a / 2)] for a in yaw]},
                              tmp_path / "p.toml").loads["payload"]
    assert flat.bound.unidentified and flat.se()["mass_kg"] is None and flat.se()["offset_fz"] is None
    assert flat.groups()["load_mass"][0] is None and flat.to_json_dict()["se"]["mass_kg"] is None
    assert len(flat.bound.unidentified) == 7                    # one gravity direction: 7 of 13 (as the estimator says)
    assert "tilt_rx" not in flat.bound.names and any("world tilt" in n for n in flat.notes)   # held at 0, as the estimator
    assert "tilt_rx" in plan_from_protocol(base, tmp_path / "p.toml").loads["payload"].bound.names   # estimated, bounded


def test_plan_of_a_urdf_leg_dataset_names_what_the_fit_names(tmp_path) -> None:
    res = simulate_urdf_leg(UrdfLegConfig(seed=5, n_orientations=8, poses_per_orientation=3, hold_s=4.0, move_s=2.0))
    manifest = write_free_load(res, tmp_path / "u")
    out = tmp_path / "plan.json"
    assert plan_cli.main([str(manifest), "-o", str(out)]) == 0
    js = json.loads(out.read_text())["transducers"]["r_leg"]
    fit = fit_free_load(read_dataset(manifest), "r_leg")
    fit_se = {n.split(".", 1)[1].replace(".h_", ".moment_").replace("offset.", "offset_").replace("mount.r", "mount_r")
              .replace("tilt.r", "tilt_r"): s
              for n, s in zip(fit.names, fit.se)}
    assert set(fit_se) == set(js["se"])
    for n, s in js["se"].items():
        assert (s is None) == np.isinf(fit_se[n]), n                # the same parameters undetermined
        if s is not None:
            assert abs(s / fit_se[n] - 1) < REL, (n, s, fit_se[n])
    assert abs(js["groups"]["load_mass"]["se"] / fit.load_report()["load_mass_se_kg"] - 1) < REL
    assert len(js["undetermined"]) == len(fit.undetermined)
    # a protocol of held orientations with the joints never moving: every group's split is undetermined, named
    proto = tmp_path / "proto.toml"
    rng = np.random.default_rng(0)
    holds = "\n".join(f"  {{quat = [{', '.join(f'{v:.6f}' for v in q / np.linalg.norm(q))}]}}," for q in rng.normal(size=(6, 4)))
    proto.write_text(f'[protocol]\nkind = "urdf"\nrobot = "u/robot.toml"\ntransducer = "r_leg"\nhold_s = 4.0\n'
                     f'noise_force_N = 0.05\nnoise_torque_Nm = 0.003\nholds = [\n{holds}\n]\n')
    out2 = tmp_path / "plan2.json"
    assert plan_cli.main([str(proto), "-o", str(out2)]) == 0
    js2 = json.loads(out2.read_text())["transducers"]["r_leg"]
    assert all(js2["se"][f"{g}.mass_kg"] is None for g in ("r_hip_pitch", "r_knee", "r_ankle_pitch", "r_ankle_roll"))
    assert js2["groups"]["load_mass"]["se"] > 0 and len(js2["undetermined"]) > len(js["undetermined"])
    proto.write_text(proto.read_text().replace("{quat", "{q = {r_kne = 0.1}, quat", 1))
    assert plan_cli.main([str(proto), "-o", str(out2), "--force"]) == 2


@pytest.mark.parametrize("table, pattern", [
    ({"kind": "arm"}, r"key 'kind' = 'arm'; expected one of \['payload', 'urdf'\]"),
    ({"kind": "payload", "hold": 3}, r"unknown key\(s\) \['hold'\]"),
    ({"kind": "payload", "orientations": [[0, 0, 0]]}, r"key 'orientations' must be a list of \[qw, qx, qy, qz\]"),
    ({"kind": "payload", "com_m": [0.1]}, r"key 'com_m' must be 3 numbers"),
    ({"kind": "urdf", "holds": []}, r"key 'robot' missing: the robot.toml"),
])
def test_protocol_errors_name_the_key(table, pattern, tmp_path) -> None:
    from ftcal_nlp.core.errors import ConfigError

    with pytest.raises(ConfigError, match=pattern):
        plan_from_protocol(table, Path(tmp_path / "p.toml"))
