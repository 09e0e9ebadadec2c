"""Issue 30, the output side of every command, through the command line (the blind tester's W1-W5): no command writes
over one of its inputs (the URDF a calibration names, a dataset's files, a protocol, a config), ``--force`` or not;
``export`` replaces only the files its manifest lists; a link as output is followed, never replaced; ``~`` is the
home folder; a transducer name that is a path is refused when robot.toml is read; ``-q`` prints no summary."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from ftcal_nlp import cli
from ftcal_nlp.core.outdir import MANIFEST
from ftcal_nlp.sim import simulate_to_folder

PAYLOAD = {"kind": "payload", "n_orientations": 8, "hold_s": 2.0, "seed": 1}


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _error(rc: int, err: str) -> str:
    lines = [x for x in err.splitlines() if x.strip() and not x[:2].isdigit()]   # log lines start with the time
    assert rc == 2 and len(lines) == 1 and lines[0].startswith("error: "), err
    return lines[0]


def _config(path: Path, manifest: str, out: str) -> Path:
    path.write_text(f'[data]\nmanifest = "{manifest}"\n[output]\ndir = "{out}"\n[diagnose]\nenabled = false\n')
    return path


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """A payload dataset and its calibration (one run, -q)."""
    tmp = tmp_path_factory.mktemp("outputs")
    simulate_to_folder(dict(PAYLOAD), tmp / "data")
    assert cli.main(["run", str(_config(tmp / "run.toml", "data/dataset.toml", "cal")), "-q"]) == 0
    return tmp


def test_correct_never_writes_over_the_urdf_a_calibration_names(tmp_path, capsys):
    """W3: the URDF a URDF-load calibration names is an input (refused before the calibration is read in full)."""
    (tmp_path / "robot.urdf").write_text("<robot name='r'/>\n")
    (tmp_path / "leg.csv").write_text("t\n0\n")
    cal = tmp_path / "calibration.json"
    cal.write_text(json.dumps({"legs": {"leg": {"load_kind": "urdf_subtree", "urdf": "robot.urdf"}}, "meta": {}}))
    before = _tree(tmp_path)
    for out in ("robot.urdf", "link.csv"):
        if out == "link.csv":
            (tmp_path / out).symlink_to("robot.urdf")   # a link to the input is the input
            before = _tree(tmp_path)
        line = _error(cli.main(["correct", str(cal), str(tmp_path / "leg.csv"), "-o", str(tmp_path / out), "--force"]),
                      capsys.readouterr().err)
        assert "would overwrite the URDF of transducer leg" in line and "--force or not" in line
    assert _tree(tmp_path) == before and (tmp_path / "link.csv").is_symlink()


def test_correct_output_a_folder_or_parquet_is_refused(calibrated, tmp_path, capsys):
    cal, rec = calibrated / "cal" / "calibration.json", calibrated / "data" / "wrist.csv"
    (tmp_path / "d").mkdir()
    line = _error(cli.main(["correct", str(cal), str(rec), "-o", str(tmp_path / "d"), "--force"]), capsys.readouterr().err)
    assert "is a folder; expected a file name for the output" in line
    line = _error(cli.main(["correct", str(cal), str(rec), "-o", str(tmp_path / "x.parquet")]), capsys.readouterr().err)
    assert "written as CSV" in line and "'.parquet'" in line and not (tmp_path / "x.parquet").exists()
    # the recording itself, --force or not
    line = _error(cli.main(["correct", str(cal), str(rec), "-o", str(rec), "--force"]), capsys.readouterr().err)
    assert "would overwrite the recording" in line
    # a bag (a ROS 2 bag is a folder, replaced whole with --force) over the recording's folder
    line = _error(cli.main(["correct", str(cal), str(rec), "-o", str(tmp_path / "o.csv"), "--bag", str(rec.parent), "--force"]),
                  capsys.readouterr().err)
    assert "the output folder holds the recording" in line and rec.is_file()


def test_plan_never_writes_over_its_inputs(calibrated, tmp_path, capsys):
    """W5: a pilot's manifest, robot.toml, recording; a protocol; a robot.toml's URDF."""
    data = calibrated / "data"
    before = _tree(data)
    for target, what in (("dataset.toml", "dataset manifest"), ("robot.toml", "robot description"),
                         ("wrist.csv", "recording")):
        line = _error(cli.main(["plan", str(data / "dataset.toml"), "-o", str(data / target), "--force"]), capsys.readouterr().err)
        assert f"would overwrite the {what}" in line
    assert _tree(data) == before
    holds = tmp_path / "P.toml"
    holds.write_text("[protocol]\norientations = [[1, 0, 0, 0], [0, 1, 0, 0]]\n")
    line = _error(cli.main(["plan", str(data / "robot.toml"), "--protocol", str(holds), "-o", str(holds), "--force"]),
                  capsys.readouterr().err)
    assert "would overwrite the protocol" in line and "orientations" in holds.read_text()
    (tmp_path / "r.urdf").write_text("<robot name='r'/>\n")
    (tmp_path / "robot.toml").write_text('g = 9.81\nlegs = ["leg"]\nurdf = "r.urdf"\n[transducers.leg]\nlink = "x"\n')
    line = _error(cli.main(["plan", str(tmp_path / "robot.toml"), "-o", str(tmp_path / "r.urdf"), "--force"]),
                  capsys.readouterr().err)
    assert "would overwrite the URDF" in line and (tmp_path / "r.urdf").read_text().startswith("<robot")


def test_export_replaces_only_what_it_wrote(calibrated, tmp_path, capsys):
    """W4: a user's USAGE.md is kept, --force or not; the export's manifest lets --force replace its own files."""
    cal = calibrated / "cal" / "calibration.json"
    user = tmp_path / "user"
    user.mkdir()
    (user / "USAGE.md").write_text("my notes\n")
    for flags in ([], ["--force"]):
        line = _error(cli.main(["export", str(cal), "-o", str(user), *flags]), capsys.readouterr().err)
        assert "USAGE.md (1 entry), not written by ftcal_nlp" in line
    assert _tree(user) == {"USAGE.md": b"my notes\n"}
    out = tmp_path / "exp"
    assert cli.main(["export", str(cal), "-o", str(out), "-q"]) == 0
    assert capsys.readouterr().out == ""   # -q: only warnings and errors
    man = json.loads((out / MANIFEST).read_text())
    assert set(man["written"]) == {"ftcal_correct.c", "ftcal_correct.h", "USAGE.md"}
    (out / "notes.txt").write_text("kept\n")
    line = _error(cli.main(["export", str(cal), "-o", str(out)]), capsys.readouterr().err)
    assert "pass --force" in line
    assert cli.main(["export", str(cal), "-o", str(out), "--force"]) == 0
    assert (out / "notes.txt").read_text() == "kept\n"
    # a file the export would write that is its input: refused, --force or not, even where a manifest lists the name
    odd = out / "USAGE.md"
    odd.write_bytes(cal.read_bytes())
    line = _error(cli.main(["export", str(odd), "-o", str(out), "--force"]), capsys.readouterr().err)
    assert "would overwrite the calibration" in line and odd.read_bytes() == cal.read_bytes()


def test_run_through_a_symlinked_output_folder_writes_the_real_folder(calibrated, tmp_path, capsys):
    """W1: the link is followed (the real folder gets the new result), never renamed away."""
    real = tmp_path / "real"
    cfg = _config(tmp_path / "a.toml", str(calibrated / "data" / "dataset.toml"), "real")
    assert cli.main(["run", str(cfg), "-q"]) == 0
    (real / "calibration.json").write_text((real / "calibration.json").read_text().replace('"meta"', '"meta_old"', 1))
    (tmp_path / "sl").mkdir()
    (tmp_path / "sl" / "link").symlink_to(real)
    cfg = _config(tmp_path / "sl" / "b.toml", str(calibrated / "data" / "dataset.toml"), "link")
    assert cli.main(["run", str(cfg), "--force", "-q"]) == 0
    assert capsys.readouterr().out == ""   # -q prints no summary
    assert (tmp_path / "sl" / "link").is_symlink() and sorted(p.name for p in (tmp_path / "sl").iterdir()) == ["b.toml", "link"]
    assert '"meta_old"' not in (real / "calibration.json").read_text()


def test_tilde_is_the_home_folder(calibrated, tmp_path, capsys, monkeypatch):
    """W2: [output] dir = "~/res" and -o ~/x.csv go to the home folder; no folder named ~ is left in the cwd."""
    home, work = tmp_path / "home", tmp_path / "work"
    home.mkdir()
    work.mkdir()
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.chdir(work)
    cfg = _config(work / "c.toml", str(calibrated / "data" / "dataset.toml"), "~/res")
    assert cli.main(["run", str(cfg), "-q"]) == 0
    assert (home / "res" / "calibration.json").is_file() and (home / "res" / MANIFEST).is_file()
    cal = calibrated / "cal" / "calibration.json"
    assert cli.main(["correct", str(cal), str(calibrated / "data" / "wrist.csv"), "-o", "~/c.csv", "-q"]) == 0
    assert (home / "c.csv").is_file() and list(work.iterdir()) == [work / "c.toml"]


@pytest.mark.parametrize("name", ["a/b", "a\\b", ".hidden"])
def test_a_transducer_name_that_is_a_path_is_refused(name, tmp_path, capsys):
    """W2: a leg name becomes a file name of the results; refused when robot.toml is read, naming it."""
    data = tmp_path / "data"
    simulate_to_folder(dict(PAYLOAD), data)
    robot = (data / "robot.toml").read_text()
    quoted = json.dumps(name)
    (data / "robot.toml").write_text(robot.replace('"wrist"', quoted).replace("transducers.wrist", f"transducers.{quoted}"))
    csv = data / "wrist.csv"
    lines = csv.read_text().splitlines()
    csv.write_text("\n".join([lines[0].replace("wrist_", f"{name}_"), *lines[1:]]) + "\n")
    line = _error(cli.main(["run", str(_config(tmp_path / "c.toml", "data/dataset.toml", "out")), "-q"]), capsys.readouterr().err)
    assert "robot.toml: 'legs'" in line and repr(name) in line and "not a plain name" in line
    assert not (tmp_path / "out").exists()


def test_simulate_into_a_file_says_it_is_a_file(tmp_path, capsys):
    notes = tmp_path / "mynotes.txt"
    notes.write_text("mine\n")
    table = tmp_path / "s.toml"
    table.write_text('[simulate]\nkind = "payload"\nn_orientations = 8\nhold_s = 2.0\n')
    line = _error(cli.main(["simulate", str(table), "-o", str(notes), "--force"]), capsys.readouterr().err)
    assert "mynotes.txt is a file, not a folder" in line and "pass --force" not in line
    assert notes.read_text() == "mine\n"
    # the config inside the folder under a name the simulation writes
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "dataset.toml").write_text(table.read_text())
    line = _error(cli.main(["simulate", str(tmp_path / "d" / "dataset.toml"), "-o", str(tmp_path / "d"), "--force"]),
                  capsys.readouterr().err)
    assert "would overwrite the config file" in line and (tmp_path / "d" / "dataset.toml").read_text() == table.read_text()


def test_a_link_to_the_datasets_folder_is_the_datasets_folder(calibrated, tmp_path, capsys):
    """Links resolved in the rule itself: an output folder that is a link to the dataset's folder is refused."""
    data = calibrated / "data"
    (tmp_path / "out").symlink_to(data)
    before = _tree(data)
    line = _error(cli.main(["run", str(_config(tmp_path / "c.toml", str(data / "dataset.toml"), "out")), "--force"]),
                  capsys.readouterr().err)
    assert "the output folder is the dataset's folder" in line
    assert _tree(data) == before and (tmp_path / "out").is_symlink()


def test_a_later_run_into_an_export_folder_is_refused(calibrated, tmp_path, capsys):
    out = tmp_path / "exp"
    assert cli.main(["export", str(calibrated / "cal" / "calibration.json"), "-o", str(out), "-q"]) == 0
    before = _tree(out)
    line = _error(cli.main(["run", str(_config(tmp_path / "c.toml", str(calibrated / "data" / "dataset.toml"), "exp")),
                            "--force"]), capsys.readouterr().err)
    assert "holds a C export ftcal_nlp wrote" in line and _tree(out) == before
