"""The free-load rows of the bench (issue 22): accuracy against crb.free_load's bound with the peers side by side, and
the speed rows. Statistics of the estimators themselves are tested in test_crb_loads.py (MC) and test_peers.py;
here what the bench computes from them, at a tiny size."""

from __future__ import annotations

import numpy as np

from ftcal_nlp.bench.accuracy_loads import LoadAccuracySettings, run_load_accuracy
from ftcal_nlp.bench.speed import chain_urdf_text
from ftcal_nlp.sim.free import load_tree


def test_peer_rows_where_their_model_holds_and_where_a_mount_rotation_exists() -> None:
    st = LoadAccuracySettings(seeds=(0, 1, 2), estimators=("ft_calib", "calib_force"),
                              scenarios=("payload_no_mount", "payload_mount"), payload={"n_orientations": 8, "hold_s": 6.0})
    acc = run_load_accuracy(st, progress=False)
    s = acc["summary"].set_index(["scenario", "estimator", "group"])
    # where their model holds both are near the bound (3 datasets: the ratio of a group of p values has a relative
    # se of about 1/sqrt(2 * 3 p); 0.4..1.8 holds it at ~4 se for the one-parameter mass)
    for est in ("ft_calib", "calib_force"):
        for g in ("offsets", "mass", "com"):
            assert 0.4 < s.loc[("payload_no_mount", est, g), "ratio"] < 1.8, (est, g)
    assert ("payload_no_mount", "ft_calib", "mount_rotation") not in s.index      # assumed, not estimated
    # with a ~1 deg mounting rotation ft_calib's CoM and offsets are biased far beyond the bound, calibForce's are not
    assert s.loc[("payload_mount", "ft_calib", "com"), "ratio"] > 20
    assert s.loc[("payload_mount", "calib_force", "com"), "ratio"] < 1.8
    assert len(acc["info"]) == 6 and np.all(acc["info"].ft_calib_kept == acc["info"].n_held)


def test_chain_urdf_has_six_joints_below_its_sensor() -> None:
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "c.urdf"
        p.write_text(chain_urdf_text(6))
        tree = load_tree(p)
    below = [j for j in tree.movable if j != "j_above"]
    assert len(below) == 6 and all(tree.joints_between("ft", f"l{k}") for k in range(6))


# The bench's load parts ("loads", "load_speed") at the tiny size: checked on test_bench.py's tiny end-to-end run
# (``test_bench_runs_end_to_end_at_a_tiny_size``, its ``check_the_load_parts``), which runs them with the same settings
# among its parts; this file ran them a second time.


def test_nlp_reaches_the_bound_and_matches_the_peers_where_their_model_holds() -> None:
    """16 payload datasets without and with a ~1 deg mounting rotation (same seeds: same truth and noise but for
    the rotation). The NLP's errors over the bound pool to 1 (208 z values per scenario; their sd of about
    1/sqrt(2 x 208) grows with the correlations within a dataset: 0.8..1.2, the issue's target, is ~4 of it);
    where the peers' model holds, ft_calib, which is told the mounting, reaches its known-mount bound and the
    NLP's offsets and mass match its errors; with the rotation the NLP is unchanged and ft_calib is not."""
    st = LoadAccuracySettings(seeds=tuple(range(16)), scenarios=("payload_no_mount", "payload_mount"),
                              payload={"n_orientations": 8, "hold_s": 6.0})
    acc = run_load_accuracy(st, progress=False)
    assert not any(c.endswith("_failure") for c in acc["info"].columns)
    d = acc["rows"]
    s = acc["summary"].set_index(["scenario", "estimator", "group"])
    for sc in ("payload_no_mount", "payload_mount"):
        z = d[(d.scenario == sc) & (d.estimator == "nlp")].z
        assert 0.8 < np.sqrt(np.mean(z**2)) < 1.2, sc
    ft = d[(d.scenario == "payload_no_mount") & (d.estimator == "ft_calib")].z_known.dropna()
    assert 0.8 < np.sqrt(np.mean(ft**2)) < 1.2
    for g in ("offsets", "mass"):
        a, b = s.loc[("payload_no_mount", "nlp", g), "rms_error"], s.loc[("payload_no_mount", "ft_calib", g), "rms_error"]
        assert 0.8 < a / b < 1.25, g
    assert s.loc[("payload_mount", "nlp", "com"), "ratio"] < 1.2 < 20 < s.loc[("payload_mount", "ft_calib", "com"), "ratio"]
