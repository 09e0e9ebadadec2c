"""Results are safe (issue 24, item 5): a run writes into a staging folder beside the target and swaps it in
whole; a run failing or killed at any stage leaves the earlier result exactly as it was; nothing stale
survives --force; the output folder is checked writable and locked before any fitting."""

import copy
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import ftcal_nlp.run as run_mod
from ftcal_nlp.core.calibration import Calibration
from ftcal_nlp.config import load_config
from ftcal_nlp.core.errors import OutputError
from ftcal_nlp.core.outdir import MANIFEST, OutputExistsError, OutputFolder, inventory, write_manifest

from conftest import require_sample

ROOT = Path(__file__).resolve().parents[1]


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _earlier(folder: Path) -> dict[str, bytes]:
    """An earlier result of the tool (its manifest lists it), with a file a new run does not write (it must not
    survive --force)."""
    (folder / "corrected").mkdir(parents=True)
    (folder / "calibration.json").write_text("earlier calibration")
    (folder / "report.md").write_text("earlier report")
    (folder / "corrected" / "old_walk.csv").write_text("t\n0\n")
    write_manifest(folder, inventory(folder))
    return _tree(folder)


def _nothing_beside(target: Path) -> None:
    """No staging folder, no lock, no set-aside result left beside the target."""
    left = sorted(p.name for p in target.parent.iterdir() if p.name.startswith(f".{target.name}."))
    assert left == [], left


# ----------------------------------------------------------------------------- the folder itself


def test_commit_replaces_the_folder_whole(tmp_path):
    target = tmp_path / "out"
    _earlier(target)
    with OutputFolder(target, force=True) as out:
        assert out.path.parent == tmp_path and out.path != target and list(out.path.iterdir()) == []
        (out.path / "calibration.json").write_text("new")
        assert (target / "calibration.json").read_text() == "earlier calibration"  # untouched until the swap
        out.commit()
    after = _tree(target)
    assert set(after) == {"calibration.json", MANIFEST} and after["calibration.json"] == b"new"  # old_walk.csv is gone
    assert oct(target.stat().st_mode & 0o777) == oct(0o777 & ~_umask())
    _nothing_beside(target)


def _umask() -> int:
    m = os.umask(0o022)
    os.umask(m)
    return m


def test_a_failure_inside_leaves_the_earlier_result(tmp_path):
    target = tmp_path / "out"
    before = _earlier(target)
    with pytest.raises(KeyboardInterrupt):
        with OutputFolder(target, force=True) as out:
            (out.path / "calibration.json").write_text("half")
            raise KeyboardInterrupt
    assert _tree(target) == before
    _nothing_beside(target)


def test_refusals_come_first(tmp_path):
    target = tmp_path / "out"
    _earlier(target)
    with pytest.raises(OutputExistsError, match=r"out holds an earlier result of ftcal_nlp .*; pass --force to replace the "
                                                "files it wrote$"):
        OutputFolder(target).__enter__()
    _nothing_beside(target)
    afile = tmp_path / "afile"
    afile.write_text("x")
    with pytest.raises(OutputError, match=r"afile is a file, not a folder"):
        OutputFolder(afile / "out").__enter__()
    with pytest.raises(OutputError, match=r"afile exists and is not a folder"):
        OutputFolder(afile, force=True).__enter__()
    with pytest.raises(OutputError, match=r"cannot write in /proc"):  # a read-only file system (root ignores modes)
        OutputFolder(Path("/proc/ftcal_out/x")).__enter__()


def test_two_runs_cannot_interleave(tmp_path):
    target = tmp_path / "out"
    with OutputFolder(target) as first:
        with pytest.raises(OutputError, match=rf"out is being written by another run \(pid {os.getpid()}; lock .*\.out\.lock\)"):
            OutputFolder(target).__enter__()
        (first.path / "a").write_text("1")
        first.commit()
    with OutputFolder(target, force=True) as again:  # free again afterwards
        again.commit()
    _nothing_beside(target)


def test_what_a_killed_run_left_is_cleaned_or_restored(tmp_path):
    target = tmp_path / "out"
    before = _earlier(target)
    (tmp_path / ".out.tmp-dead").mkdir()
    (tmp_path / ".out.tmp-dead" / "calibration.json").write_text("half")
    with OutputFolder(target, force=True):
        assert not (tmp_path / ".out.tmp-dead").exists()
    assert _tree(target) == before
    # killed between the two renames of the fallback swap: the earlier result is set aside, the target missing
    os.rename(target, tmp_path / ".out.old-x")
    with OutputFolder(target, force=True):
        assert _tree(target) == before
    _nothing_beside(target)


