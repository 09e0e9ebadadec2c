"""The name lists of a validation config (``[validation].effects``, ``variants``, ``pairs``, ...), checked against
what the library knows: one check for the hexapod sweep (``validate.py``) and the free-load sweep
(``validate_free.py``), so that neither imports the other for it."""

from __future__ import annotations


def config_names(value, known, key: str, default=None, noun: str = "effect") -> list[str]:
    """The names of ``[validation].<key>`` (None: ``default``, or every name of ``known``), checked against
    ``known`` (``noun``: what they name, for the error)."""
    if value is None:
        return list(known if default is None else default)
    if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
        raise ValueError(f"[validation].{key}: expected a list of {noun} names, got {value!r}")
    unknown = [v for v in value if v not in known]
    if unknown:
        raise ValueError(f"[validation].{key}: unknown {noun}(s) {unknown}; known {noun}s: {sorted(known)}")
    return list(value)
