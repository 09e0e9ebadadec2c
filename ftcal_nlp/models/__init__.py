"""Error-model registry: the report's models by name, or a researcher's own class.

``MODELS`` is a plain dict name -> class. :func:`resolve` accepts a registered
name, ``"package.module:Class"``, ``"path/to/file.py:Class"``, an
:class:`ErrorModel` class or instance; an unknown name raises
:class:`~ftcal_nlp.core.errors.ConfigError` listing the known ones. A model name read from a ``calibration.json``
(:class:`~ftcal_nlp.core.calibration.ModelName`) is looked up in the registry only:
code named in a data file is never imported.
"""

from __future__ import annotations

from ..core.calibration import REPORT_CANDIDATES, ModelName
from ..core.errors import ConfigError
from ..core.plugins import load_class
from .base import Block, ErrorModel, ModelContext, ModelSpec, make_spec, so3_variable, vector_variable
from .builtin import Full, OffsetsOnly, Rot6Trans1, Trans1, Trans6

MODELS: dict[str, type[ErrorModel]] = {
    "full": Full,
    "rot6_trans1": Rot6Trans1,
    "trans6": Trans6,
    "trans1": Trans1,
    "offsets": OffsetsOnly,
}

def resolve(name_or_path: str | ErrorModel | type) -> ErrorModel:
    """An error-model instance from a registered name, ``module:Class``, a path, a class or an instance."""
    obj = name_or_path
    if isinstance(obj, ErrorModel):
        return obj
    if isinstance(obj, str):
        if obj in MODELS:
            return MODELS[obj]()
        if isinstance(obj, ModelName):  # read from a calibration file: never imported (issue 24)
            raise ConfigError(f"error model {str.__str__(obj)!r} of a calibration file is not a registered name; known models: "
                              f"{sorted(MODELS)} (a calibration names its model; code is never imported from a data file)")
        if ":" not in obj:
            raise ConfigError(f"unknown error model {obj!r}; known models: {sorted(MODELS)} (or 'module:Class' / 'file.py:Class')")
        obj = load_class(obj, "error model")
    if isinstance(obj, type):
        inst = obj()
    else:
        raise ConfigError(f"error model: expected a name, 'module:Class' or an ErrorModel, got {type(obj).__name__}")
    if not callable(getattr(inst, "build", None)):
        raise ConfigError(f"error model {name_or_path!r}: class has no build(ctx) method")
    if not getattr(inst, "name", ""):
        raise ConfigError(f"error model {name_or_path!r}: class has no 'name'")
    return inst


__all__ = [
    "MODELS", "REPORT_CANDIDATES", "resolve", "ErrorModel", "ModelContext", "ModelSpec", "Block",
    "make_spec", "so3_variable", "vector_variable", "Full", "Rot6Trans1", "Trans6", "Trans1", "OffsetsOnly",
]
