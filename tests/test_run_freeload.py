"""Simulator wiring of section-5 datasets into the run (issue 22): ``[simulate] kind = "payload" | "urdf_leg"``
in ``run.load_or_simulate``, the problems' configs, and the truth loader (``truth.py``) on both simulators'
``truth.json`` and on the independent shared samples."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from ftcal_nlp.config import load_config
from ftcal_nlp.core.errors import ConfigError, DataFormatError
from ftcal_nlp.sim.free import config_from_dict, simulate_free
from ftcal_nlp.truth import LoadTruth, free_load_kind, load_truth, load_truth_from_dict

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path("/work/shared")


@pytest.mark.parametrize("name, kind", [("payload_sim.toml", "payload"), ("urdf_leg_sim.toml", "urdf_leg")])
def test_problem_configs_describe_free_load_simulations(name, kind) -> None:
    cfg = load_config(ROOT / "problems" / name)
    assert cfg.simulate["kind"] == kind and "dir" not in cfg.simulate and cfg.simulate_dir is not None
    assert cfg.manifest.parent == cfg.simulate_dir
    sim_cfg = config_from_dict(cfg.simulate)
    assert sim_cfg.kind == kind and sim_cfg.seed == 0


def test_truth_of_both_simulators_round_trips() -> None:
    for table in ({"kind": "payload", "n_orientations": 3, "hold_s": 1.0, "seed": 4},
                  {"kind": "urdf_leg", "n_orientations": 2, "hold_s": 1.0, "seed": 4}):
        res = simulate_free(config_from_dict(table))
        t = load_truth_from_dict(json.loads(json.dumps(res.truth)))
        assert isinstance(t, LoadTruth) and t.kind == table["kind"] and t.transducer == res.config.transducer
        np.testing.assert_array_equal(t.offset, res.truth["offset"])
        np.testing.assert_array_equal(t.mount_rotvec, res.truth["mount_rotvec"])
        if t.kind == "payload":
            assert t.mass_kg == res.config.mass_kg and np.allclose(t.com_m, res.config.com_m)
        else:
            assert t.ft_link == res.config.ft_link and set(t.body_tuples()) == set(res.truth["bodies"])
            assert np.isclose(t.mass_kg, sum(m for m, _ in t.body_tuples().values()))


@pytest.mark.skipif(not SHARED.is_dir(), reason="the shared samples live outside the repository")
def test_truth_of_the_independent_shared_samples() -> None:
    class Robot:                                       # what the truth loader reads of robot.toml
        def __init__(self, folder):
            d = tomllib.loads((folder / "robot.toml").read_text())
            self.legs, self.transducers = tuple(d["legs"]), d["transducers"]

    p = load_truth(SHARED / "sample_payload" / "truth.json", robot=Robot(SHARED / "sample_payload"))
    assert p.kind == "payload" and p.transducer == "wrist" and p.com_m.shape == (3,) and p.mount_rotvec.shape == (3,)
    u = load_truth(SHARED / "sample_urdf" / "truth.json", robot=Robot(SHARED / "sample_urdf"))
    assert u.kind == "urdf_leg" and u.transducer == "leg" and u.ft_link == "leg_ft" and u.mount_rotvec is None
    assert set(u.bodies) == {"upper", "lower", "foot"}


def test_hexapod_truth_is_not_a_free_load() -> None:
    assert free_load_kind({"legs": {}, "mass_kg": 8.0, "com_m": [0, 0, 0]}) is None
    with pytest.raises(DataFormatError, match="needs key 'noise'"):
        load_truth_from_dict({"kind": "payload", "mass_kg": 1.0, "com_m": [0, 0, 0], "offset": [0] * 6})


def test_bad_simulate_key_is_a_config_error(tmp_path) -> None:
    from ftcal_nlp.run import load_or_simulate

    (tmp_path / "c.toml").write_text('[simulate]\nkind = "payload"\nmass = 2.0\n[output]\ndir = "out"\n')
    with pytest.raises(ConfigError, match="unknown key.*mass"):
        load_or_simulate(load_config(tmp_path / "c.toml"), force=False)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("kind", ["payload", "urdf_leg"])
def test_load_or_simulate_writes_and_reads_a_section5_dataset(tmp_path, kind) -> None:
    from ftcal_nlp.run import load_or_simulate

    (tmp_path / "c.toml").write_text(f'[simulate]\nkind = "{kind}"\ndir = "data"\nn_orientations = 3\nhold_s = 1.0\nseed = 2\n'
                                     '[output]\ndir = "out"\n')
    cfg = load_config(tmp_path / "c.toml")
    ds, truth = load_or_simulate(cfg, force=False)
    folder = tmp_path / "data"
    assert (folder / "dataset.toml").is_file() and (folder / "truth.json").is_file()
    assert isinstance(truth, LoadTruth) and truth.kind == kind and ds.robot.legs == (truth.transducer,)
    assert (folder / "robot.urdf").is_file() == (kind == "urdf_leg")
    # the same truth when read back from the written folder by a later run
    (tmp_path / "d.toml").write_text('[data]\nmanifest = "data/dataset.toml"\n[output]\ndir = "out"\n')
    ds2, truth2 = load_or_simulate(load_config(tmp_path / "d.toml"), force=False)
    assert isinstance(truth2, LoadTruth) and np.array_equal(truth2.offset, truth.offset) and truth2.ft_link == truth.ft_link
    assert ds2.recordings[0].n == ds.recordings[0].n
