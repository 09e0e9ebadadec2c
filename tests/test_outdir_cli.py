"""Issue 30, items 1 and 5, through the command line: the tool replaces only what it wrote (its manifest lists it),
an output folder that is or holds an input is refused before anything is read, ``simulate`` writes over only a
dataset it wrote; ``-v`` shows the tool's own debug lines and not the libraries'; a free-load run leaves no empty
``corrected/`` and no naive-tare line."""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest

import ftcal_nlp.run as run_mod
from ftcal_nlp import cli
from ftcal_nlp.core.outdir import MANIFEST, ForeignContentError, OutputFolder, check_apart
from ftcal_nlp.sim import simulate_to_folder

ROOT = Path(__file__).resolve().parents[1]
TABLES = {  # small enough to simulate in well under a second each
    "payload": {"kind": "payload", "n_orientations": 8, "hold_s": 2.0, "seed": 1},
    "urdf_leg": {"kind": "urdf_leg", "n_orientations": 3, "hold_s": 1.0, "seed": 1},
    "hexapod": {"seed": 4, "n_poses": 12, "hanging_cycles": 1.0, "walk_cycles": 0.0},
}


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _dataset(folder: Path, kind: str = "payload") -> Path:
    return simulate_to_folder(dict(TABLES[kind]), folder)


def _config(path: Path, manifest: str, out: str, extra: str = "") -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f'[data]\nmanifest = "{manifest}"\n[output]\ndir = "{out}"\n[diagnose]\nenabled = false\n{extra}')
    return path


def _error(rc: int, err: str) -> str:
    lines = [x for x in err.splitlines() if x.strip()]
    assert rc == 2 and len(lines) == 1 and lines[0].startswith("error: "), err
    return lines[0]


@pytest.fixture
def nothing_read(monkeypatch):
    """The run fails loudly if it gets as far as reading the dataset."""
    def boom(*a, **k):
        raise AssertionError("the dataset was read")

    monkeypatch.setattr(run_mod, "load_or_simulate", boom)
    monkeypatch.setattr(run_mod, "read_dataset", boom)


# ----------------------------------------------------------------------------- an output folder over the inputs


@pytest.mark.parametrize("kind", list(TABLES))
def test_force_into_the_datasets_own_folder_is_refused_before_reading(kind, tmp_path, capsys, nothing_read):
    data = tmp_path / "data"
    _dataset(data, kind)
    cfg = _config(data / "run.toml", "dataset.toml", ".")   # [output] dir = "." beside the dataset (issue 30)
    before = _tree(data)
    line = _error(run_mod.main([str(cfg), "--force"]), capsys.readouterr().err)
    assert f"{data}: the output folder is the dataset's folder {data}" in line and "apart from the inputs" in line
    assert _tree(data) == before and not list(tmp_path.glob(".data.*"))
    # the folder above the dataset, and the same through the one command line
    cfg = _config(tmp_path / "run.toml", "data/dataset.toml", ".")
    line = _error(cli.main(["run", str(cfg), "--force"]), capsys.readouterr().err)
    assert "the output folder holds the" in line and _tree(data) == before


def test_every_input_counts(tmp_path, capsys, nothing_read):
    """The URDF and a recording outside the dataset's folder, an [offsets_only] calibration: each is an input."""
    data = tmp_path / "data"
    _dataset(data, "urdf_leg")
    (tmp_path / "urdf").mkdir()
    os.rename(data / "robot.urdf", tmp_path / "urdf" / "robot.urdf")
    robot = (data / "robot.toml").read_text().replace('urdf = "robot.urdf"', 'urdf = "../urdf/robot.urdf"')
    assert robot != (data / "robot.toml").read_text()
    (data / "robot.toml").write_text(robot)
    cfg = _config(tmp_path / "run.toml", "data/dataset.toml", "urdf")
    line = _error(run_mod.main([str(cfg), "--force"]), capsys.readouterr().err)
    assert "the output folder holds the URDF" in line and (tmp_path / "urdf" / "robot.urdf").is_file()
    (tmp_path / "prior").mkdir()
    (tmp_path / "prior" / "calibration.json").write_text("{}")
    cfg = _config(tmp_path / "run.toml", "data/dataset.toml", "prior", '[offsets_only]\ncalibration = "prior/calibration.json"\n')
    line = _error(run_mod.main([str(cfg), "--force"]), capsys.readouterr().err)
    assert "holds the [offsets_only] calibration" in line and (tmp_path / "prior" / "calibration.json").read_text() == "{}"
    inputs = run_mod.input_paths(run_mod.load_config(_config(tmp_path / "c.toml", "data/dataset.toml", "out")))
    assert {"config file", "dataset's folder", "dataset manifest", "robot description", "URDF", "recording leg.csv"} <= set(inputs)


