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
- an entry names what it is: it stores its key's inputs (:class:`EntryInputs`: the mesh's digest,
  the settings, the library versions), and a reader that finds other inputs than the key's (a
  valid entry copied under another object's name) treats it as missing too, and says so once;
- the multi-part ``.obj`` PyBullet loads is named by the hash of its own text, written from the
  entry that was read, so it always matches the parts the reader simulates.

Where the OS offers it, :func:`advisory_lock` lets one process compute a new entry while another
waits for it (to save the work, not for correctness); where locking fails it is skipped.

A cache that cannot be written (a cluster's shared cache mounted read-only, a folder of another
user) is read all the same: its entries are used as they are, and what it lacks (an entry, or
the ``.obj`` of a copied entry) is written to a folder private to this process instead
(:func:`write_here_or_aside`, :func:`private_folder`), said once in the log, and used from there:
the same bytes, so the same labels.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import hashlib
import json
import logging
import os
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

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


@dataclass(frozen=True)
class EntryInputs:
    """What an entry is made from: its key is the hash of these, and the entry stores them, so a
    reader checks that the entry it found is the one it asked for (a valid entry copied under
    another object's key is a miss, never used)."""

    version: int  # CACHE_VERSION
    method: str  # "hull", "shells" or "coacd" (the ladder)
    arrays: tuple[str, ...]  # per input array: dtype, shape and SHA-256 of its little-endian bytes
    settings: str  # repr of every setting that shapes the result (cleaning, the ladder, the error)
    libraries: tuple[tuple[str, str], ...]  # (distribution, version), sorted

    def text(self) -> str:
        """The canonical JSON an entry stores."""
        return json.dumps(dataclasses.asdict(self), sort_keys=True)

    @property
    def key(self) -> str:
        """The entry's name: 32 hex digits of the SHA-256 of :meth:`text`."""
        return hashlib.sha256(self.text().encode()).hexdigest()[:32]

    def differences(self, stored: str) -> list[str]:
        """The fields in which an entry's stored inputs (``stored``, its :meth:`text`) differ."""
        try:
            other = json.loads(stored)
        except ValueError:
            return ["unreadable inputs"]
        mine = json.loads(self.text())
        if not isinstance(other, dict):
            return ["unreadable inputs"]
        return [name for name in mine if other.get(name) != mine[name]] or ["inputs"]


def _array_digest(a: np.ndarray) -> str:
    a = np.ascontiguousarray(a)
    a = a.astype(a.dtype.newbyteorder("<"), copy=False)
    return f"{a.dtype.str}{a.shape} {hashlib.sha256(a.tobytes()).hexdigest()}"


def entry_inputs(method: str, arrays: list[np.ndarray], settings: tuple) -> EntryInputs:
    """What makes an entry: the cache version, the method, the bytes of ``arrays`` (the cleaned,
    scaled mesh's vertices and faces, little-endian, with their shapes), the ``settings`` that shape
    the result and the versions of :data:`annotator.versions.LABEL_LIBRARIES`."""
    return EntryInputs(
        CACHE_VERSION,
        method,
        tuple(_array_digest(a) for a in arrays),
        repr(settings),
        tuple(sorted(label_versions.library_versions().items())),
    )


def entry_key(method: str, arrays: list[np.ndarray], settings: tuple) -> str:
    """Hex key of an entry: the hash of its :func:`entry_inputs`."""
    return entry_inputs(method, arrays, settings).key


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


INPUTS = "inputs"  # the array of an entry that holds its EntryInputs.text()


def save_arrays(path: Path, arrays: dict[str, np.ndarray], inputs: EntryInputs | None = None) -> None:
    """``arrays`` as an ``.npz`` entry with their checksum, written atomically; with ``inputs``,
    the entry names what it was made from (checked by :func:`load_arrays`, covered by the checksum)."""
    import io

    payload: dict[str, Any] = dict(arrays)
    if inputs is not None:
        payload[INPUTS] = np.array(inputs.text())
    buffer = io.BytesIO()
    np.savez(buffer, checksum=np.array(_checksum(payload)), **payload)
    write_atomic(path, buffer.getvalue())


class CorruptEntry(ValueError):
    """An entry that cannot be read or whose checksum does not match: treat it as missing."""


class ForeignEntry(CorruptEntry):
    """A whole entry made from other inputs than the key's (copied or written under another
    object's name): treat it as missing."""


def load_arrays(path: Path, inputs: EntryInputs | None = None) -> dict[str, np.ndarray]:
    """The arrays of an entry written by :func:`save_arrays`, verified; :class:`CorruptEntry`
    for a truncated, corrupt or foreign file, :class:`ForeignEntry` when ``inputs`` are given and
    the entry does not name the same, FileNotFoundError when there is none."""
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
    named = arrays.pop(INPUTS, None)
    if inputs is not None:
        if named is None:
            raise ForeignEntry("the entry does not name its inputs")
        if str(named) != inputs.text():
            differ = ", ".join(inputs.differences(str(named)))
            raise ForeignEntry(f"made from other inputs (its {differ} differ)")
    return arrays


def write_obj(folder: Path, key: str, text: str) -> Path:
    """``text`` at ``folder/<key>.<hash of text>.obj`` unless that file already holds it (in a
    cache that cannot be written: aside, :func:`write_here_or_aside`)."""
    data = text.encode()
    name = f"{key}.{hashlib.sha256(data).hexdigest()[:16]}.obj"
    path = Path(folder) / name
    try:
        if path.stat().st_size == len(data) and path.read_bytes() == data:
            return path
    except OSError:
        pass
    return write_here_or_aside(path, lambda target: write_atomic(target, data))


# errno values that mean "this folder cannot be written" (not a fault of the entry)
UNWRITABLE = (errno.EROFS, errno.EACCES, errno.EPERM)
_PRIVATE: list[Path] = []  # this process's folder for what a read-only cache lacks
_SAID: set[str] = set()  # read-only caches already reported by this process


def private_folder() -> Path:
    """A folder of this process for entries a read-only cache lacks (made once, under the
    system's temporary folder; removed when the process ends)."""
    if not _PRIVATE:
        import atexit
        import shutil

        folder = Path(tempfile.mkdtemp(prefix="rg2-annotator-cache-"))
        atexit.register(shutil.rmtree, folder, True)
        _PRIVATE.append(folder)
    return _PRIVATE[0]


def write_here_or_aside(path: Path, write: Callable[[Path], object]) -> Path:
    """``write(path)``; where ``path``'s folder cannot be written (:data:`UNWRITABLE`), the same
    file in :func:`private_folder` instead, said once per folder. Returns where it went."""
    try:
        write(path)
        return path
    except OSError as exc:
        if exc.errno not in UNWRITABLE:
            raise
        folder = str(path.parent)
        if folder not in _SAID:
            _SAID.add(folder)
            log.warning(
                "the decomposition cache %s cannot be written (%s): its entries are read; what it lacks "
                "is kept for this process only",
                folder,
                exc.strerror or exc,
            )
    aside = private_folder() / path.name
    write(aside)
    return aside


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
