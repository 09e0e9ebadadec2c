"""Results are written whole or not at all, and only over what the tool wrote itself.

``with OutputFolder(target, force=force) as out:`` (on entry, before any computation)

1. checks the target: a target that is not a folder, or whose parent cannot be created or written, is an
   :class:`~ftcal_nlp.core.errors.OutputError` now, not after the fitting. A non-empty folder is refused unless
   the tool wrote it (its :data:`MANIFEST`, ``.ftcal_manifest.json``, lists every file and folder a run
   wrote there, with the tool's version): a folder without one is refused with or without ``--force``
   (:class:`ForeignContentError`, naming what is there), one with it is refused without ``force``
   (:class:`OutputExistsError`);
2. takes a lock, ``.<name>.lock`` beside the target (``fcntl.flock``: the kernel drops it when the
   process dies, so a killed run never leaves a stale lock; a second run on the same folder is refused
   with the holder's pid);
3. removes what killed runs left beside the target (``.<name>.tmp-*`` staging folders; a ``.<name>.old-*``
   is put back if the target is missing, i.e. a run died between the two renames of the fallback swap);
4. gives ``out.path``, a fresh empty staging folder ``.<name>.tmp-XXXX`` in the same parent (same file
   system, so the swap is a rename).

``out.commit()`` writes the manifest of what the run wrote, then swaps the staging folder in as the target:
one atomic ``renameat2(RENAME_EXCHANGE)`` where the kernel has it (Linux >= 3.15), else two renames (target
aside, staging in); then the earlier result is deleted.

What ``--force`` replaces (the choice, of the two issue 30 allows): the files and folders the earlier
manifest lists; anything else in the folder (a note the user put beside the results, a file dropped into
``corrected/``) is kept byte-identical: hard-linked (copied where the file system has no hard links) into
the staging folder before the swap, so that it is in the target before, during and after it, and listed
as ``kept`` in the new manifest. A kept file with the name of a new result stops the commit (nothing
changed). Until the swap the earlier result is exactly as it was: leaving the block with an exception (a
failed stage, Ctrl-C) deletes the staging folder; a SIGKILL leaves it hidden beside the target for the next
run to remove.

:func:`check_apart` is the one rule of outputs against inputs for every command: an output folder that is, or lies
above, an input (the dataset, the config, a recording), or an output file that is one (:func:`check_file_output` for a
named file, :func:`check_files_apart` for the fixed names written into a folder), is an error, ``--force`` or not; the
caller collects the inputs (:func:`dataset_inputs`, :func:`robot_inputs`, :func:`toml_inputs`,
:func:`calibration_inputs`: the files each names, found by parsing TOML or JSON only) and calls it before anything is
read. Every output path has ``~`` expanded and links resolved (:func:`output_path`): the real folder or file behind a
link is written, the link is left as it is. :func:`guard_files` is
the rule for commands that write named files into a folder without replacing it (``simulate``,
``ingest``): an existing file is written over only with ``force`` and only when the folder's manifest
lists it; :func:`record_written` adds what they wrote to the manifest.
"""

from __future__ import annotations

import ctypes
import errno
import fcntl
import json
import logging
import os
import shutil
import tempfile
from pathlib import Path
from typing import Callable, Iterable, Mapping, TypeVar

from .errors import OutputError, OutputExistsError

__all__ = ["OutputFolder", "OutputExistsError", "ForeignContentError", "MANIFEST", "check_apart", "check_files_apart",
           "check_file_output", "output_path", "check_writable", "guard_files", "record_written", "read_manifest",
           "dataset_inputs", "robot_inputs", "toml_inputs", "calibration_inputs"]

log = logging.getLogger(__name__)
T = TypeVar("T")

#: the file in every folder the tool writes that lists what it wrote there
MANIFEST = ".ftcal_manifest.json"
_SHOWN = 5   # names an error message lists before "... (N entries)"


