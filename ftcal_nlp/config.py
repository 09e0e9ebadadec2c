"""Run configuration: TOML -> frozen dataclasses, validated with errors that name the key.

The minimal config of ``OUTPUT_FORMAT.md`` works on any dataset::

    [data]
    manifest = "path/to/dataset.toml"   # relative to this config file
    [output]
    dir = "path/to/output"
    [diagnose]
    enabled = true

Every other table is a field of :class:`~ftcal_nlp.core.settings.CalibrationSettings`
(``[hanging]``, ``[standing]`` with ``[standing.poses]``, ``[selection]``,
``[diagnose]``, ``[correct]``) or ``[offsets_only]`` or ``[holdout]`` (:class:`HoldoutSettings`); its keys are the fields of
that settings dataclass, mapped generically (by the dataclass' fields and their
types), so the defaults and the valid keys live in ``settings.py`` alone. An
unknown key is a :class:`~ftcal_nlp.core.errors.ConfigError` naming the file and the
key and listing the valid ones. Instead of ``[data] manifest`` a ``[simulate]``
table may describe a dataset to generate with :mod:`ftcal_nlp.sim` (written to
``[simulate] dir`` when given, else into the output folder).
"""

from __future__ import annotations

import dataclasses
import os
import tomllib
import types
import typing
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from .core.errors import ConfigError
from .core.settings import CalibrationSettings, OffsetsOnlySettings

__all__ = ["RunConfig", "HoldoutSettings", "load_config", "ConfigError"]


@dataclass(frozen=True)
class HoldoutSettings:
    """``[holdout]``: later recordings of the free loads touching nothing, on which a run validates the calibration it
    fitted (``holdout.py``; outputs in ``holdout/`` of the output folder). ``recordings`` paths relative to the config
    (they must exist), ``alpha`` the test's size, ``gravity_body`` a fixed base's gravity direction in B for recordings
    without orientation columns (None: the calibration's)."""

    recordings: tuple[Path, ...] = ()
    alpha: float = 0.01
    gravity_body: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class RunConfig:
    """A run config: where the data and the output are, and the settings of :func:`ftcal_nlp.calibrate`
    (each TOML table ``[hanging]``, ``[standing]``, ... is the field of :class:`CalibrationSettings` of
    that name)."""

    path: Path
    manifest: Path | None
    simulate: dict[str, Any] | None
    simulate_dir: Path | None
    output_dir: Path
    settings: CalibrationSettings = field(default_factory=CalibrationSettings)
    offsets_only: OffsetsOnlySettings = field(default_factory=OffsetsOnlySettings)
    holdout: HoldoutSettings = field(default_factory=HoldoutSettings)


# tables of the config besides the fields of CalibrationSettings
_RUN_TABLES = ("data", "simulate", "output", "offsets_only", "holdout")
# keys that were accepted once and are gone, with what to use instead
_REMOVED = {"seed": "the top-level seed was read by nothing; the seeds are [simulate] seed (the simulated data), "
                    "[selection] seed and [diagnose] seed (their cross-validation splits)"}


def _is_type(value: Any, hint: Any) -> bool:
    """Whether a TOML value fits the type hint of a settings field (an int is a float, not a bool)."""
    if hint is Any:
        return True
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        return any(_is_type(value, h) for h in typing.get_args(hint))
    if hint is type(None):
        return value is None
    if hint is bool:
        return isinstance(value, bool)
    if hint is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if hint is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if hint is Path:
        return isinstance(value, str)
    if origin is tuple:   # a list of names, or of numbers where the field says tuple[float, ...]
        elem = float if typing.get_args(hint)[:1] == (float,) else str
        return isinstance(value, list) and all(_is_type(v, elem) for v in value)
    return isinstance(value, hint)


