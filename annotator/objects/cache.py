"""The decomposition cache: content-addressed entries, safe for several processes and machines.

An entry's name is :func:`entry_key`: a hash of what shapes the result (the cleaned mesh's bytes,
every setting the method reads, the versions of the libraries that compute it), so an entry is
never stale and one folder can be shared by any number of runs, users and machines (a shared
filesystem for a cluster). No lock is needed for correctness, because flock does not work on
every shared filesystem:

- writes are atomic: an entry is written to a temporary file in the same folder and renamed over
  its name (POSIX rename), so a reader sees a whole entry or none; two writers of one entry both
  succeed and one of their files stays, each valid;
- reads are verified: an entry carries the SHA-256 of its payload and a reader that finds a
  truncated, corrupt or foreign file treats it as missing (it is recomputed and replaced);
- the multi-part ``.obj`` PyBullet loads is named by the hash of its own text, written from the
  entry that was read, so it always matches the parts the reader simulates.

Where the OS offers it, :func:`advisory_lock` lets one process compute a new entry while another
waits for it (to save the work, not for correctness); where locking fails it is skipped.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from annotator import versions as label_versions
from annotator.files import atomic_write_bytes

log = logging.getLogger(__name__)

# Bump when an entry's content changes meaning (it is part of every key). 5: the libraries are
# annotator.versions.LABEL_LIBRARIES (pymeshfix and manifold3d added, which shape the cleaned mesh).
CACHE_VERSION = 5


def default_cache_dir() -> Path:
    """``$RG2_CACHE_DIR`` if set, else ``~/.cache/rg2-annotator``."""
    env = os.environ.get("RG2_CACHE_DIR")
    return Path(env) if env else Path.home() / ".cache" / "rg2-annotator"


def entry_key(method: str, arrays: list[np.ndarray], settings: tuple) -> str:
    """Hex key of an entry: the cache version, the method, the bytes of ``arrays`` (little-endian,
    with their shapes), the ``settings`` that shape the result and the versions of
    :data:`annotator.versions.LABEL_LIBRARIES`."""
    h = hashlib.sha256(f"rg2-annotator collision v{CACHE_VERSION}\0{method}\0".encode())
    for a in arrays:
        a = np.ascontiguousarray(a)
        a = a.astype(a.dtype.newbyteorder("<"), copy=False)
        h.update(f"{a.dtype.str}{a.shape}\0".encode())
        h.update(a.tobytes())
    h.update(repr(settings).encode())
    h.update(repr(sorted(label_versions.library_versions().items())).encode())
    return h.hexdigest()[:32]


def _checksum(arrays: dict[str, np.ndarray]) -> str:
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.asarray(arrays[name])
        h.update(f"{name}\0{a.dtype.str}\0{a.shape}\0".encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def write_atomic(path: Path, data: bytes) -> None:
    """``data`` at ``path`` via a temporary file in the same folder and a rename."""
    atomic_write_bytes(path, data, make_parents=True)


def save_arrays(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """``arrays`` as an ``.npz`` entry with their checksum, written atomically."""
    import io

    buffer = io.BytesIO()
    np.savez(buffer, checksum=np.array(_checksum(arrays)), **arrays)
    write_atomic(path, buffer.getvalue())


class CorruptEntry(ValueError):
    """An entry that cannot be read or whose checksum does not match: treat it as missing."""


def load_arrays(path: Path) -> dict[str, np.ndarray]:
    """The arrays of an entry written by :func:`save_arrays`, verified; :class:`CorruptEntry`
    for a truncated, corrupt or foreign file, FileNotFoundError when there is none."""
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {name: z[name] for name in z.files}
    except FileNotFoundError:
        raise
    except Exception as exc:  # zipfile, numpy and OS errors of a damaged file: many types
        raise CorruptEntry(f"{type(exc).__name__}: {exc}") from None
    stored = arrays.pop("checksum", None)
    if stored is None or str(stored) != _checksum(arrays):
        raise CorruptEntry("checksum mismatch")
    return arrays


def write_obj(folder: Path, key: str, text: str) -> Path:
    """``text`` at ``folder/<key>.<hash of text>.obj`` unless that file already holds it."""
    data = text.encode()
    path = Path(folder) / f"{key}.{hashlib.sha256(data).hexdigest()[:16]}.obj"
    try:
        if path.stat().st_size == len(data) and path.read_bytes() == data:
            return path
    except OSError:
        pass
    write_atomic(path, data)
    return path


@contextlib.contextmanager
def advisory_lock(path: Path) -> Iterator[bool]:
    """Hold an exclusive OS lock on ``path`` if the filesystem offers one; yields whether it is held.

    Only saves work (a second process waits for the first one's entry instead of computing it
    too); correctness never depends on it, so any failure to lock is skipped.
    """
    try:
        import fcntl

        path.parent.mkdir(parents=True, exist_ok=True)
        fh = open(path, "a+b")  # closed in the finally below
    except (ImportError, OSError):
        yield False
        return
    try:
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX)
            held = True
        except OSError as exc:  # e.g. a filesystem without locks (ENOLCK)
            log.debug("no lock on %s (%s): computing without it", path, exc)
            held = False
        yield held
    finally:
        fh.close()  # releases the lock