class ForeignContentError(OutputExistsError):
    """The output folder holds files the tool did not write; ``foreign`` lists them (paths inside the folder)."""

    def __init__(self, message: str, *, path: str | Path | None = None, foreign: tuple[str, ...] = ()):
        super().__init__(message, path=path)
        self.foreign = foreign


def tool_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("ftcal_nlp")
    except PackageNotFoundError:
        return "unknown"


def _entries(folder: Path, own: set[str] | None) -> list[str]:
    """Entries under ``folder`` as paths relative to it (``/``-separated, folders with a trailing ``/``; symbolic
    links are entries, never followed; the manifest itself left out): every one with ``own`` None, else those
    ``own`` does not list (a folder not listed counts once, not its content)."""
    out: list[str] = []

    def walk(d: Path, rel: str) -> None:
        for e in sorted(os.scandir(d), key=lambda e: e.name):
            is_dir = e.is_dir(follow_symlinks=False)
            name = f"{rel}{e.name}" + ("/" if is_dir else "")
            if name == MANIFEST:
                continue
            listed = own is None or name in own
            if not listed or own is None:
                out.append(name)
            if listed and is_dir:
                walk(Path(e.path), name)

    walk(folder, "")
    return out


def inventory(folder: Path) -> list[str]:
    """Every entry under ``folder`` (:func:`_entries`)."""
    return _entries(folder, None)


