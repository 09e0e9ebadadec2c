"""Every key the run config accepts is read by something (issue 21).

The config maps its tables onto the settings dataclasses field by field (``config.py``), so a key the
config accepts is a field of a settings dataclass. This test runs the command line's ``run`` on a small
simulated dataset with every stage on and records which fields code outside ``settings.py`` and
``config.py`` reads (their own checks and the dataclass machinery do not count): every field must be.
A field nobody reads (as ``CalibrationSettings.seed`` was) fails here.
"""

from __future__ import annotations

import sys
from contextlib import contextmanager
from dataclasses import fields, is_dataclass
from typing import Iterator, get_type_hints

from ftcal_nlp.config import load_config
from ftcal_nlp.run import run
from ftcal_nlp.core.settings import CalibrationSettings, OffsetsOnlySettings

# whose reads do not count: the settings' own checks, the config's mapping, generated dataclass methods
_NOT_A_USE = ("settings.py", "config.py", "dataclasses.py", "<string>")


def settings_classes(cls: type = CalibrationSettings) -> list[type]:
    """``cls`` and every settings dataclass below it, walking the fields' types."""
    out = [cls]
    for name, hint in get_type_hints(cls).items():
        if is_dataclass(hint) and hint not in out:
            out += [c for c in settings_classes(hint) if c not in out]
    return out


def leaf_fields(classes: list[type]) -> set[str]:
    """``Class.field`` of every field that is not itself a settings table."""
    return {f"{c.__name__}.{f.name}" for c in classes for f in fields(c) if not is_dataclass(get_type_hints(c)[f.name])}


@contextmanager
def recording_reads(classes: list[type]) -> Iterator[set[str]]:
    """Record ``Class.field`` for each read of a field of ``classes`` from outside ``_NOT_A_USE``."""
    reads: set[str] = set()
    for cls in classes:
        names = {f.name for f in fields(cls)}

        def hook(self, name, _cls=cls, _names=names):
            if name in _names and not sys._getframe(1).f_code.co_filename.endswith(_NOT_A_USE):
                reads.add(f"{_cls.__name__}.{name}")
            return object.__getattribute__(self, name)

        cls.__getattribute__ = hook
    try:
        yield reads
    finally:
        for cls in classes:
            del cls.__getattribute__


def test_the_hook_sees_reads_and_ignores_the_settings_own_checks():
    classes = settings_classes()
    with recording_reads(classes) as reads:
        s = CalibrationSettings()  # __post_init__ checks read fields: not a use
        assert reads == set()
        assert s.selection.folds == 5
    assert reads == {"CalibrationSettings.selection", "SelectionSettings.folds"}


def test_every_setting_the_config_accepts_is_read(tmp_path):
    classes = settings_classes() + [OffsetsOnlySettings]
    cfg_path = tmp_path / "run.toml"
    cfg_path.write_text(
        # a casing load the diagnosis names: the joint refit's switch is read only then
        '[simulate]\ndir = "data"\nseed = 11\nn_poses = 120\nhanging_cycles = 2.0\nwalk_cycles = 2.0\n'
        'effects = [{name = "casing_load", seed = 11}]\n'
        '[output]\ndir = "out"\n'
        '[standing]\nmodel = "auto"\ncandidates = ["full", "trans1"]\n'
        '[correct]\ntrack_offsets = true\n'  # the tracking settings are read only when tracking
    )
    cfg = load_config(cfg_path)
    # a free load (DATA_FORMAT.md section 5): the free-load settings are read only there
    free_path = tmp_path / "free.toml"
    free_path.write_text('[simulate]\nkind = "payload"\ndir = "free_data"\nseed = 3\n[output]\ndir = "free_out"\n'
                         '[free_load]\nloads = {wrist = "rigid_payload"}\n')
    free_cfg = load_config(free_path)
    with recording_reads(classes) as reads:
        res = run(cfg)
        free_res = run(free_cfg)
    assert res.diagnosis is not None and res.diagnosis.verdict == "effect"
    assert free_res.free_loads is not None
    unread = sorted(leaf_fields(classes) - reads)
    assert not unread, f"settings the config accepts but nothing reads: {unread}"
