"""One command line: ``python -m ftcal_nlp COMMAND ...`` (console script ``ftcal COMMAND ...``).

Commands (each also runs as its own module, ``python -m ftcal_nlp.run`` ...; the same ``main``):

========  ==========================================================  ===============================
run       calibrate the transducers of a dataset (run config TOML)    :mod:`ftcal_nlp.run`
correct   calibrated contact wrenches of a recording                  :mod:`ftcal_nlp.correct`
holdout   validate a free-load calibration on a later session         :mod:`ftcal_nlp.holdout`
plan      predicted se of a protocol, shortest protocol for targets   :mod:`ftcal_nlp.plan`
export    the correction as C source for a controller                 :mod:`ftcal_nlp.export`
ingest    ROS bags + URDF -> interchange dataset                      :mod:`ftcal_nlp.ingest`
bench     the benchmarks                                              :mod:`ftcal_nlp.bench`
simulate  write the dataset a ``[simulate]`` table describes          this module
========  ==========================================================  ===============================

Every command takes the same common flags (:func:`add_common`): ``-o/--output``,
``--force`` (replace what the tool wrote before; ``outdir.py``), ``-v/--verbose``, ``-q/--quiet``, ``--no-progress``; the
spellings used before (``--overwrite``, ``--out``) are kept as hidden aliases.
:func:`guarded` turns every error meant for the user (the :class:`~ftcal_nlp.core.errors.FtcalError`
family and the operating system's file errors) into one ``error: ...`` line on stderr and exit
status 2; anything else is a defect and keeps its traceback. :func:`setup` routes Python
warnings (numpy's ``RuntimeWarning`` included) to the log at DEBUG level (seen with ``-v``),
so that none reaches the user as a bare warning. ``-v`` is the tool's own debug lines: the
libraries' loggers (:data:`QUIET_LIBRARIES`: matplotlib's font manager alone logs thousands of
lines) stay at WARNING.
"""

from __future__ import annotations

import argparse
import functools
import importlib
import logging
import os
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

from .core.errors import ConfigError, FtcalError

log = logging.getLogger("ftcal_nlp.cli")

#: errors of the user's own files and folders: one line, not a traceback
USER_ERRORS: tuple[type[BaseException], ...] = (FtcalError, FileNotFoundError, FileExistsError, IsADirectoryError,
                                                NotADirectoryError, PermissionError)
LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"
#: third-party loggers kept at WARNING under -v (their DEBUG lines are theirs, not the run's)
QUIET_LIBRARIES = ("matplotlib", "PIL", "fontTools", "casadi", "cvxpy", "numba", "asyncio", "urllib3", "h5py",
                   "numexpr", "yourdfpy", "trimesh", "rosbags", "pyarrow", "fsspec", "concurrent", "filelock", "joblib")
_UNDO: list[Callable[[], object]] = []   # what setup() changed, undone by guarded() when the command ends


@dataclass(frozen=True)
class Command:
    module: str
    summary: str


COMMANDS: dict[str, Command] = {
    "run": Command("ftcal_nlp.run", "calibrate the transducers of a dataset: run config TOML -> calibration.json, report"),
    "correct": Command("ftcal_nlp.correct", "calibrated wrenches of a recording (contact wrenches with se; contact state for legs)"),
    "holdout": Command("ftcal_nlp.holdout", "validate a free-load calibration on a later session: where it holds, where not"),
    "plan": Command("ftcal_nlp.plan", "predicted se of a protocol; --search: the shortest protocol meeting targets"),
    "export": Command("ftcal_nlp.export", "the correction as C source + header for a controller"),
    "ingest": Command("ftcal_nlp.ingest", "ROS bags (+ URDF) -> interchange dataset"),
    "bench": Command("ftcal_nlp.bench.__main__", "the benchmarks (accuracy, speed, scaling, correction, plan)"),
    "simulate": Command("ftcal_nlp.cli", "write the simulated dataset of a [simulate] table"),
}


def prog_name(command: str | None = None) -> str:
    """``python -m ftcal_nlp`` or the console script's name, with the command."""
    base = os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else ""
    base = "python -m ftcal_nlp" if base in ("", "__main__.py", "-c", "cli.py") or base.endswith(".py") else base
    return f"{base} {command}" if command else base


# ----------------------------------------------------------------------------- common flags