def read_manifest(folder: Path) -> dict | None:
    """The manifest of ``folder`` (``written``: what the tool wrote there), or None when there is none or it is not
    one the tool wrote (unreadable, not JSON, no ``written`` list)."""
    try:
        d = json.loads((folder / MANIFEST).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(d, dict) or not isinstance(d.get("written"), list):
        return None
    return d


def write_manifest(folder: Path, written: Iterable[str], kept: Iterable[str] = (), *, kind: str = "result") -> None:
    """``kind``: ``"result"`` (an output folder :class:`OutputFolder` may replace) or ``"dataset"`` (files written beside
    whatever is there, :func:`record_written`: never replaced as a whole)."""
    d = {"tool": "ftcal_nlp", "version": tool_version(), "kind": kind, "written": sorted(set(written) - {MANIFEST}),
         "kept": sorted(set(kept))}
    (folder / MANIFEST).write_text(json.dumps(d, indent=1) + "\n")


def foreign_entries(folder: Path, manifest: dict | None) -> list[str]:
    """The entries of ``folder`` its manifest does not list (:func:`_entries`)."""
    return _entries(folder, set() if manifest is None else {str(x) for x in manifest["written"]})


def _names(entries: list[str]) -> str:
    shown = ", ".join(entries[:_SHOWN])
    more = f", ... ({len(entries)} entries)" if len(entries) > _SHOWN else f" ({len(entries)} entr{'y' if len(entries) == 1 else 'ies'})"
    return shown + more


def output_path(path: str | Path) -> Path:
    """The path an output is written to: ``~`` expanded, symbolic links resolved (the real file or folder a link names
    is written, never the link replaced by a new file); a relative path stays relative to the working folder."""
    p = Path(os.path.expanduser(str(path)))
    real = Path(os.path.realpath(p))
    if real != Path(os.path.abspath(p)):
        log.info("%s: writing %s (the real path of the link)", p, real)
    return real


def check_apart(target: str | Path, inputs: Mapping[str, str | Path | None], *, folder: bool = True) -> None:
    """The one rule of outputs against inputs, for every command: an :class:`OutputError` when the output ``target``
    is one of ``inputs`` (what each is: its path; None entries skipped), or (``folder``: an output folder the tool
    replaces as a whole) lies above one. Paths are compared with ``~`` expanded and links resolved (a link to an
    input is the input; a hard link too). An input the output is named before one it holds. ``--force`` never
    lifts it: it is for the tool's earlier outputs, never for the data."""
    t = Path(os.path.expanduser(str(target)))
    t = t if t.name not in ("", ".", "..") else Path(os.path.abspath(t))
    rt = t.resolve()
    given = {what: Path(os.path.expanduser(str(p))) for what, p in inputs.items() if p is not None}

    def same(p: Path) -> bool:
        if p.resolve() == rt:
            return True
        try:
            return rt.exists() and p.exists() and os.path.samefile(rt, p)
        except OSError:
            return False

    hits = [(w, p) for w, p in given.items() if same(p)]
    below = [(w, p) for w, p in given.items() if rt in p.resolve().parents] if folder else []
    if hits and not folder:
        what, p = hits[0]
        raise OutputError(f"{t}: the output would overwrite the {what} {p} (an input of this command), --force or not; "
                          "expected another file for the output", path=t)
    for what, p in hits[:1] or below[:1]:
        where = "is" if hits else "holds"
        raise OutputError(f"{t}: the output folder {where} the {what} {p}; the results must go to a folder apart "
                          "from the inputs (e.g. -o results, or [output] dir = \"results\" in the config)", path=t)


def check_files_apart(folder: str | Path, names: Iterable[str], inputs: Mapping[str, str | Path | None]) -> None:
    """:func:`check_apart` for each file ``names`` a command writes into ``folder`` beside what is there (``export``,
    ``simulate``, ``ingest``): none of them may be an input, and ``folder`` must not be a file."""
    f = Path(os.path.expanduser(str(folder)))
    if f.exists() and not f.is_dir():
        raise OutputError(f"{f} is a file, not a folder; expected a folder to write {_names(list(names))} into "
                          "(-o DIR)", path=f)
    for n in names:
        check_apart(f / n, inputs, folder=False)


def check_file_output(target: str | Path, inputs: Mapping[str, str | Path | None], *, force: bool,
                      flag: str = "--force", suffixes: tuple[str, ...] = ()) -> Path:
    """A single named output file (``correct -o``, ``plan -o``): not an input (:func:`check_apart`), not a folder, an
    existing file replaced only with ``force``, a suffix among ``suffixes`` (when given; no suffix passes). Returns the
    path to write (:func:`output_path`: the real file behind a link)."""
    given = Path(os.path.expanduser(str(target)))
    check_apart(given, inputs, folder=False)
    if given.is_dir():
        raise OutputError(f"{given} is a folder; expected a file name for the output (e.g. {given / 'out.csv'})", path=given)
    if suffixes and given.suffix and given.suffix.lower() not in suffixes:
        raise OutputError(f"{given}: the output is written as {suffixes[0].lstrip('.').upper()}; expected a name ending "
                          f"in {' or '.join(suffixes)}, not {given.suffix!r}", path=given)
    if (given.exists() or given.is_symlink()) and not force:
        raise OutputError(f"{given} exists; pass {flag} to replace it", path=given)
    return output_path(given)


def _toml(path: Path) -> dict:
    import tomllib

    try:
        return tomllib.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError):
        return {}  # the reader reports it, naming the file


def robot_inputs(robot: Path) -> dict[str, Path]:
    """A robot.toml and the URDF it names (found cheaply: parsed as TOML only)."""
    out = {"robot description": robot}
    urdf = _toml(robot).get("urdf") if robot.is_file() else None
    if isinstance(urdf, str):
        out["URDF"] = robot.parent / os.path.expanduser(urdf)
    return out


def dataset_inputs(manifest: Path) -> dict[str, Path]:
    """A dataset.toml, its folder, its robot.toml and URDF, every recording it lists (parsed as TOML only)."""
    folder = manifest.parent
    out: dict[str, Path] = {"dataset's folder": folder, "dataset manifest": manifest}
    man = _toml(manifest) if manifest.is_file() else {}
    if isinstance(man.get("robot"), str):
        out.update(robot_inputs(folder / man["robot"]))
    recs = man.get("recording")
    for r in recs if isinstance(recs, list) else []:
        if isinstance(r, dict) and isinstance(r.get("file"), str):
            out[f"recording {r['file']}"] = folder / r["file"]
    return out