def _expected(hint: Any) -> str:
    """What a field of type ``hint`` takes in TOML, in words."""
    args = [h for h in typing.get_args(hint) if h is not type(None)] if typing.get_origin(hint) in (typing.Union, types.UnionType) else [hint]
    words = {bool: "true or false", int: "an integer", float: "a number", str: "a string", Path: "a path string"}
    return " or ".join(words.get(a, ("a list of numbers" if typing.get_args(a)[:1] == (float,) else "a list of names") if typing.get_origin(a) is tuple else getattr(a, "__name__", str(a))) for a in args)


def _convert(value: Any, hint: Any, base: Path) -> Any:
    """A checked TOML value as the field wants it: lists become tuples, numbers floats, paths relative to the config."""
    args = typing.get_args(hint) if typing.get_origin(hint) in (typing.Union, types.UnionType) else (hint,)
    if isinstance(value, list):
        return tuple(float(v) for v in value) if any(typing.get_args(a)[:1] == (float,) for a in args) else tuple(value)
    if Path in args and isinstance(value, str):
        return _at(base, value)
    if float in args and int not in args and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def _build(cls: type, table: Any, path: Path, section: str, base: Path) -> Any:
    """Instantiate the settings dataclass ``cls`` from the TOML ``table`` of ``section``: one key per
    field, of the field's type; a field that is itself a settings dataclass is the sub-table
    ``[section.field]``. Unknown keys and wrong types are errors naming the file and the key."""
    where = f"{path} [{section}]"
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: expected a table, got {type(table).__name__}", path=path, key=section)
    known = {f.name: f for f in fields(cls)}
    unknown = sorted(set(table) - set(known))
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown}; known keys: {sorted(known)}", path=path,
                          key=f"{section}.{unknown[0]}" if section else unknown[0])
    hints = typing.get_type_hints(cls)
    choices = getattr(cls, "CHOICES", {})
    kwargs = {}
    for name, value in table.items():
        hint, key = hints[name], f"{section}.{name}" if section else name
        if isinstance(hint, type) and dataclasses.is_dataclass(hint):   # (a hint is a class, never an instance)
            kwargs[name] = _build(hint, value, path, key, base)
            continue
        if isinstance(value, str) and typing.get_origin(hint) is tuple:
            value = [value]  # one name for a list of names
        if not _is_type(value, hint):
            raise ConfigError(f"{where}.{name}: expected {_expected(hint)}, got {value!r}", path=path, key=key)
        if name in choices and value not in choices[name][1]:
            raise ConfigError(f"{where}.{name}: expected one of {list(choices[name][1])}, got {value!r}", path=path, key=key)
        kwargs[name] = _convert(value, hint, base)
    try:
        return cls(**kwargs)
    except ConfigError as exc:  # the settings check their own ranges and combinations
        raise ConfigError(f"{where}: {exc}", path=path, key=exc.key) from exc


def _norm(p: Path) -> Path:
    """``a/../b`` -> ``b``, so logs and reports show the paths a user recognises."""
    return Path(os.path.normpath(p))


def _at(base: Path, value: str) -> Path:
    """A path of the config: ``~`` is the home folder (as in a shell), else relative to the config's folder."""
    return _norm(base / os.path.expanduser(value))


def read_toml(path: Path, error: type[ConfigError] = ConfigError, what: str = "config file") -> dict[str, Any]:
    """The TOML table of a file (a run config; ``plan``'s protocols and robots); a missing file or invalid TOML is an
    ``error`` naming it (``what`` is said of a missing one)."""
    if not path.is_file():
        raise error(f"{path}: {what} not found", path=path)
    try:
        return tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{path}: not valid TOML ({exc})", path=path) from exc


