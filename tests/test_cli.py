"""One command line (issue 24, item 7): ``python -m ftcal_nlp COMMAND``, the console script, the same
flags everywhere (old spellings still accepted), one ``error:`` line with status 2 for every user error,
a bad error model found before any data are read, no Python warning reaching the user."""

import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import ftcal_nlp.run as run_mod
from ftcal_nlp import cli
from ftcal_nlp.correct import main as correct_main
from ftcal_nlp.export import main as export_main

from conftest import require_sample

ROOT = Path(__file__).resolve().parents[1]


def _py(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    env = {"PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "PATH": "/usr/bin:/bin"}
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, cwd=cwd, env=env, timeout=600)


def _one_error(rc: int, err: str) -> str:
    lines = [line for line in err.splitlines() if line.startswith("error: ")]
    assert rc == 2 and len(lines) == 1 and "Traceback" not in err, (rc, err[-2000:])
    return lines[0]


def test_one_command_line_lists_every_command_and_run_help_points_at_the_keys():
    p = _py("-m", "ftcal_nlp", "--help")
    assert p.returncode == 0
    for name in ("run", "correct", "plan", "export", "ingest", "bench", "simulate"):
        assert re.search(rf"^  {name} ", p.stdout, re.M), p.stdout
    h = _py("-m", "ftcal_nlp", "run", "--help")
    assert h.returncode == 0 and "ftcal_nlp/core/settings.py" in h.stdout and "problems/bigant_sim.toml" in h.stdout
    for flag in ("-o PATH, --output PATH", "--force", "-v, --verbose", "-q, --quiet", "--no-progress"):
        assert flag in h.stdout, flag
    # the module forms keep working and show the same flags
    for mod in ("ftcal_nlp.run", "ftcal_nlp.correct", "ftcal_nlp.plan", "ftcal_nlp.export", "ftcal_nlp.ingest", "ftcal_nlp.bench"):
        m = _py("-m", mod, "--help")
        assert m.returncode == 0 and "--output" in m.stdout and "--force" in m.stdout and "--no-progress" in m.stdout, (mod, m.stderr)
    assert _py("-m", "ftcal_nlp", "fit").returncode == 2


def test_console_script_is_declared_and_is_the_dispatcher():
    d = tomllib.loads((ROOT / "pyproject.toml").read_text())
    target = d["project"]["scripts"]["ftcal"]
    module, _, attr = target.partition(":")
    assert module == "ftcal_nlp.cli" and getattr(cli, attr) is cli.main


def test_old_spellings_are_hidden_aliases():
    import argparse

    ap = argparse.ArgumentParser()
    cli.add_common(ap, output_help="x", old_output=("--out",), old_force=("--overwrite",))
    a = ap.parse_args(["--out", "d", "--overwrite"])
    assert a.output == "d" and a.force
    assert "--overwrite" not in ap.format_help() and "--out " not in ap.format_help()


def _sample_config(tmp_path: Path, standing: str) -> Path:
    cfg = tmp_path / "run.toml"
    cfg.write_text(f'[data]\nmanifest = "{require_sample()}/dataset.toml"\n[output]\ndir = "out"\n[diagnose]\nenabled = false\n'
                   f'[standing]\n{standing}\n')
    return cfg


@pytest.mark.parametrize("standing, match", [
    ('model = "fulll"', r"run\.toml \[standing\]\.model: unknown error model 'fulll'; known models: \['full'"),
    ('model = "nowhere/model.py:MyModel"', r"\[standing\]\.model: error model 'nowhere/model\.py:MyModel': file nowhere/model\.py not found"),
    ('candidates = ["full", "trans7"]', r"\[standing\]\.candidates: unknown error model 'trans7'"),
])
def test_unknown_model_is_an_error_before_any_data_are_read(standing, match, tmp_path, capsys, monkeypatch):
    def no_data(*a, **k):
        raise AssertionError("data read before the model was checked")

    monkeypatch.setattr(run_mod, "load_or_simulate", no_data)
    line = _one_error(run_mod.main([str(_sample_config(tmp_path, standing))]), capsys.readouterr().err)
    assert re.search(match, line), line
    assert not (tmp_path / "out").exists()


def test_dash_o_overrides_the_config_output(tmp_path, monkeypatch):
    seen = {}
    monkeypatch.setattr(run_mod, "run", lambda cfg, force=False, quiet=False: seen.update(out=cfg.output_dir, force=force))
    assert cli.main(["run", str(_sample_config(tmp_path, 'model = "full"')), "-o", str(tmp_path / "elsewhere"), "--overwrite"]) == 0
    assert seen == {"out": tmp_path / "elsewhere", "force": True}


def test_every_user_error_is_one_line_with_status_2(tmp_path, capsys):
    cal = tmp_path / "calibration.json"
    cal.write_text("{}")
    # FtcalError subclasses from three commands: a bad option, a missing file, an output that exists
    assert "not a C identifier" in _one_error(export_main([str(cal), "-o", str(tmp_path / "c"), "--name", "1x"]), capsys.readouterr().err)
    assert "nope.json" in _one_error(correct_main([str(tmp_path / "nope.json"), "walk.csv", "-o", str(tmp_path / "o.csv")]),
                                     capsys.readouterr().err)
    (tmp_path / "o.csv").write_text("earlier")
    line = _one_error(cli.main(["correct", str(cal), "walk.csv", "-o", str(tmp_path / "o.csv")]), capsys.readouterr().err)
    assert "o.csv exists; pass --force" in line and (tmp_path / "o.csv").read_text() == "earlier"


def test_no_python_warning_reaches_the_user():
    code = ("import warnings, numpy as np\nfrom ftcal_nlp import cli\nimport argparse\n"
            "cli.setup(argparse.Namespace(verbose=False, quiet=False, no_progress=True))\n"
            "np.log(np.array([-1.0])); np.array([1.0]) / 0.0\nwarnings.warn('a developer message', UserWarning)\n"
            "from tqdm.auto import tqdm\nassert tqdm(range(2), disable=None).disable  # --no-progress over a terminal's default\n"
            "print('done')\n")
    p = _py("-c", code)
    assert p.returncode == 0 and p.stdout.strip() == "done" and p.stderr == "", p.stderr
    v = _py("-c", code.replace("verbose=False", "verbose=True"))
    assert "RuntimeWarning" in v.stderr and "DEBUG ftcal_nlp.pywarnings" in v.stderr  # -v shows them, as log lines


def test_simulate_command_writes_a_dataset(tmp_path, capsys):
    cfg = tmp_path / "sim.toml"
    cfg.write_text('[simulate]\nseed = 4\nn_poses = 12\nhanging_cycles = 1.0\nwalk_cycles = 0.0\ndir = "ds"\n')
    assert cli.main(["simulate", str(cfg), "-q"]) == 0
    assert (tmp_path / "ds" / "dataset.toml").is_file() and capsys.readouterr().out == ""   # -q: only warnings and errors
    assert cli.main(["simulate", str(cfg), "--force"]) == 0 and "simulated" in capsys.readouterr().out
    # a second time: refused without --force, one line
    assert re.search(r"ds/dataset\.toml exists.*; pass --force", _one_error(cli.main(["simulate", str(cfg)]), capsys.readouterr().err))
    assert cli.main(["simulate", str(cfg), "--force", "-o", str(tmp_path / "other")]) == 0
    bad = tmp_path / "bad.toml"
    bad.write_text('[simulate]\nn_poses = "many"\n')
    assert "bad.toml" in _one_error(cli.main(["simulate", str(bad), "-o", str(tmp_path / "x")]), capsys.readouterr().err)