def toml_inputs(path: Path, what: str = "input") -> dict[str, Path]:
    """What a TOML input of ``plan`` names, by its keys: a dataset (:func:`dataset_inputs`), a robot.toml
    (:func:`robot_inputs`), a protocol naming ``robot`` (that robot.toml and its URDF), else the file alone."""
    d = _toml(path) if path.is_file() else {}
    if "recording" in d or "recordings" in d:
        return dataset_inputs(path)
    if "legs" in d and "transducers" in d:
        return robot_inputs(path)
    out = {what: path}
    table = d.get("protocol", d)
    if isinstance(table, dict) and isinstance(table.get("robot"), str):
        out.update(robot_inputs(path.parent / os.path.expanduser(table["robot"])))
    return out


def calibration_inputs(cal: Path) -> dict[str, Path]:
    """A calibration.json, its covariance file (``meta.covariance_file``, else ``calibration_cov.npz`` beside it) and
    every URDF its transducers name (relative to its folder, and the file of that name beside it), read as JSON only."""
    out: dict[str, Path] = {"calibration": cal}
    try:
        d = json.loads(cal.read_text())
    except (OSError, ValueError):
        d = {}
    raw_meta = d.get("meta") if isinstance(d, dict) else None
    meta: dict = raw_meta if isinstance(raw_meta, dict) else {}
    cov = meta.get("covariance_file")
    out["calibration's covariance file"] = cal.parent / (cov if isinstance(cov, str) else "calibration_cov.npz")
    raw_legs = d.get("legs") if isinstance(d, dict) else None
    legs: dict = raw_legs if isinstance(raw_legs, dict) else {}
    for name, leg in legs.items():
        if isinstance(leg, dict) and isinstance(leg.get("urdf"), str):
            u = Path(os.path.expanduser(leg["urdf"]))
            out[f"URDF of transducer {name}"] = u if u.is_absolute() else cal.parent / u
            out[f"URDF of transducer {name} (beside the calibration)"] = cal.parent / u.name
    return out


def guard_files(folder: str | Path, names: Iterable[str], *, force: bool, flag: str = "--force") -> None:
    """Before writing the files ``names`` into ``folder`` (a command that writes named files beside whatever is
    there): refused if any exists that the folder's manifest does not list (the tool did not write it, so it
    is not replaced, ``force`` or not), or exists at all without ``force``."""
    folder = output_path(folder)
    present = [n for n in names if (folder / n).exists() or (folder / n).is_symlink()]
    if not present:
        return
    man = read_manifest(folder)
    own = set() if man is None else {str(x) for x in man["written"]}
    foreign = [n for n in present if n not in own]
    if foreign:
        raise ForeignContentError(
            f"{folder}: holds {_names(foreign)}, not written by ftcal_nlp (not in its {MANIFEST}); it only replaces files "
            "it wrote itself: choose a new or empty folder, or move these away", path=folder, foreign=tuple(foreign))
    if not force:
        more = f" with {_names(present[1:])} of the same earlier output" if present[1:] else ""
        raise OutputExistsError(f"{folder / present[0]} exists{more} (written by ftcal_nlp); pass {flag} to replace "
                                "what it wrote (files it did not write are left as they are)", path=folder)


def write_guarded(folder: str | Path, names: Iterable[str], write: Callable[[], T], *, force: bool,
                  kind: str = "dataset") -> T:
    """Write the files ``names`` into ``folder`` beside whatever is there: :func:`guard_files` first (nothing the tool did
    not write is replaced; what it wrote only with ``force``), then ``write()``, then :func:`record_written`; returns
    what ``write`` returns. Every command that writes named files into a folder (simulate, ingest, export, a run's
    simulated dataset) goes through here."""
    names = list(names)
    guard_files(folder, names, force=force)
    out = write()
    record_written(folder, names, kind=kind)
    return out