def add_common(ap: argparse.ArgumentParser, *, output_help: str, output_required: bool = False,
               output_default: str | None = None, old_output: Sequence[str] = (), old_force: Sequence[str] = (),
               force_help: str = "overwrite existing outputs") -> None:
    """The flags every command has: ``-o/--output``, ``--force``, ``-v``/``-q``, ``--no-progress``.

    ``old_output`` / ``old_force``: earlier spellings, accepted but not shown in ``--help``.
    ``output_required`` is checked by :func:`parse` (a hidden alias may give it too)."""
    ap.add_argument("-o", "--output", default=output_default, metavar="PATH",
                    help=output_help + (" (required)" if output_required else ""))
    for alias in old_output:
        ap.add_argument(alias, dest="output", help=argparse.SUPPRESS)
    ap.add_argument("--force", action="store_true", help=force_help)
    for alias in old_force:
        ap.add_argument(alias, dest="force", action="store_true", help=argparse.SUPPRESS)
    g = ap.add_mutually_exclusive_group()
    g.add_argument("-v", "--verbose", action="store_true", help="debug log lines (also Python's own warnings)")
    g.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors (no summary: the written files hold it)")
    ap.add_argument("--no-progress", action="store_true", help="no progress bars (they are shown only on a terminal anyway)")
    ap.set_defaults(_output_required=output_required)


def parse(ap: argparse.ArgumentParser, argv: Sequence[str] | None) -> argparse.Namespace:
    """Parse ``argv`` and check what :func:`add_common` leaves to after parsing."""
    args = ap.parse_args(argv)
    if getattr(args, "_output_required", False) and args.output is None:
        ap.error("the following arguments are required: -o/--output")
    return args


def _log_warning(message, category, filename, lineno, file=None, line=None) -> None:
    # a Python warning is a developer's message: the log at DEBUG (-v), never a bare line on stderr
    logging.getLogger("ftcal_nlp.pywarnings").debug("%s: %s (%s:%s)", category.__name__, message, filename, lineno)


def setup(args: argparse.Namespace) -> None:
    """Logging level and format from ``-v``/``-q``; Python warnings to the log; progress bars off on
    ``--no-progress`` or ``-q``; matplotlib's file-only backend."""
    level = logging.DEBUG if getattr(args, "verbose", False) else logging.WARNING if getattr(args, "quiet", False) else logging.INFO
    logging.basicConfig(level=level, format=LOG_FORMAT, datefmt="%H:%M:%S")
    logging.getLogger().setLevel(level)
    quiet_libraries(level)
    route_warnings()
    if getattr(args, "no_progress", False) or getattr(args, "quiet", False):
        disable_progress()
    # files only; the entry point, not the library, picks the backend (before pyplot is imported, if at all)
    if "matplotlib" in sys.modules:
        import matplotlib

        matplotlib.use("Agg")
    else:
        os.environ.setdefault("MPLBACKEND", "Agg")


def quiet_libraries(level: int) -> None:
    """Under ``-v`` (``level`` DEBUG): the :data:`QUIET_LIBRARIES` loggers at WARNING, the tool's own (``ftcal_nlp.*``)
    at DEBUG; undone when the command ends (:func:`restore`)."""
    if level > logging.DEBUG:
        return
    for name in (*QUIET_LIBRARIES, "ftcal_nlp"):
        lg = logging.getLogger(name)
        before = lg.level
        lg.setLevel(logging.DEBUG if name == "ftcal_nlp" else logging.WARNING)
        _UNDO.append(functools.partial(lg.setLevel, before))


def disable_progress() -> None:
    """No progress bar in this process: tqdm's classes default to ``disable=True`` (its ``TQDM_DISABLE`` is read
    when tqdm is imported, which may have happened already); also set for child processes."""
    import tqdm
    import tqdm.auto

    env = os.environ.get("TQDM_DISABLE")
    os.environ["TQDM_DISABLE"] = "1"
    _UNDO.append(lambda: os.environ.pop("TQDM_DISABLE", None) if env is None else os.environ.__setitem__("TQDM_DISABLE", env))
    for cls in {tqdm.tqdm, tqdm.auto.tqdm}:
        if "__init__" in vars(cls) and getattr(cls.__init__, "_ftcal", False):
            continue
        had = "__init__" in vars(cls)
        orig = cls.__init__

        def init(self, *a, _orig=orig, **k):
            k["disable"] = True  # over the caller's disable=None (shown on a terminal)
            _orig(self, *a, **k)

        init._ftcal = True  # type: ignore[attr-defined]  # a marker on the function: the patch is ours
        cls.__init__ = init

        def undo(cls: type = cls, orig: object = orig, had: bool = had) -> None:
            setattr(cls, "__init__", orig) if had else delattr(cls, "__init__")

        _UNDO.append(undo)


def route_warnings() -> None:
    """Every Python warning (numpy's included) goes to the log at DEBUG, once per place."""
    shown, filters = warnings.showwarning, list(warnings.filters)
    warnings.showwarning = _log_warning
    warnings.simplefilter("default")

    def undo() -> None:
        warnings.showwarning = shown
        warnings.filters[:] = filters  # type: ignore[index]  # typeshed declares a Sequence; it is the module's list

    _UNDO.append(undo)


