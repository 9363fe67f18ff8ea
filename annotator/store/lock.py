"""One run per output folder: an exclusive ``flock`` the OS releases however the run ends.

The lock is taken on the folder itself (its directory file descriptor), so removing the lock
file during a run neither frees the folder for a second run nor breaks the first; the lock file
(``.rg2-annotator.lock``) only says who holds the folder. Where a file system cannot lock a
directory, the lock file is locked instead and its inode is checked whenever the manifest is
saved: a run whose lock file was removed or replaced stops with one line
(:class:`LockLostError`) instead of writing beside another run.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import errno
import fcntl
import json
import os
import signal
import socket
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from annotator.store.errors import LockedError
from annotator.store.files import OutputError, output_error
from annotator.store.names import LOCK_NAME

LOCK_ATTEMPTS = 5


class LockLostError(OutputError):
    """The folder's lock file was removed or replaced while this run held it (exit code 3)."""


@dataclass
class RunLock:
    """An exclusive ``flock`` on the output folder (or, where folders cannot be locked, on its
    lock file); the file tells who holds it.

    ``name`` and ``whole_folder=False``: the lock of one file a tool writes in the folder (its own
    lock file ``name``, locked itself; :mod:`annotator.store.outputs`), so that two commands
    writing other files in one folder do not exclude each other. Such a lock file is removed when
    the lock is released; a process that locked it after the removal sees its inode gone and locks
    the new one instead."""

    out_dir: Path
    fd: int | None = None  # the locked descriptor: the folder's, or the lock file's
    on_file: bool = False  # the lock file itself is locked (no directory locks here)
    inode: tuple[int, int] | None = None  # (st_dev, st_ino) of the lock file this run wrote
    name: str = LOCK_NAME
    whole_folder: bool = True
    subject: str = ""  # what the refusal names as held ("" the folder)

    def acquire(self) -> None:
        """Take the lock, LockedError naming the holder, or OutputError if the folder is not writable."""
        path = self.out_dir / self.name
        for _ in range(LOCK_ATTEMPTS):
            try:
                info_fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o666)
            except OSError as exc:
                raise output_error(path, exc) from exc
            try:
                self.fd, self.on_file = self._lock_soon(info_fd)
            except BlockingIOError:
                holder = _read_holder(info_fd)
                os.close(info_fd)
                if self.whole_folder:
                    raise LockedError(
                        f"{self.out_dir} is in use by another run ({holder}); wait for it to finish or "
                        "choose another --out"
                    ) from None
                raise LockedError(
                    f"{self.subject or path} is being written by another command ({holder}); wait for "
                    "it to finish or give another file name"
                ) from None
            if self.whole_folder or _same_file(path, info_fd):
                break
            self.release()  # the file was removed by the holder that released it: lock the new one
        else:
            raise LockedError(f"{path}: its lock file keeps being replaced; try again")
        info = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "started": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]])[:300],
        }
        with contextlib.suppress(OSError):
            os.ftruncate(info_fd, 0)
            os.pwrite(info_fd, json.dumps(info).encode(), 0)
        stat = os.fstat(info_fd)
        self.inode = (stat.st_dev, stat.st_ino)
        if not self.on_file:
            os.close(info_fd)

    def _lock_soon(self, info_fd: int) -> tuple[int, bool]:
        """:meth:`_lock`, tried a few times over ~0.1 s: a reader's probe (:func:`is_locked`) holds a
        shared lock for microseconds and must not turn a run away."""
        for attempt in range(LOCK_ATTEMPTS):
            try:
                return self._lock(info_fd)
            except BlockingIOError:
                if attempt == LOCK_ATTEMPTS - 1:
                    raise
                time.sleep(0.02)
        raise AssertionError("unreachable")

    def _lock(self, info_fd: int) -> tuple[int, bool]:
        """Lock the folder (or the lock file where that is not possible, or where only the file is
        to be locked); BlockingIOError if held."""
        dir_fd = None
        if self.whole_folder:
            try:
                dir_fd = os.open(self.out_dir, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
            except OSError:
                dir_fd = None
        if dir_fd is not None:
            try:
                fcntl.flock(dir_fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                return dir_fd, False
            except BlockingIOError:
                os.close(dir_fd)
                raise
            except OSError as exc:  # a file system that cannot lock a folder (some NFS)
                os.close(dir_fd)
                if exc.errno not in (errno.EBADF, errno.ENOLCK, errno.EINVAL, errno.EOPNOTSUPP):
                    raise
        fcntl.flock(info_fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return info_fd, True

    def check(self) -> None:
        """Where the lock file itself is the lock: LockLostError if it was removed or replaced."""
        if not self.on_file or self.fd is None:
            return
        try:
            stat = os.stat(self.out_dir / self.name, follow_symlinks=False)
            same = (stat.st_dev, stat.st_ino) == self.inode
        except OSError:
            same = False
        if not same:
            raise LockLostError(
                errno.ENOLCK,
                f"{self.out_dir / self.name} was removed or replaced while this run held it; another run "
                "may be writing here, so this one stops (re-run to resume once the folder is free)",
            )

    def release(self) -> None:
        if self.fd is not None:
            if not self.whole_folder and _same_file(self.out_dir / self.name, self.fd):
                with contextlib.suppress(OSError):
                    os.unlink(self.out_dir / self.name)  # still locked: a waiter re-checks its inode
            with contextlib.suppress(OSError):
                fcntl.flock(self.fd, fcntl.LOCK_UN)
            with contextlib.suppress(OSError):
                os.close(self.fd)
            self.fd = None


def _same_file(path: Path, fd: int) -> bool:
    """Is ``path`` (not followed) the file open as ``fd``?"""
    try:
        a, b = os.stat(path, follow_symlinks=False), os.fstat(fd)
    except OSError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def is_locked(out_dir: Path) -> bool:
    """A run holds ``out_dir`` right now (its folder or lock file is locked by another process)."""
    for path, flags in ((out_dir, os.O_RDONLY | os.O_DIRECTORY), (out_dir / LOCK_NAME, os.O_RDONLY)):
        try:
            fd = os.open(path, flags | os.O_CLOEXEC | os.O_NOFOLLOW)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return True
        except OSError:
            pass
        finally:
            os.close(fd)
    return False


def _read_holder(fd: int) -> str:
    try:
        info = json.loads(os.pread(fd, 4096, 0).decode())
        return f"pid {info['pid']} on {info['host']}, started {info['started']}: {info['command']}"
    except Exception:
        return "a process whose lock file says nothing: it may have been removed"


@contextlib.contextmanager
def sigint_deferred() -> Iterator[None]:
    """Hold back Ctrl-C (in the main thread) until the block is done, then raise it."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: received.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if received:
            raise KeyboardInterrupt