def record_written(folder: str | Path, names: Iterable[str], *, kind: str = "dataset") -> None:
    """Add ``names`` (written into ``folder``) to its manifest (created, of ``kind``, if missing)."""
    folder = output_path(folder)
    man = read_manifest(folder) or {"written": [], "kind": kind}
    write_manifest(folder, [*map(str, man["written"]), *names], [], kind=str(man.get("kind", kind)))

def _nearest_existing(p: Path) -> Path:
    p = p.absolute()
    while not p.exists():
        p = p.parent
    return p


def check_writable(target: Path) -> None:
    """An :class:`OutputError` unless ``target``'s parent exists as a writable folder or can be created
    (probed by creating and removing a file there: permissions, read-only file systems and quotas alike)."""
    base = _nearest_existing(target.parent)
    if not base.is_dir():
        raise OutputError(f"{target}: cannot be created: {base} is a file, not a folder", path=target)
    try:
        fd, probe = tempfile.mkstemp(prefix=".ftcal-probe-", dir=base)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise OutputError(f"{target}: cannot write in {base} ({exc.strerror or exc}); expected a writable output folder",
                          path=target) from exc


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux ``renameat2`` with ``RENAME_EXCHANGE``); False where unavailable."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    AT_FDCWD, RENAME_EXCHANGE = -100, 2
    if fn(AT_FDCWD, os.fsencode(a), AT_FDCWD, os.fsencode(b), RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.EOPNOTSUPP):  # no such call, or a file system without it
        return False
    raise OSError(err, os.strerror(err), str(a))


def _link_or_copy(src: str, dst: str) -> None:
    try:
        os.link(src, dst, follow_symlinks=False)
    except OSError:  # a file system without hard links: the same bytes, times and mode
        shutil.copy2(src, dst, follow_symlinks=False)