def guarded(fn: Callable[[], int | None], *, extra: tuple[type[BaseException], ...] = ()) -> int:
    """``fn()``'s exit status (None: 0); a user error (:data:`USER_ERRORS` and ``extra``) becomes one
    ``error: ...`` line on stderr and status 2."""
    try:
        rc = fn()
    except USER_ERRORS + extra as exc:
        print(f"error: {error_text(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130
    finally:
        restore()
    return 0 if rc is None else int(rc)


def restore() -> None:
    """Undo what :func:`setup` changed beyond logging (progress bars, warning display): a ``main`` called from
    Python (a test, a notebook) leaves the process as it found it."""
    while _UNDO:
        _UNDO.pop()()


def error_text(exc: BaseException) -> str:
    """One line: the message (an OS error with its file name), newlines folded."""
    if isinstance(exc, OSError) and not isinstance(exc, FtcalError) and exc.filename is not None:
        text = f"{exc.filename}: {exc.strerror or exc}"
    else:
        text = str(exc) or type(exc).__name__
    return " ".join(text.split("\n"))


# ----------------------------------------------------------------------------- simulate


def simulate_main(argv: Sequence[str] | None = None, prog: str | None = None) -> int:
    """``simulate CONFIG.toml [-o DIR] [--force]``: the dataset of a ``[simulate]`` table, written."""
    ap = argparse.ArgumentParser(prog=prog or prog_name("simulate"),
                                 description="Write the simulated dataset a [simulate] table describes (a run config's "
                                             "table, or a TOML file holding only its keys); keys: ftcal_nlp/sim/config.py "
                                             "(hexapod) and ftcal_nlp/sim/free (kind = \"payload\" | \"urdf_leg\").")
    ap.add_argument("config", help="run config with a [simulate] table, or a TOML file of simulator keys")
    add_common(ap, output_help="dataset folder to write (default: the table's 'dir', relative to the config)",
               old_force=("--overwrite",), force_help="replace an existing dataset in the folder")
    args = parse(ap, argv)
    setup(args)
    return guarded(lambda: _simulate(Path(os.path.expanduser(args.config)), args.output, args.force, quiet=args.quiet))


def _simulate(path: Path, output: str | None, force: bool, *, quiet: bool = False) -> int:
    from .config import read_toml
    from .core.outdir import check_files_apart, output_path
    from .sim import simulate_to_folder

    d = read_toml(path)
    table = dict(d["simulate"]) if isinstance(d.get("simulate"), dict) else d
    where = table.pop("dir", None)
    folder = Path(output) if output else (path.parent / os.path.expanduser(where) if isinstance(where, str) else None)
    if folder is None:
        raise ConfigError(f"{path}: no output folder; pass -o DIR or set [simulate] dir", path=path, key="simulate.dir")
    # the files a simulation writes (dataset.toml, robot.toml, recordings, truth.json, a URDF): none may be the config
    check_files_apart(folder, ["dataset.toml", "robot.toml", "truth.json"], {"config file": path})
    folder = output_path(folder)
    try:
        manifest = simulate_to_folder(table, folder, overwrite=force)
    except (TypeError, ValueError) as exc:  # the simulator's own key checks: named with the config file
        if isinstance(exc, FtcalError) and str(path) in str(exc):
            raise
        msg = str(exc) if str(exc).startswith("[simulate]") else f"[simulate]: {exc}"
        raise ConfigError(f"{path} {msg}", path=path, key=getattr(exc, "key", None) or "simulate") from exc
    if not quiet:
        print(f"wrote {manifest} (simulated)")
    return 0


# ----------------------------------------------------------------------------- dispatch


def usage(prog: str) -> str:
    width = max(map(len, COMMANDS))
    lines = [f"usage: {prog} COMMAND [ARGS ...]   ({prog} COMMAND --help for each)", "", "commands:"]
    lines += [f"  {name:<{width}}  {c.summary}" for name, c in COMMANDS.items()]
    lines += ["", "common flags: -o/--output PATH, --force, -v/--verbose, -q/--quiet, --no-progress;",
              "an error is one line 'error: ...' with exit status 2."]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m ftcal_nlp COMMAND ...``: the command's own ``main`` with the rest of the arguments."""
    argv = list(sys.argv[1:] if argv is None else argv)
    prog = prog_name()
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(usage(prog))
        return 0 if argv else 2
    if argv[0] == "--version":
        from importlib.metadata import PackageNotFoundError, version

        try:
            print(version("ftcal_nlp"))
        except PackageNotFoundError:
            print("ftcal_nlp (not installed)")
        return 0
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"error: unknown command {name!r}; expected one of {', '.join(COMMANDS)}", file=sys.stderr)
        return 2
    if name == "simulate":
        return simulate_main(rest, prog=f"{prog} simulate")
    module = importlib.import_module(COMMANDS[name].module)
    return module.main(rest, prog=f"{prog} {name}")


if __name__ == "__main__":
    raise SystemExit(main())
