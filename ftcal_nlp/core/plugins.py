"""Plug-ins named by the user: a class from ``"package.module:Class"`` or ``"path/to/file.py:Class"``.

The registries (error models, loads) look a name up in their own dict first; a name with a colon is code the user
asked for in a run config, imported here. A name read from a data file is never imported (the registries' rule).
"""

from __future__ import annotations

import importlib
import importlib.util
from pathlib import Path

from .errors import ConfigError


def load_class(spec: str, what: str) -> type:
    """The class ``spec`` names: ``"package.module:Class"`` or ``"path/to/file.py:Class"`` (the file imported under a
    name of its own); ``what`` (``"error model"``, ``"load"``) names the plug-in in every error."""
    target, _, cls_name = spec.rpartition(":")
    if not target or not cls_name:
        raise ConfigError(f"{what} {spec!r}: expected 'module:Class' or 'path/file.py:Class'")
    if target.endswith(".py") or "/" in target or "\\" in target:
        path = Path(target)
        if not path.is_file():
            raise ConfigError(f"{what} {spec!r}: file {path} not found", path=path)
        mod_spec = importlib.util.spec_from_file_location(f"ftcal_user_model_{path.stem}", path)
        if mod_spec is None or mod_spec.loader is None:   # a file Python cannot import (not .py)
            raise ConfigError(f"{what} {spec!r}: {path} is not a Python file; expected 'path/file.py:Class'", path=path)
        module = importlib.util.module_from_spec(mod_spec)
        mod_spec.loader.exec_module(module)
    else:
        try:
            module = importlib.import_module(target)
        except ImportError as exc:
            raise ConfigError(f"{what} {spec!r}: cannot import module {target!r} ({exc})") from exc
    if not hasattr(module, cls_name):
        raise ConfigError(f"{what} {spec!r}: module {target!r} has no attribute {cls_name!r}")
    return getattr(module, cls_name)
