"""``write_dataset`` / ``recording_to_frame`` with section-5 recordings (issue 22): read -> write -> read gives the
same dataset (CSV and Parquet): transducers without ``{leg}_phi``, ``q_{joint}`` columns, orientation ``qw..qz``
(NaN rows kept) or gravity ``gx..gz``, ``gravity_body`` beside orientation columns, ``free`` lists, the URDF copied
beside ``robot.toml``."""

from __future__ import annotations

import shutil
from dataclasses import replace

import numpy as np
import pytest

from ftcal_nlp.core.data import read_dataset, write_dataset
from ftcal_nlp.sim.free import PayloadConfig, UrdfLegConfig, simulate_payload, simulate_urdf_leg, write_free_load


def _same_array(a, b, what: str, ulp: float = 0.0) -> None:
    assert (a is None) == (b is None), what
    if a is None:
        return
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and np.array_equal(np.isnan(a), np.isnan(b)), what
    ok = ~np.isnan(a)
    assert np.all(np.abs(a[ok] - b[ok]) <= ulp * np.spacing(np.abs(a[ok]))), (what, np.abs(a[ok] - b[ok]).max())


def assert_same_dataset(x, y) -> None:
    rx, ry = x.robot.to_toml_dict(), y.robot.to_toml_dict()
    assert rx == ry
    assert (x.robot.tree is None) == (y.robot.tree is None)
    if x.robot.tree is not None:
        assert x.robot.tree.links == y.robot.tree.links and set(x.robot.tree.bodies) == set(y.robot.tree.bodies)
    assert [(r.name, r.kind, r.free) for r in x.recordings] == [(r.name, r.kind, r.free) for r in y.recordings]
    assert x.free_load_legs == y.free_load_legs
    for a, b in zip(x.recordings, y.recordings):
        w = a.name
        _same_array(a.t, b.t, f"{w}.t")
        assert set(a.phi) == set(b.phi) and set(a.wrench) == set(b.wrench) and list(a.q) == list(b.q), w
        for k in a.phi:
            _same_array(a.phi[k], b.phi[k], f"{w}.phi.{k}")
        for k in a.wrench:
            _same_array(a.wrench[k], b.wrench[k], f"{w}.wrench.{k}")
        for j in a.q:
            _same_array(a.q[j], b.q[j], f"{w}.q.{j}")
        _same_array(a.quat, b.quat, f"{w}.quat")
        _same_array(a.gravity_body, b.gravity_body, f"{w}.gravity_body")
        # gravity from gx..gz is normalised again on reading: a unit vector may move by an ulp
        _same_array(a.gravity, b.gravity, f"{w}.gravity", ulp=2.0)


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_payload_dataset_round_trips(fmt, tmp_path) -> None:
    res = simulate_payload(PayloadConfig(seed=2, n_orientations=4, hold_s=2.0, move_s=1.0))
    df = res.frame.copy()
    df.loc[10:14, ["qw", "qx", "qy", "qz"]] = np.nan                     # orientation lost for a few rows
    ds = read_dataset(write_free_load(replace(res, frame=df), tmp_path / "a"))
    assert ds.free_load_legs == ("wrist",) and ds.hanging[0].phi == {} and np.isnan(ds.hanging[0].gravity[10:15]).all()
    again = read_dataset(write_dataset(ds, tmp_path / "b", fmt=fmt))
    assert_same_dataset(ds, again)


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_urdf_dataset_with_gravity_columns_free_lists_and_gravity_body_round_trips(fmt, tmp_path) -> None:
    cfg = UrdfLegConfig(seed=4, n_orientations=3, poses_per_orientation=2, hold_s=2.0, move_s=1.0, orientation="gravity")
    d = tmp_path / "a"
    write_free_load(simulate_urdf_leg(cfg), d)
    # a second recording with quaternion columns and a nominal gravity_body, in which the leg hangs free
    other = tmp_path / "other"
    write_free_load(simulate_urdf_leg(replace(cfg, seed=9, orientation="quat")), other)
    shutil.copyfile(other / "leg.csv", d / "leg_quat.csv")
    (d / "dataset.toml").write_text((d / "dataset.toml").read_text().replace(
        '{ file = "leg.csv", kind = "hanging" },',
        '{ file = "leg.csv", kind = "hanging", free = ["r_leg"] },\n'
        '    { file = "leg_quat.csv", kind = "hanging", gravity_body = [0.0, 0.0, -1.0] },'))
    ds = read_dataset(d / "dataset.toml")
    a, b = ds.hanging
    assert a.free == ("r_leg",) and a.quat is None and a.gravity is not None and len(a.q) == 6
    assert b.gravity_body is not None and b.quat is None and b.gravity is not None   # gravity from its quaternions
    manifest = write_dataset(ds, tmp_path / "b", fmt=fmt)
    assert (tmp_path / "b" / "robot.urdf").is_file()
    again = read_dataset(manifest)
    assert_same_dataset(ds, again)
    # and once more: what was written reads back to what it was written from
    assert_same_dataset(again, read_dataset(write_dataset(again, tmp_path / "c", fmt=fmt)))


def test_hexapod_dataset_still_round_trips(tmp_path) -> None:
    from conftest import require_sample

    ds = read_dataset(require_sample() / "dataset.toml")
    assert_same_dataset(ds, read_dataset(write_dataset(ds, tmp_path / "h")))
