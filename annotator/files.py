"""Files that appear whole or not at all: the one atomic write every package uses.

A file is written to a hidden temporary file beside it (``.<name>.<random>.tmp``, in the same
folder, so that the rename never crosses a filesystem), flushed and fsynced, given the usual
permissions (0666 minus the umask: ``mkstemp`` creates 0600, and datasets and caches are meant to
be shared), then renamed over ``path`` with :func:`os.replace`, and the folder is fsynced so that
the rename survives a power cut. A reader sees the old file or the new one, never a part; a crash
leaves at most a temporary file, whose name :func:`annotator.store.names.is_temp_name` and the
status folder's reader recognise and skip.

``durable=False`` skips both fsyncs, for files whose loss costs nothing (a worker's status line),
where an fsync per write would cost more than the file is worth.

This module depends on the standard library only: it is the lowest floor (docs/architecture.md,
"Floors"), so that ``objects``, ``cell``, ``store``, ``tools`` and the rest may all import it.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO

__all__ = ["atomic_write", "atomic_write_bytes", "atomic_write_path", "atomic_write_text", "probe_writable"]


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _current_umask()


def _fsync_dir(folder: Path) -> None:
    """Make a rename in ``folder`` durable (a no-op where folders cannot be opened)."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def atomic_write_path(
    path: Path | str,
    write: Callable[[Path], object],
    *,
    durable: bool = True,
    make_parents: bool = False,
) -> None:
    """Call ``write(tmp)`` to fill a temporary file, then rename it over ``path`` (see the module).

    For writers that open the file by name (h5py, ``DataFrame.to_parquet``). Any exception,
    ``OSError`` included, propagates unchanged after the temporary file is removed.
    ``make_parents``: create ``path``'s folder first.
    """
    path = Path(path)
    if make_parents:
        path.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        write(tmp)
        if durable:
            with open(tmp, "rb+") as fh:
                os.fsync(fh.fileno())  # on a shared filesystem the rename must not overtake the data
        os.chmod(tmp, 0o666 & ~_UMASK)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    if durable:
        _fsync_dir(path.parent)


def atomic_write(
    path: Path | str,
    write: Callable[[IO[bytes]], object],
    *,
    durable: bool = True,
    make_parents: bool = False,
) -> None:
    """Call ``write(fh)`` on a binary file handle of a temporary file, then rename it over ``path``."""

    def fill(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            write(fh)

    atomic_write_path(path, fill, durable=durable, make_parents=make_parents)


def atomic_write_bytes(
    path: Path | str, data: bytes, *, durable: bool = True, make_parents: bool = False
) -> None:
    """``data`` at ``path``, whole or not at all."""
    atomic_write(path, lambda fh: fh.write(data), durable=durable, make_parents=make_parents)


def atomic_write_text(
    path: Path | str, text: str, *, durable: bool = True, make_parents: bool = False
) -> None:
    """``text`` (UTF-8) at ``path``, whole or not at all."""
    atomic_write_bytes(path, text.encode("utf-8"), durable=durable, make_parents=make_parents)


def probe_writable(folder: Path | str) -> None:
    """Make ``folder`` (and its parents) if it is missing and check that a file can be created in
    it, leaving nothing behind; OSError (with the system's reason) otherwise."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    fd, probe = tempfile.mkstemp(prefix=".rg2-write-check-", dir=folder)
    os.close(fd)
    os.unlink(probe)