def _holdout(table: Any, path: Path, base: Path) -> HoldoutSettings:
    """``[holdout]`` checked: a table of known keys, ``recordings`` a non-empty list of existing files (a string is
    one), ``alpha`` in (0, 1), ``gravity_body`` three numbers not all zero; errors name the file and the key."""
    where = f"{path} [holdout]"
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: expected a table (recordings = [\"later.csv\"])", path=path, key="holdout")
    known = [f.name for f in fields(HoldoutSettings)]
    unknown = sorted(set(table) - set(known))
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown}; known keys: {known}", path=path, key=f"holdout.{unknown[0]}")
    recs = table.get("recordings")
    recs = [recs] if isinstance(recs, str) else recs
    if not isinstance(recs, list) or not recs or not all(isinstance(r, str) for r in recs):
        raise ConfigError(f"{where}.recordings: expected a non-empty list of recording files (paths relative to the "
                          f"config), got {table.get('recordings')!r}", path=path, key="holdout.recordings")
    paths = tuple(_at(base, r) for r in recs)
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        raise ConfigError(f"{where}.recordings: file(s) not found: {missing}", path=path, key="holdout.recordings")
    alpha = table.get("alpha", HoldoutSettings.alpha)
    if isinstance(alpha, bool) or not isinstance(alpha, (int, float)) or not 0 < alpha < 1:
        raise ConfigError(f"{where}.alpha: expected a number between 0 and 1 (the test's size, e.g. 0.01), got {alpha!r}",
                          path=path, key="holdout.alpha")
    gb = table.get("gravity_body")
    if gb is not None:
        ok = isinstance(gb, list) and len(gb) == 3 and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in gb)
        if not ok or not any(gb):
            raise ConfigError(f"{where}.gravity_body: expected three numbers, not all zero (gravity's direction in B, "
                              f"pointing down), got {gb!r}", path=path, key="holdout.gravity_body")
        gb = tuple(float(v) for v in gb)
    return HoldoutSettings(paths, float(alpha), gb)


def load_config(path: str | Path) -> RunConfig:
    """Read and validate a run config; paths in it are relative to the config file."""
    path = Path(path)
    d = read_toml(path)
    base = path.parent
    settings_tables = [f.name for f in fields(CalibrationSettings)]
    allowed = set(_RUN_TABLES) | set(settings_tables)
    unknown = sorted(set(d) - allowed)
    if unknown:
        hints = "".join(f"; {k}: {_REMOVED[k]}" for k in unknown if k in _REMOVED)
        raise ConfigError(f"{path}: unknown section(s) {unknown}; known: {sorted(allowed)}{hints}", path=path, key=unknown[0])

    manifest = None
    data = d.get("data", {})
    if data:
        if set(data) - {"manifest"}:
            raise ConfigError(f"{path} [data]: unknown key(s) {sorted(set(data) - {'manifest'})}; known keys: ['manifest']",
                              path=path, key="data")
        if not isinstance(data.get("manifest"), str):
            raise ConfigError(f"{path} [data].manifest: expected a path string to dataset.toml", path=path, key="data.manifest")
        manifest = _at(base, data["manifest"])
    simulate = d.get("simulate")
    sim_dir = None
    if simulate is not None:
        if not isinstance(simulate, dict):
            raise ConfigError(f"{path} [simulate]: expected a table", path=path, key="simulate")
        simulate = dict(simulate)
        if "dir" in simulate:
            sim_dir = _at(base, str(simulate.pop("dir")))
    if manifest is None and simulate is None:
        raise ConfigError(f"{path}: needs [data].manifest (a dataset.toml) or a [simulate] table", path=path, key="data.manifest")

    out = d.get("output", {})
    if not isinstance(out, dict) or not isinstance(out.get("dir"), str):
        raise ConfigError(f"{path} [output].dir: expected a path string for the output folder", path=path, key="output.dir")
    if set(out) - {"dir"}:
        raise ConfigError(f"{path} [output]: unknown key(s) {sorted(set(out) - {'dir'})}; known keys: ['dir']", path=path, key="output")

    settings = _build(CalibrationSettings, {k: d[k] for k in settings_tables if k in d}, path, "", base)
    return RunConfig(
        path=path,
        manifest=manifest,
        simulate=simulate,
        simulate_dir=sim_dir,
        output_dir=_at(base, out["dir"]),
        settings=settings,
        offsets_only=_build(OffsetsOnlySettings, d.get("offsets_only", {}), path, "offsets_only", base),
        holdout=_holdout(d["holdout"], path, base) if "holdout" in d else HoldoutSettings(),
    )
