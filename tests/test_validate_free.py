"""The free-load validation sweep (issue 23, item 5; ``ftcal_nlp/diagnose/validation.py``, part 2): its plan (explicit
seeds, every effect at two sizes, every off-face shape, pairs, clean data; what a kind cannot take left out and
said so), its scoring, config errors that name the key, and a small sweep through ``python -m ftcal_nlp.run``."""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ftcal_nlp.diagnose.validation import free_check_config as check_config
from ftcal_nlp.diagnose.validation import free_effects, shapes_of
from ftcal_nlp.diagnose.validation import free_plan as plan
from ftcal_nlp.diagnose.validation import free_score as score
from ftcal_nlp.diagnose.validation import free_summarise as summarise
from ftcal_nlp.effects import EFFECTS

ROOT = Path(__file__).resolve().parent.parent
NEW = ("clock_offset", "creep", "inertial_load", "joint_limit_contact", "temperature", "gain_crosstalk")


def _toml(path):
    import tomllib

    return tomllib.loads(Path(path).read_text())["validation"]


def test_the_library_of_the_sweep_is_the_new_effects_offset_drift_and_the_gain_matrix():
    assert set(free_effects()) == {"offset_drift", *NEW}
    # every unit's off-face shapes are in the default plan
    assert set(shapes_of(free_effects())) == {s.name for n in free_effects() for s in EFFECTS[n].shapes}


@pytest.mark.parametrize("name,n_runs,n_pairs", [("diagnose_validation_free.toml", 94, 36),
                                                 ("diagnose_validation_free_quick.toml", 63, 11)])
def test_the_problems_plan(name, n_runs, n_pairs):
    c, over = check_config(_toml(ROOT / "problems" / name))
    items, skipped = plan(c, over)
    assert len(items) == n_runs and sum(it["role"] == "pair" for it in items) == n_pairs
    assert [it["seed"] for it in items] == [1000 * c["seed"] + i for i in range(len(items))]   # explicit, distinct
    for kind in ("payload", "urdf_leg"):
        mine = [it for it in items if it["kind"] == kind]
        assert sum(it["role"] == "clean" for it in mine) == c["n_clean"]
        for e in free_effects():
            sizes = [it["scale"] for it in mine if it["role"] == "effect" and it["label"] == e]
            if kind == "payload" and e == "joint_limit_contact":
                assert sizes == [] and f"{e} on payload" in skipped        # no joints: left out, and said so
            else:
                assert sizes == list(EFFECTS[e].magnitude.realistic)   # the realistic low and high end
        for it in mine:
            inj = json.loads(it["injectors"])
            assert all(x["seed"] == it["seed"] for x in inj)
            if it["role"] == "shape":
                assert EFFECTS[it["expect"]].shapes and it["label"] in {s.name for s in EFFECTS[it["expect"]].shapes}
            if it["role"] == "pair":
                assert [x["scale"] for x in inj] == [EFFECTS[x["name"]].magnitude.test for x in inj]


@pytest.mark.parametrize("table,key", [({"design": "free", "bogus": 1}, "bogus"),
                                       ({"design": "free", "effects": ["casing_load"]}, "effects"),
                                       ({"design": "free", "shapes": ["creep"]}, "shapes"),
                                       ({"design": "free", "pairs": [["creep", "creep"]]}, "pairs"),
                                       ({"design": "free", "simulate": {"payload": {"seed": 3}}}, "simulate.payload"),
                                       ({"design": "free", "simulate": {"payload": {"mass": 3}}}, "simulate.payload"),
                                       ({"design": "free", "kinds": ["hexapod"]}, "kinds")])
def test_config_errors_name_the_key(table, key):
    with pytest.raises(ValueError, match=key.replace(".", r"\.")):
        check_config(table)