def test_a_validation_config_beside_its_output_is_refused(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(run_mod, "run_validation", lambda *a, **k: pytest.fail("validation ran"))
    cfg = tmp_path / "v.toml"
    cfg.write_text('[validation]\ndesign = "free"\n[output]\ndir = "."\n')
    line = _error(run_mod.main([str(cfg), "--force"]), capsys.readouterr().err)
    assert "the output folder holds the config file" in line and cfg.is_file()


def test_check_apart_allows_an_output_inside_the_datasets_folder(tmp_path):
    check_apart(tmp_path / "data" / "out", {"dataset's folder": tmp_path / "data", "recording": tmp_path / "data" / "a.csv"})
    with pytest.raises(Exception, match="is the recording"):
        check_apart(tmp_path / "x.csv", {"recording": tmp_path / "x.csv"})


# ----------------------------------------------------------------------------- files the tool did not write


def test_force_into_a_folder_holding_a_users_file_is_refused_and_the_file_kept(tmp_path, capsys, nothing_read):
    _dataset(tmp_path / "data")
    out = tmp_path / "out"
    out.mkdir()
    (out / "thesis.tex").write_bytes(b"\\chapter{my work}\n")
    cfg = _config(tmp_path / "run.toml", "data/dataset.toml", "out")
    for flags in ([], ["--force"]):
        line = _error(run_mod.main([str(cfg), *flags]), capsys.readouterr().err)
        assert "thesis.tex (1 entry)" in line and f"no {MANIFEST}" in line and "--force or not" in line
        assert "only replaces an output folder it wrote" in line
        assert "pass --force" not in line
    assert _tree(out) == {"thesis.tex": b"\\chapter{my work}\n"}


@pytest.fixture(scope="module")
def first_run(tmp_path_factory):
    """A free-load run's result (payload), written once."""
    tmp = tmp_path_factory.mktemp("outcli")
    _dataset(tmp / "data")
    cfg = _config(tmp / "run.toml", "data/dataset.toml", "out")
    assert run_mod.main([str(cfg), "-q"]) == 0
    return tmp, cfg


def test_a_free_load_run_writes_its_manifest_and_no_empty_corrected(first_run):
    tmp, _ = first_run
    out = tmp / "out"
    man = json.loads((out / MANIFEST).read_text())
    assert man["kind"] == "result" and man["kept"] == []
    on_disk = {str(p.relative_to(out)) + ("/" if p.is_dir() else "") for p in out.rglob("*")} - {MANIFEST}
    assert set(man["written"]) == on_disk and "calibration.json" in on_disk
    assert not (out / "corrected").exists()
    cal = json.loads((out / "calibration.json").read_text())
    for leg in cal["legs"].values():   # OUTPUT_FORMAT: hexapod keys only where they apply
        assert "leg_weight_N" not in leg and "leg_com_grid" not in leg and leg["load_mass_kg"] > 0


def test_rerun_with_force_replaces_the_tools_files_and_keeps_the_users(first_run, tmp_path, capsys):
    tmp, _ = first_run
    out = tmp_path / "out"
    os.system(f"cp -a {tmp / 'out'} {out}")
    fresh = json.loads((out / "calibration.json").read_text())["legs"]
    (out / "calibration.json").write_text("stale")              # the tool's: replaced
    (out / "old_figure.png").write_text("stale")                # the tool's (listed), not written again: removed
    man = json.loads((out / MANIFEST).read_text())
    man["written"].append("old_figure.png")
    (out / MANIFEST).write_text(json.dumps(man))
    (out / "notes.txt").write_bytes(b"mine\x00\xff")            # the user's: kept byte-identical
    (out / "mine").mkdir()
    (out / "mine" / "a.csv").write_text("1\n")
    inode = (out / "notes.txt").stat().st_ino
    cfg2 = _config(tmp_path / "run.toml", str(tmp / "data" / "dataset.toml"), "out")
    line = _error(run_mod.main([str(cfg2)]), capsys.readouterr().err)
    assert "holds an earlier result of ftcal_nlp" in line and "pass --force to replace the files it wrote" in line
    assert "would be kept as it is" in line and "mine/" in line and "notes.txt" in line
    assert run_mod.main([str(cfg2), "--force", "-q"]) == 0
    assert json.loads((out / "calibration.json").read_text())["legs"] == fresh and not (out / "old_figure.png").exists()
    assert (out / "notes.txt").read_bytes() == b"mine\x00\xff" and (out / "notes.txt").stat().st_ino == inode
    assert (out / "mine" / "a.csv").read_text() == "1\n"
    assert json.loads((out / MANIFEST).read_text())["kept"] == ["mine/", "notes.txt"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out.")]
    # a user's file with the name of a new result: nothing changes
    (out / "report.md").unlink()
    man = json.loads((out / MANIFEST).read_text())
    man["written"].remove("report.md")
    (out / MANIFEST).write_text(json.dumps(man))
    (out / "report.md").write_text("my report")
    before = _tree(out)
    line = _error(run_mod.main([str(cfg2), "--force", "-q"]), capsys.readouterr().err)
    assert "report.md (1 entry), not written by ftcal_nlp, would be replaced by a new result" in line
    assert _tree(out) == before


def test_a_dataset_the_tool_wrote_is_not_an_output_folder(tmp_path):
    _dataset(tmp_path / "sim")
    before = _tree(tmp_path / "sim")
    with pytest.raises(ForeignContentError, match=r"holds a dataset ftcal_nlp wrote \(.*dataset.toml"):
        OutputFolder(tmp_path / "sim", force=True).__enter__()
    assert _tree(tmp_path / "sim") == before


# ----------------------------------------------------------------------------- simulate writes over its own only


def test_simulate_force_writes_over_only_a_dataset_it_wrote(tmp_path, capsys):
    table = tmp_path / "sim.toml"
    table.write_text('[simulate]\nkind = "payload"\nn_orientations = 8\nhold_s = 2.0\nseed = 1\n')
    real = tmp_path / "real"
    real.mkdir()
    (real / "dataset.toml").write_text('robot = "robot.toml"\n')   # a user's dataset, not the tool's
    (real / "robot.toml").write_text("mine\n")
    line = _error(cli.main(["simulate", str(table), "-o", str(real), "--force"]), capsys.readouterr().err)
    assert "dataset.toml, robot.toml (2 entries), not written by ftcal_nlp" in line and "pass --force" not in line
    assert _tree(real) == {"dataset.toml": b'robot = "robot.toml"\n', "robot.toml": b"mine\n"}
    sim = tmp_path / "sim"
    assert cli.main(["simulate", str(table), "-o", str(sim), "-q"]) == 0
    (sim / "notes.txt").write_text("mine")
    line = _error(cli.main(["simulate", str(table), "-o", str(sim)]), capsys.readouterr().err)
    assert "dataset.toml exists" in line and "pass --force" in line
    assert cli.main(["simulate", str(table), "-o", str(sim), "--force", "-q"]) == 0
    assert (sim / "notes.txt").read_text() == "mine"


# ----------------------------------------------------------------------------- -v, words


def test_verbose_quiets_the_libraries_and_restores_them():
    import argparse

    font = logging.getLogger("matplotlib.font_manager")
    cli.setup(argparse.Namespace(verbose=True, quiet=False, no_progress=False))
    try:
        assert not font.isEnabledFor(logging.DEBUG) and logging.getLogger("ftcal_nlp.run").isEnabledFor(logging.DEBUG)
    finally:
        cli.restore()
    assert logging.getLogger("matplotlib").level == logging.NOTSET


def test_verbose_free_load_run_prints_its_own_lines(tmp_path):
    """A real process (the font manager logs only the first time fonts are looked up in a process)."""
    _dataset(tmp_path / "data")
    cfg = _config(tmp_path / "run.toml", "data/dataset.toml", "out")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MPLCONFIGDIR": str(tmp_path / "mpl")}  # an empty font cache: its lines too
    p = subprocess.run([sys.executable, "-m", "ftcal_nlp", "run", str(cfg), "-v"], capture_output=True, text=True,
                       env=env, timeout=300, cwd=tmp_path, check=False)
    assert p.returncode == 0, p.stderr[-3000:]
    debug = [x for x in p.stderr.splitlines() if " DEBUG " in x]
    assert not [x for x in debug if " DEBUG ftcal_nlp" not in x], debug[:5]
    assert any("DEBUG ftcal_nlp.run: inputs:" in x for x in debug)
    assert "naive-tare" not in p.stdout and "model: free_load" in p.stdout
    assert not (tmp_path / "out" / "corrected").exists()
    md = (tmp_path / "out" / "report.md").read_text()
    assert not [e for e in ("&gt;", "&lt;", "&amp;") if e in md]


def test_help_speaks_to_every_transducer(capsys):
    with pytest.raises(SystemExit):
        run_mod.main(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "legged robot" not in text and "free load" in text and "wrist" in text
    assert cli.main(["--help"]) == 0
    usage = capsys.readouterr().out
    assert "walks" not in usage and "ground contact" not in usage


# ----------------------------------------------------------------------------- ingest writes over its own only


def test_ingest_force_writes_over_only_a_dataset_it_wrote(tmp_path, capsys):
    from test_ros import _source, base_map, make_bag, write_map, write_urdf

    from ftcal_nlp.ingest import main as ingest_main

    write_urdf(tmp_path / "robot.urdf")
    for name, seed in (("hang_xpos", 1), ("hang_xneg", 2)):
        make_bag(tmp_path / name, "sqlite3", _source(f"{name}.csv", "hanging", 200), seed=seed, pose=False)
    mp = write_map(tmp_path / "map.toml", base_map(recordings=[{"bag": "hang_xpos", "kind": "hanging", "gravity_body": [1, 0, 0]},
                                                              {"bag": "hang_xneg", "kind": "hanging", "gravity_body": [-1, 0, 0]}]))
    out = tmp_path / "out"
    out.mkdir()
    (out / "robot.toml").write_text("mine\n")      # a user's file with the name the dataset's robot.toml takes
    line = _error(ingest_main([str(mp), "-o", str(out), "--force", "--format", "csv"]), capsys.readouterr().err)
    assert "robot.toml (1 entry), not written by ftcal_nlp" in line and _tree(out) == {"robot.toml": b"mine\n"}
    (out / "robot.toml").unlink()
    (out / "notes.txt").write_text("mine")
    assert ingest_main([str(mp), "-o", str(out), "--format", "csv", "-q"]) == 0
    line = _error(ingest_main([str(mp), "-o", str(out), "--format", "csv"]), capsys.readouterr().err)
    assert "dataset.toml exists" in line and "pass --force" in line
    assert ingest_main([str(mp), "-o", str(out), "--format", "csv", "--force", "-q"]) == 0
    assert (out / "notes.txt").read_text() == "mine"
    assert set(json.loads((out / MANIFEST).read_text())["written"]) == {"dataset.toml", "robot.toml", "hang_xpos.csv",
                                                                        "hang_xneg.csv"}