def _replicate(src: Path, dst: Path) -> None:
    """``src`` (a file, link or folder the tool did not write) at ``dst`` too, byte-identical: hard links where possible."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    if src.is_symlink():
        os.symlink(os.readlink(src), dst)
    elif src.is_dir():
        shutil.copytree(src, dst, symlinks=True, copy_function=_link_or_copy)
    else:
        _link_or_copy(str(src), str(dst))


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


class OutputFolder:
    """A staged output folder for ``target`` (module docstring): ``path`` to write into, ``commit()`` to swap in."""

    def __init__(self, target: str | Path, *, force: bool = False):
        # absolute ("." has no name to stage beside) and real: a link to a folder is followed (the staging folder and
        # the swap are beside the real folder), never renamed away and replaced by a folder of its name
        self.target = output_path(target)
        self.force = force
        self.path: Path | None = None
        self._lock_fd: int | None = None
        self._lock_path = self.target.parent / f".{self.target.name}.lock"
        self.committed = False

    # -- entry: checks, lock, clean-up, staging
    def __enter__(self) -> "OutputFolder":
        t = self.target
        if t.exists() and not t.is_dir():
            raise OutputError(f"{t} exists and is not a folder; expected an output folder", path=t)
        if t.is_dir() and any(t.iterdir()):
            self._check_earlier(t)
        check_writable(t)
        try:
            t.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OutputError(f"{t}: cannot create {t.parent} ({exc.strerror or exc})", path=t) from exc
        self._lock()
        try:
            self._clean_leftovers()
            self.path = Path(tempfile.mkdtemp(prefix=f".{t.name}.tmp-", dir=t.parent))
            os.chmod(self.path, 0o777 & ~_umask())  # mkdtemp's 0700 would become the result's mode
        except BaseException:
            self._unlock()
            raise
        return self

    def _check_earlier(self, t: Path) -> None:
        man = read_manifest(t)
        if man is not None and man.get("kind", "result") != "result":
            raise ForeignContentError(
                f"{t} holds a {man['kind']} ftcal_nlp wrote ({_names(foreign_entries(t, None))}), not a result; "
                "a result goes to a folder of its own: choose a new or empty folder (-o PATH)",
                path=t, foreign=tuple(map(str, man["written"])))
        if man is None:
            there = foreign_entries(t, None)
            raise ForeignContentError(
                f"{t} is not empty and has no {MANIFEST} (the list of what ftcal_nlp wrote there): {_names(there)}; the "
                "tool only replaces an output folder it wrote itself, --force or not: choose a new or empty folder (-o PATH), "
                "or move these away (a result of a version without the list: delete it by hand)", path=t, foreign=tuple(there))
        foreign = foreign_entries(t, man)
        if not self.force:
            kept = (f"; what it did not write ({_names(foreign)}) would be kept as it is" if foreign else "")
            raise OutputExistsError(f"{t} holds an earlier result of ftcal_nlp {man.get('version', '')}".rstrip()
                                    + f"; pass --force to replace the files it wrote{kept}", path=t)
        if foreign:
            log.info("%s: keeping %s (not written by ftcal_nlp) as they are", t, _names(foreign))

    def _lock(self) -> None:
        while True:
            fd = os.open(self._lock_path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "?"
                os.close(fd)
                raise OutputError(f"{self.target} is being written by another run (pid {holder}; lock {self._lock_path}); "
                                  "expected one run per output folder", path=self.target) from None
            # the lock file may have been removed (and re-created) by its last holder since we opened it
            try:
                same = os.fstat(fd).st_ino == os.stat(self._lock_path).st_ino
            except FileNotFoundError:
                same = False
            if same:
                os.ftruncate(fd, 0)
                os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
                self._lock_fd = fd
                return
            os.close(fd)

    def _unlock(self) -> None:
        if self._lock_fd is not None:
            try:
                os.unlink(self._lock_path)
            except FileNotFoundError:
                pass
            os.close(self._lock_fd)
            self._lock_fd = None

    def _clean_leftovers(self) -> None:
        parent, name = self.target.parent, self.target.name
        olds = sorted(parent.glob(f".{name}.old-*"))
        if olds and not self.target.exists():  # died between the two renames: the earlier result comes back
            os.rename(olds[-1], self.target)
            log.warning("%s: restored the earlier result from %s (a run was killed while swapping)", self.target, olds[-1].name)
            olds = olds[:-1]
        for p in [*parent.glob(f".{name}.tmp-*"), *olds]:
            log.info("%s: removing %s left by an interrupted run", self.target, p.name)
            shutil.rmtree(p, ignore_errors=True)

    # -- the swap
    def commit(self) -> Path:
        """Swap the staged folder in as the target; returns the target."""
        if self.path is None or self.committed:
            raise RuntimeError("OutputFolder.commit outside its with-block or twice")
        t = self.target
        written = inventory(self.path)
        kept = foreign_entries(t, read_manifest(t)) if t.is_dir() else []
        clash = [k for k in kept if (self.path / k.rstrip("/")).exists() or (self.path / k.rstrip("/")).is_symlink()]
        if clash:
            raise ForeignContentError(f"{t}: {_names(clash)}, not written by ftcal_nlp, would be replaced by a new result of "
                                      "the same name; nothing was changed: move these away and run again",
                                      path=t, foreign=tuple(clash))
        for k in kept:
            _replicate(t / k.rstrip("/"), self.path / k.rstrip("/"))
        write_manifest(self.path, written, kept)
        log.debug("%s: %d entries written, %d kept; swapping %s in", t, len(written), len(kept), self.path.name)
        if t.exists():
            if _exchange(self.path, t):
                old = self.path  # now holds the earlier result
            else:
                old = Path(tempfile.mkdtemp(prefix=f".{t.name}.old-", dir=t.parent))
                os.rmdir(old)
                os.rename(t, old)
                os.rename(self.path, t)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.rename(self.path, t)
        self.committed = True
        return t

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if not self.committed and self.path is not None:
                shutil.rmtree(self.path, ignore_errors=True)  # a failed run leaves the earlier result as it was
        finally:
            self._unlock()
