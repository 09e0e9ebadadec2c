"""Run configuration: TOML -> frozen dataclasses, validated with errors that name the key.

The minimal config of ``OUTPUT_FORMAT.md`` works on any dataset::

    [data]
    manifest = "path/to/dataset.toml"   # relative to this config file
    [output]
    dir = "path/to/output"
    [diagnose]
    enabled = true

Every other section has defaults (see the dataclasses below). Instead of
``[data] manifest`` a ``[simulate]`` table may describe a dataset to generate
with :mod:`ftcal_nlp.sim` (written to ``[simulate] dir`` when given, else into
the output folder).
"""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from .errors import ConfigError
from .settings import (
    BALANCES,
    COVARIANCES,
    HANGING_METHODS,
    STANDING_SOLVERS,
    WEIGHTINGS,
    CalibrationSettings,
    CorrectSettings,
    DiagnoseSettings,
    HangingSettings,
    OffsetsOnlySettings,
    PoseExtraction,
    SelectionSettings,
    StandingSettings,
)




@dataclass(frozen=True)
class RunConfig:
    path: Path
    manifest: Path | None
    simulate: dict[str, Any] | None
    simulate_dir: Path | None
    output_dir: Path
    hanging: HangingSettings = field(default_factory=HangingSettings)
    standing: StandingSettings = field(default_factory=StandingSettings)
    selection: SelectionSettings = field(default_factory=SelectionSettings)
    diagnose: DiagnoseSettings = field(default_factory=DiagnoseSettings)
    offsets_only: OffsetsOnlySettings = field(default_factory=OffsetsOnlySettings)
    seed: int = 0
    correct: CorrectSettings = field(default_factory=CorrectSettings)

    @property
    def settings(self) -> CalibrationSettings:
        """What :func:`ftcal_nlp.calibrate` needs of this config."""
        return CalibrationSettings(self.hanging, self.standing, self.selection, self.diagnose, self.seed, self.correct)


# key-level choices: checked here too so that the error names the key before the dataclass sees it
_CHOICES = {
    ("hanging", "method"): HANGING_METHODS,
    ("standing", "solver"): STANDING_SOLVERS,
    ("standing", "balance"): BALANCES,
    ("standing", "weighting"): WEIGHTINGS,
    ("standing", "covariance"): COVARIANCES,
}


def _build(cls, table: dict, where: str, section: str):
    """Instantiate dataclass ``cls`` from ``table``, checking keys and types."""
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: expected a table, got {type(table).__name__}")
    known = {f.name: f for f in fields(cls)}
    unknown = sorted(set(table) - set(known))
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown}; known keys: {sorted(known)}")
    kwargs = {}
    for name, value in table.items():
        default = getattr(cls(), name)
        key = f"{where}.{name}"
        if isinstance(default, bool):
            if not isinstance(value, bool):
                raise ConfigError(f"{key}: expected true or false, got {value!r}")
        elif isinstance(default, int) and not isinstance(default, bool):
            if not isinstance(value, int) or isinstance(value, bool):
                raise ConfigError(f"{key}: expected an integer, got {value!r}")
        elif isinstance(default, float):
            if not isinstance(value, (int, float)) or isinstance(value, bool):
                raise ConfigError(f"{key}: expected a number, got {value!r}")
            value = float(value)
        elif isinstance(default, tuple) or (default is None and name in ("effects",)):
            if isinstance(value, str):
                value = (value,)
            if not isinstance(value, list | tuple) or not all(isinstance(v, str) for v in value):
                raise ConfigError(f"{key}: expected a list of names, got {value!r}")
            value = tuple(value)
        elif isinstance(default, str) and not isinstance(value, str):
            if not (name == "smoothing" and isinstance(value, (int, float))):
                raise ConfigError(f"{key}: expected a string, got {value!r}")
        choices = _CHOICES.get((section, name))
        if choices and value not in choices:
            raise ConfigError(f"{key}: expected one of {list(choices)}, got {value!r}")
        kwargs[name] = value
    try:
        return cls(**kwargs)
    except ValueError as exc:  # the settings check their own ranges
        raise ConfigError(f"{where}: {exc}") from exc


