"""Results are written whole or not at all, and only over what the tool wrote itself.

``with OutputFolder(target, force=force) as out:`` (on entry, before any computation)

1. checks the target: a target that is not a folder, or whose parent cannot be created or written, is an
   :class:`~ftcal_nlp.errors.OutputError` now, not after the fitting. A non-empty folder is refused unless
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

:func:`check_apart` refuses an output folder that is, or lies above, an input (the dataset, the config, a
recording): the caller collects the inputs and calls it before anything is read. :func:`guard_files` is
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
from typing import Iterable, Mapping

from .errors import OutputError, OutputExistsError

__all__ = ["OutputFolder", "OutputExistsError", "ForeignContentError", "MANIFEST", "check_apart", "check_writable",
           "guard_files", "record_written", "read_manifest"]

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


def check_apart(target: str | Path, inputs: Mapping[str, str | Path | None]) -> None:
    """An :class:`OutputError` when the output folder ``target`` is, or lies above, one of ``inputs`` (what each is:
    its path; None entries skipped): replacing the folder would replace the input. An input the folder is
    named before one it holds."""
    t = Path(target) if Path(target).name not in ("", ".", "..") else Path(os.path.abspath(target))
    rt = t.resolve()
    given = {what: Path(p) for what, p in inputs.items() if p is not None}
    same = [(w, p) for w, p in given.items() if p.resolve() == rt]
    below = [(w, p) for w, p in given.items() if rt in p.resolve().parents]
    for what, p in same[:1] or below[:1]:
        where = "is" if same else "holds"
        raise OutputError(f"{t}: the output folder {where} the {what} {p}; the results must go to a folder apart "
                          "from the inputs (e.g. -o results, or [output] dir = \"results\" in the config)", path=t)


def guard_files(folder: str | Path, names: Iterable[str], *, force: bool, flag: str = "--force") -> None:
    """Before writing the files ``names`` into ``folder`` (a command that writes named files beside whatever is
    there): refused if any exists that the folder's manifest does not list (the tool did not write it, so it
    is not replaced, ``force`` or not), or exists at all without ``force``."""
    folder = Path(folder)
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


def record_written(folder: str | Path, names: Iterable[str]) -> None:
    """Add ``names`` (written into ``folder``) to its manifest (created if missing)."""
    folder = Path(folder)
    man = read_manifest(folder) or {"written": [], "kept": []}
    write_manifest(folder, [*map(str, man["written"]), *names], [], kind=str(man.get("kind", "dataset")))

log = logging.getLogger(__name__)


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
        self.target = Path(target)
        if self.target.name in ("", ".", ".."):  # "." has no name to stage beside: the same folder, absolute
            self.target = Path(os.path.abspath(self.target))
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
                f"{t} holds a {man['kind']} ftcal_nlp wrote ({_names(foreign_entries(t, {'written': []}))}), not a result; "
                "results go to a folder apart from datasets: choose a new or empty folder (-o PATH)",
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
