"""The run's journal (``_journal.jsonl``): what changed since the manifest was last compacted.

The manifest (``_manifest.json``) holds the run's binding and its progress as of its last
compaction; every change since (a chunk recorded, an object merged or failed, what an object was
simulated as, a file the resume no longer trusts) is one line appended here, so a save costs what
changed, not what the folder holds. Compaction (:meth:`annotator.store.Store.compact`: when a run
opens a folder it has to clean up, and when it ends) writes the manifest whole again and starts
an empty journal.

Each line is ``<16 hex digits> <JSON object>``: the digits are the first 64 bits of the SHA-256 of
the JSON text, so a line cut short by a kill, a flipped byte or a garbage line is told from a
record. The first line names the journal (``{"op": "begin", "journal": <id>}``); the manifest
names the journal that continues it, so a journal a compaction has already folded in (a kill
between writing the manifest and starting the new journal) is never applied twice.

What a line means (the operations and their schema) is :mod:`annotator.store.manifest`'s; this
module only writes and reads lines.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import stat
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

from annotator.store.errors import ManifestUnreadableError
from annotator.store.files import atomic_write, output_error

# A line longer than this is not one the tool writes (the longest, the list of a run's objects,
# takes ~40 bytes an object).
MAX_LINE_BYTES = 1 << 28
_DIGITS = 16


def encode(op: dict[str, Any]) -> bytes:
    """One journal line: the checksum, a space, the compact JSON of ``op``, a newline."""
    text = json.dumps(op, sort_keys=True, separators=(",", ":"), ensure_ascii=False).encode("utf-8")
    return hashlib.sha256(text).hexdigest()[:_DIGITS].encode() + b" " + text + b"\n"


def decode(line: bytes) -> dict[str, Any] | None:
    """The operation of a whole line (its newline included), or None if the line does not verify:
    cut short, a checksum that does not match, not a JSON object."""
    if not line.endswith(b"\n") or len(line) < _DIGITS + 3 or line[_DIGITS : _DIGITS + 1] != b" ":
        return None
    text = line[_DIGITS + 1 : -1]
    if hashlib.sha256(text).hexdigest()[:_DIGITS].encode() != line[:_DIGITS]:
        return None
    try:
        op = json.loads(text.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError):
        return None
    return op if isinstance(op, dict) and isinstance(op.get("op"), str) else None


@dataclass
class JournalText:
    """A journal as read: its id (None if its first line does not verify), and each line after
    the first as (line number, operation or None where the line does not verify); ``last`` is the
    number of the file's last line."""

    journal_id: str | None
    lines: list[tuple[int, dict[str, Any] | None]]
    last: int


def _lines(fh: BinaryIO) -> Iterator[bytes]:
    while True:
        line = fh.readline(MAX_LINE_BYTES)
        if not line:
            return
        yield line


def read_journal(path: Path) -> JournalText | None:
    """Read the journal at ``path``; None if there is none; ManifestUnreadableError if it is not
    a regular file or cannot be read."""
    try:
        info = path.lstat()
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise ManifestUnreadableError(f"{path}: cannot be read ({exc.strerror or exc})") from exc
    if not stat.S_ISREG(info.st_mode):
        raise ManifestUnreadableError(f"{path} is not a regular file")
    journal_id: str | None = None
    lines: list[tuple[int, dict[str, Any] | None]] = []
    number = 0
    try:
        with open(path, "rb") as fh:
            for number, line in enumerate(_lines(fh), start=1):
                op = decode(line)
                if number == 1:
                    if op is not None and op["op"] == "begin" and isinstance(op.get("journal"), str):
                        journal_id = op["journal"]
                    else:
                        lines.append((number, None))
                    continue
                lines.append((number, op))
    except OSError as exc:
        raise ManifestUnreadableError(f"{path}: cannot be read ({exc.strerror or exc})") from exc
    return JournalText(journal_id, lines, number)


class JournalWriter:
    """Appends lines to a journal: :meth:`add` keeps them, :meth:`flush` writes them at the end of
    the file and fsyncs. A write that fails (a full disk) is cut back to the last whole line, so
    the lines appended later never follow half a line; the lines stay to be written again."""

    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            self.fd: int | None = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CLOEXEC | os.O_NOFOLLOW)
            self.size = os.fstat(self.fd).st_size
        except OSError as exc:
            raise output_error(path, exc) from exc
        self.pending: list[bytes] = []

    @classmethod
    def start(cls, path: Path, journal_id: str) -> JournalWriter:
        """Replace whatever journal is at ``path`` with an empty one named ``journal_id``."""
        line = encode({"op": "begin", "journal": journal_id})
        atomic_write(path, lambda fh: fh.write(line))
        return cls(path)

    def add(self, op: dict[str, Any]) -> bytes:
        """Keep ``op``'s line for the next flush; returns the line (for :meth:`withdraw`)."""
        line = encode(op)
        self.pending.append(line)
        return line

    def withdraw(self, line: bytes) -> None:
        """Forget a line not yet flushed (its change was undone)."""
        with contextlib.suppress(ValueError):
            self.pending.remove(line)

    def flush(self) -> None:
        """Write the lines added since the last flush and fsync (OutputError if the folder cannot
        be written)."""
        if not self.pending or self.fd is None:
            return
        data = b"".join(self.pending)
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(self.fd, view) :]
            os.fsync(self.fd)
        except OSError as exc:
            with contextlib.suppress(OSError):
                os.ftruncate(self.fd, self.size)
            raise output_error(self.path, exc) from exc
        self.size += len(data)
        self.pending.clear()

    def close(self) -> None:
        if self.fd is not None:
            with contextlib.suppress(OSError):
                os.close(self.fd)
            self.fd = None