def _norm(p: Path) -> Path:
    """``a/../b`` -> ``b``, so logs and reports show the paths a user recognises."""
    return Path(os.path.normpath(p))


def load_config(path: str | Path) -> RunConfig:
    """Read and validate a run config; paths in it are relative to the config file."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: config file not found")
    try:
        d = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from exc
    base = path.parent
    allowed = {"data", "simulate", "output", "hanging", "standing", "selection", "diagnose", "offsets_only", "seed", "correct"}
    unknown = sorted(set(d) - allowed)
    if unknown:
        raise ConfigError(f"{path}: unknown section(s) {unknown}; known: {sorted(allowed)}")

    manifest = None
    data = d.get("data", {})
    if data:
        if set(data) - {"manifest"}:
            raise ConfigError(f"{path} [data]: unknown key(s) {sorted(set(data) - {'manifest'})}; known keys: ['manifest']")
        if not isinstance(data.get("manifest"), str):
            raise ConfigError(f"{path} [data].manifest: expected a path string to dataset.toml")
        manifest = _norm(base / data["manifest"])
    simulate = d.get("simulate")
    sim_dir = None
    if simulate is not None:
        if not isinstance(simulate, dict):
            raise ConfigError(f"{path} [simulate]: expected a table")
        simulate = dict(simulate)
        if "dir" in simulate:
            sim_dir = _norm(base / str(simulate.pop("dir")))
    if manifest is None and simulate is None:
        raise ConfigError(f"{path}: needs [data].manifest (a dataset.toml) or a [simulate] table")

    out = d.get("output", {})
    if not isinstance(out, dict) or not isinstance(out.get("dir"), str):
        raise ConfigError(f"{path} [output].dir: expected a path string for the output folder")
    if set(out) - {"dir"}:
        raise ConfigError(f"{path} [output]: unknown key(s) {sorted(set(out) - {'dir'})}; known keys: ['dir']")

    standing_tbl = dict(d.get("standing", {}))
    poses_tbl = standing_tbl.pop("poses", {})
    standing = _build(StandingSettings, standing_tbl, f"{path} [standing]", "standing")
    try:
        poses = _build(PoseExtraction, poses_tbl, f"{path} [standing.poses]", "poses")
    except ValueError as exc:  # PoseExtraction checks its own ranges
        raise ConfigError(f"{path} [standing.poses]: {exc}") from exc
    standing = replace(standing, poses=poses)
    off_tbl = d.get("offsets_only", {})
    off = OffsetsOnlySettings()
    if off_tbl:
        if set(off_tbl) - {"calibration"} or not isinstance(off_tbl.get("calibration"), str):
            raise ConfigError(f"{path} [offsets_only]: expected only 'calibration' = path to an earlier calibration.json")
        off = OffsetsOnlySettings(_norm(base / off_tbl["calibration"]))
    seed = d.get("seed", 0)
    if not isinstance(seed, int):
        raise ConfigError(f"{path} seed: expected an integer, got {seed!r}")
    sel = _build(SelectionSettings, d.get("selection", {}), f"{path} [selection]", "selection")
    return RunConfig(
        path=path,
        manifest=manifest,
        simulate=simulate,
        simulate_dir=sim_dir,
        output_dir=_norm(base / out["dir"]),
        hanging=_build(HangingSettings, d.get("hanging", {}), f"{path} [hanging]", "hanging"),
        standing=standing,
        selection=sel,
        diagnose=_build(DiagnoseSettings, d.get("diagnose", {}), f"{path} [diagnose]", "diagnose"),
        offsets_only=off,
        seed=seed,
        correct=_build(CorrectSettings, d.get("correct", {}), f"{path} [correct]", "correct"),
    )