def _row(**kw):
    base = {"index": 0, "seed": 0, "kind": "payload", "role": "effect", "label": "creep", "size": "lo", "scale": 0.01,
            "expect": "creep", "verdict": "effect", "first": "creep", "named": "creep", "time_s": 1.0,
            "worst_before_noise": 5.0, "worst_after_noise": 1.2}
    return {**base, **kw}


def test_scores():
    rows = pd.DataFrame([
        _row(),                                                                   # named, shrunk
        _row(named="creep clock_offset", worst_after_noise=2.0),                  # named, false second, not shrunk
        _row(named="clock_offset creep", first="clock_offset"),                   # named, not first, false second
        _row(verdict="none", first="none", named="", worst_after_noise=5.0),      # missed
        _row(role="clean", label="none", expect="", verdict="none", first="none", named=""),
        _row(role="clean", label="none", expect="", verdict="unexplained", first="unexplained", named=""),   # not clean
        _row(role="pair", label="creep+temperature", expect="creep+temperature", named="temperature creep", first="temperature"),
        _row(role="pair", label="creep+temperature", expect="creep+temperature", named="creep", first="creep"),
        _row(verdict="error", first="error", named="", worst_after_noise=np.nan),
    ])
    s = score(rows, 1.5)
    assert s["right"].tolist() == [True, True, True, False, True, False, True, False, False]
    assert s["first_right"].tolist() == [True, True, False, False, False, False, False, False, False]
    assert s["false_second"].tolist() == [False, True, True, False, False, False, False, False, False]
    assert s["shrunk"].tolist() == [True, False, True, False, False, False, False, False, False]
    assert s["false_third"].tolist() == [False] * 9
    s3 = score(pd.DataFrame([_row(role="pair", label="creep+temperature", expect="creep+temperature",
                                  named="temperature creep clock_offset")]), 1.5)
    assert s3["right"].tolist() == [True] and s3["false_third"].tolist() == [True] and s3["extra"].tolist() == ["clock_offset"]
    c, _ = check_config({"design": "free", "kinds": ["payload"]})
    per = summarise(s, 1.0, c, [])["per_kind"]["payload"]
    assert per["named"] == [3, 5] and per["clean"] == [1, 2] and per["pairs"] == [1, 2]
    assert per["false_second"] == [2, 4] and per["shrunk"] == [2, 3] and per["finished"] == [8, 9]


def test_a_small_sweep_through_run(tmp_path):
    """``python -m ftcal_nlp.run`` on a ``design = "free"`` table: the outputs of the hexapod sweep, clean data called
    clean on both kinds, and the table's rows."""
    from ftcal_nlp.run import main as run_main

    cfg = tmp_path / "v.toml"
    cfg.write_text('[validation]\ndesign = "free"\nseed = 3\nn_clean = 2\neffects = ["creep", "clock_offset"]\nshapes = []\n'
                   'pairs = [["creep", "clock_offset"]]\n'
                   '[validation.simulate.payload]\nn_orientations = 10\nhold_s = 5.0\nmove_s = 3.0\n'
                   '[validation.simulate.urdf_leg]\nn_orientations = 5\nposes_per_orientation = 3\nhold_s = 4.0\nmove_s = 2.0\n'
                   '[output]\ndir = "out"\n')
    assert run_main([str(cfg)]) == 0
    out = tmp_path / "out"
    for f in ("datasets.csv", "scores.csv", "confusion.csv", "confusion.md", "validation.md", "summary.json"):
        assert (out / f).exists(), f
    rows = pd.read_csv(out / "datasets.csv")
    assert len(rows) == 2 * (2 + 4 + 1) and (rows["verdict"] != "error").all()
    assert rows["seed"].tolist() == [3000 + i for i in range(len(rows))]
    summary = json.loads((out / "summary.json").read_text())
    for kind in ("payload", "urdf_leg"):
        assert summary["per_kind"][kind]["clean"] == [2, 2]
    md = (out / "validation.md").read_text()
    assert "| clean kept clean (verdict `none`) | 2/2 | 2/2 | all |" in md and "false second" in md
