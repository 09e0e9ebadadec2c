"""Results are written whole or not at all: an output folder staged beside its target and swapped in.

``with OutputFolder(target, force=force) as out:`` (on entry, before any computation)

1. checks the target: a non-empty folder is refused without ``force`` (:class:`OutputExistsError`); a
   target that is not a folder, or whose parent cannot be created or written, is an
   :class:`~ftcal_nlp.errors.OutputError` now, not after the fitting;
2. takes a lock, ``.<name>.lock`` beside the target (``fcntl.flock``: the kernel drops it when the
   process dies, so a killed run never leaves a stale lock; a second run on the same folder is refused
   with the holder's pid);
3. removes what killed runs left beside the target (``.<name>.tmp-*`` staging folders; a ``.<name>.old-*``
   is put back if the target is missing, i.e. a run died between the two renames of the fallback swap);
4. gives ``out.path``, a fresh empty staging folder ``.<name>.tmp-XXXX`` in the same parent (same file
   system, so the swap is a rename).

``out.commit()`` swaps the staging folder in as the target: one atomic ``renameat2(RENAME_EXCHANGE)``
where the kernel has it (Linux >= 3.15), else two renames (target aside, staging in); then the earlier
result is deleted. Nothing of it survives ``--force`` (files the new run does not write are gone with
it), and until the swap the earlier result is exactly as it was: leaving the block with an exception
(a failed stage, Ctrl-C) deletes the staging folder; a SIGKILL leaves it hidden beside the target for the
next run to remove.
"""

from __future__ import annotations

import ctypes
import errno
import fcntl
import logging
import os
import shutil
import tempfile
from pathlib import Path

from .errors import OutputError, OutputExistsError

__all__ = ["OutputFolder", "OutputExistsError", "check_writable"]

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


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


class OutputFolder:
    """A staged output folder for ``target`` (module docstring): ``path`` to write into, ``commit()`` to swap in."""

    def __init__(self, target: str | Path, *, force: bool = False):
        self.target = Path(target)
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
        if t.is_dir() and any(t.iterdir()) and not self.force:
            raise OutputExistsError(f"{t} exists and is not empty; pass --force to overwrite it", path=t)
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