# ----------------------------------------------------------------------------- a run killed at each stage


def _config(tmp_path: Path) -> Path:
    cfg = tmp_path / "run.toml"
    cfg.write_text(f'[data]\nmanifest = "{require_sample()}/dataset.toml"\n[output]\ndir = "out"\n[diagnose]\nenabled = false\n'
                   '[hanging]\ncompare_baseline = false\n[standing]\nmodel = "full"\ncompare_baseline = false\n')
    return cfg


@pytest.fixture(scope="module")
def sample_result(tmp_path_factory):
    """One real calibration of the sample, replayed by the stage tests (the stages after it are the subject)."""
    tmp = tmp_path_factory.mktemp("outdir")
    cfg = load_config(_config(tmp))
    captured = {}
    real = run_mod.calibrate

    def keep(*a, **k):
        captured["res"] = real(*a, **k)
        return captured["res"]

    run_mod.calibrate = keep
    try:
        run_mod.run(cfg)
    finally:
        run_mod.calibrate = real
    return captured["res"], _tree(tmp / "out")


class Boom(Exception):
    pass


def _boom(*a, **k):
    raise Boom("stage failed")


STAGES = {
    "load": ("load_or_simulate", None),
    "calibrate": ("calibrate", None),
    "write calibration": (None, "save"),
    "write corrected": ("write_corrected", None),
    "report": ("write_report", None),
}


@pytest.mark.parametrize("stage", list(STAGES))
def test_a_run_failing_at_any_stage_leaves_the_earlier_result(stage, sample_result, tmp_path, monkeypatch):
    res, good = sample_result
    cfg = load_config(_config(tmp_path))
    before = _earlier(cfg.output_dir)
    monkeypatch.setattr(run_mod, "calibrate", lambda *a, **k: copy.copy(res))
    fn, method = STAGES[stage]
    if fn:
        monkeypatch.setattr(run_mod, fn, _boom)
    else:
        monkeypatch.setattr(Calibration, method, _boom)
    with pytest.raises(Boom):
        run_mod.run(cfg, force=True)
    assert _tree(cfg.output_dir) == before
    _nothing_beside(cfg.output_dir)
    if stage != "report":
        # The run without the fault below starts from the same folder after every stage's failure (the earlier result
        # byte for byte, nothing beside it: both asserted above) and runs the same code: it is run once, after the
        # last stage's failure (the most written before it), not five times.
        return
    # and the same run without the fault: the whole new result, nothing of the earlier one
    monkeypatch.undo()
    monkeypatch.setattr(run_mod, "calibrate", lambda *a, **k: copy.copy(res))
    run_mod.run(cfg, force=True)
    after = _tree(cfg.output_dir)
    assert set(after) == set(good) and "corrected/old_walk.csv" not in after
    assert after["calibration.json"] != before["calibration.json"]
    _nothing_beside(cfg.output_dir)


def test_unwritable_output_is_found_before_any_fitting(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(run_mod, "calibrate", _boom)
    monkeypatch.setattr(run_mod, "load_or_simulate", _boom)
    (tmp_path / "afile").write_text("x")
    assert run_mod.main([str(_config(tmp_path)), "-o", str(tmp_path / "afile" / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "afile is a file, not a folder" in err and "Traceback" not in err


def test_a_run_killed_while_writing_leaves_the_earlier_result(tmp_path):
    """A real process, SIGKILLed in the middle of writing the corrected recordings (after calibration.json)."""
    cfg = _config(tmp_path)
    out = tmp_path / "out"
    before = _earlier(out)
    script = textwrap.dedent(f"""
        import os, signal
        import ftcal_nlp.run as r
        def write_corrected(res, folder):
            (folder / "corrected").mkdir()
            (folder / "corrected" / "walk.csv").write_text("t,FL_fx\\n1.0,")
            assert (folder / "calibration.json").is_file()
            os.kill(os.getpid(), signal.SIGKILL)
        r.write_corrected = write_corrected
        r.main([{str(cfg)!r}, "--force", "-q"])
    """)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    p = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=600)
    assert p.returncode == -signal.SIGKILL, p.stderr[-2000:]
    assert _tree(out) == before
    assert [q.name.split("-")[0] for q in tmp_path.glob(".out.*")] in ([".out.tmp"], [".out.lock", ".out.tmp"], [".out.tmp", ".out.lock"])
    # the next run is not blocked by the dead one's lock and clears what it left
    with OutputFolder(out, force=True):
        pass
    assert _tree(out) == before
    _nothing_beside(out)
