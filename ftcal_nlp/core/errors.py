"""The one error family users can act on.

Every error the package raises on purpose is a :class:`FtcalError`; its few
subclasses say what to fix, and each carries the thing it is about, so the
command line can print one ``error:`` line and a caller can catch by kind:

* :class:`DataFormatError` -- a dataset (or a recording, a bag, a URDF) does
  not follow ``DATA_FORMAT.md``; ``path`` / ``column`` name where.
  Its :class:`ImplausibleLoadFit` is a free load's fit that is not physical, with the likely causes.
* :class:`ConfigError` -- a config, protocol or plan file is invalid; ``path``
  / ``key`` name where.
* :class:`SolverError` -- a solver did not report success; ``status`` holds
  the solver's own status text.
* :class:`OutputError` -- a result cannot be written where asked (exists,
  not writable, locked); ``path`` names the folder or file. Its
  :class:`OutputExistsError` (an earlier result is there and overwriting was
  not asked for) is also a ``FileExistsError``.

Anything else that escapes is a defect, not a user error: the command line
and :func:`ftcal_nlp.pipeline.optional` report it with its traceback.

The subclasses also derive from the built-in they replaced (``ValueError``,
``RuntimeError``, ``FileExistsError``) so that callers written against those still work.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["FtcalError", "DataFormatError", "ImplausibleLoadFit", "ConfigError", "SolverError", "OutputError",
           "OutputExistsError"]


class FtcalError(Exception):
    """Base of every error the package raises for the user to act on."""


class DataFormatError(FtcalError, ValueError):
    """A dataset does not follow ``DATA_FORMAT.md``; the message names file, column or key."""

    def __init__(self, message: str, *, path: str | Path | None = None, column: str | None = None):
        super().__init__(message)
        self.path = None if path is None else Path(path)
        self.column = column


class MisSignedChannel(DataFormatError):
    """A standing recording whose load share one leg's channel, sign reversed, brings back (``checks.py``):
    ``column`` names that channel (``{leg}_f{x,y,z}``) and ``leg`` the leg."""

    def __init__(self, message: str, *, leg: str, column: str, path: str | Path | None = None):
        super().__init__(message, path=path, column=column)
        self.leg = leg


class ImplausibleLoadFit(DataFormatError):
    """A free load's fit that is not physical (mass <= 0, mount far from the nominal, residual far above the noise,
    mass 1000x off; ``freeload/plausibility.py``): ``leg`` the transducer, ``causes`` the conventions whose fix made
    it plausible, in the order tried (``"quaternion order"``, ``"gravity sign"``, ``"degrees"``, ``"frame"``,
    ``"units"``; empty when none did)."""

    def __init__(self, message: str, *, leg: str, causes: tuple[str, ...] = (), path: str | Path | None = None):
        super().__init__(message, path=path)
        self.leg = leg
        self.causes = causes


class ConfigError(FtcalError, ValueError):
    """A config file is invalid; the message names the file, the key and what was expected."""

    def __init__(self, message: str, *, path: str | Path | None = None, key: str | None = None):
        super().__init__(message)
        self.path = None if path is None else Path(path)
        self.key = key


class SolverError(FtcalError, RuntimeError):
    """A solver did not converge; ``status`` holds the solver's own status text."""

    def __init__(self, message: str, status: str = "unknown"):
        super().__init__(message)
        self.status = status


class OutputError(FtcalError, RuntimeError):
    """A result cannot be written where asked; ``path`` names the folder or file."""

    def __init__(self, message: str, *, path: str | Path | None = None):
        super().__init__(message)
        self.path = None if path is None else Path(path)


class OutputExistsError(OutputError, FileExistsError):
    """The output (folder or file) holds an earlier result and overwriting was not asked for."""
