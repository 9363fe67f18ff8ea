"""The one way a tool writes a file it was asked for (a model, a picture, a page, a table, a
configuration): :class:`Outputs`.

A command names its output files up front (``{"--out": path, ...}``) and claims them before any
work (:meth:`Outputs.claim`):

- two options naming one file (``--reliability`` = ``--write-config``) are refused: one output
  would silently replace the other;
- each file's folder must take a file (:class:`OutputError`, exit 3, otherwise);
- each file is locked for the command's whole life with the store's lock
  (:class:`annotator.store.lock.RunLock` on a lock file of its own beside it,
  ``.<name>.rg2-annotator.lock``, removed at the end): a second command writing the same file is
  refused naming the first;
- an existing file is replaced only when this tool wrote it and nobody changed it since: every
  file written here gets a mark beside it (``.<name>.rg2-annotator``, JSON: the SHA-256 and size
  of what was written, the command, when). A file without a mark, or whose content is no longer
  the marked digest (edited, or replaced by another program), is refused unless the command was
  given ``--overwrite``.

:meth:`Outputs.write` then writes a file whole or not at all (:func:`annotator.files.
atomic_write_path`: a temporary file beside it, renamed over it): a full disk or a read-only
folder leaves the previous file as it was and no part of the new one (:class:`OutputError` naming
the file and the system's reason). A file changed by someone else while the command ran is not
replaced: the output goes beside it (``<stem>.new<suffix>``) and the caller is told where.

``mark=False``: the files are written without a mark beside them, for a folder that keeps its
own record of what it wrote (an export's ``_export.json``, whose readers list the folder): the
caller checks what lies there and records each file's digest (:meth:`Outputs.digest`).
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import logging
import os
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

from annotator import files
from annotator.store.errors import StoreError
from annotator.store.files import OutputError, output_error
from annotator.store.lock import RunLock

log = logging.getLogger(__name__)

MARK_FORMAT = "rg2-annotator output 1"


class OutputRefusedError(StoreError):
    """An output the command must not write (another option's file, a user's file, one edited
    since the tool wrote it): a usage error, exit code 2, one line."""


def mark_path(path: Path) -> Path:
    """Where the mark of output ``path`` lives: ``.<name>.rg2-annotator`` beside it."""
    return path.parent / f".{path.name}.rg2-annotator"


def lock_name(path: Path) -> str:
    """The name of the lock file of output ``path`` in its folder."""
    return f".{path.name}.rg2-annotator.lock"


def file_sha256(path: Path) -> str:
    """SHA-256 of the file at ``path`` (hex), read in blocks."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def read_mark(path: Path) -> dict | None:
    """The mark of output ``path`` (a dict with ``sha256``), or None when it has none or an
    unreadable one."""
    try:
        mark = json.loads(mark_path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if (
        not isinstance(mark, dict)
        or mark.get("format") != MARK_FORMAT
        or not isinstance(mark.get("sha256"), str)
    ):
        return None
    return mark


def written_here(path: Path) -> bool:
    """Is ``path`` a file this tool wrote and nobody changed since (its mark's digest is its own)?"""
    mark = read_mark(path)
    try:
        return mark is not None and mark["sha256"] == file_sha256(path)
    except OSError:
        return False


def _state(path: Path) -> str | None:
    """What is at ``path`` now: None (nothing) or its SHA-256; a folder or another non-file is
    refused by the caller before."""
    try:
        return file_sha256(path)
    except FileNotFoundError:
        return None


@dataclass
class _Claimed:
    option: str
    path: Path
    lock: RunLock
    found: str | None  # the SHA-256 of the file at claim time (None: there was none)


_Outputs = TypeVar("_Outputs", bound="Outputs")


@dataclass
class Outputs:
    """The output files of one command, claimed (module docstring); :meth:`write` each, then
    :meth:`release` (or use it as a context manager)."""

    command: str
    claimed: dict[str, _Claimed] = field(default_factory=dict)
    mark: bool = True  # a mark beside each file written (module docstring)
    digests: dict[Path, str] = field(default_factory=dict)  # what was written where

    @classmethod
    def claim(
        cls: type[_Outputs],
        command: str,
        paths: Mapping[str, Path | str | None],
        *,
        overwrite: bool = False,
        overwrite_option: str = "--overwrite",
        mark: bool = True,
    ) -> _Outputs:
        """Claim ``paths`` (option -> file; None: not asked for) for ``command``: refused with
        :class:`OutputRefusedError` or :class:`annotator.store.LockedError` (usage, one line) or
        :class:`OutputError` (a folder that cannot take the file); nothing is written.
        ``mark``: mark each file written (module docstring)."""
        outputs = cls(command, mark=mark)
        asked = {option: Path(p) for option, p in paths.items() if p is not None}
        seen: dict[Path, str] = {}
        for option, path in asked.items():
            real = Path(os.path.realpath(path))
            if real in seen:
                raise OutputRefusedError(
                    f"{seen[real]} and {option} name the same file {path}: give each its own, or one "
                    "would replace the other"
                )
            seen[real] = option
        try:
            for option, path in asked.items():
                outputs.claimed[option] = _claim_one(option, path, overwrite, overwrite_option)
        except BaseException:
            outputs.release()
            raise
        return outputs

    def path(self, option: str) -> Path:
        """The file claimed for ``option``."""
        return self.claimed[option].path

    def write(self, option: str, fill: Callable[[Path], object]) -> Path:
        """Write the output of ``option``: ``fill(tmp)`` fills a temporary file beside it, which is
        renamed over it and marked. Returns where it went: its path, or ``<stem>.new<suffix>`` beside
        it when its file was changed by someone else since the claim (then logged).
        :class:`OutputError` (exit 3) when the file cannot be written; the file that was there is
        untouched."""
        claimed = self.claimed[option]
        target = claimed.path
        try:
            changed = _state(target) != claimed.found
        except OSError as exc:
            raise output_error(target, exc) from exc
        if changed:
            target = _beside(target)
            log.warning(
                "%s changed while this command ran: not replaced; wrote %s",
                named(option, claimed.path),
                target,
            )
        digest: list[str] = []

        def fill_and_hash(tmp: Path) -> None:
            fill(tmp)
            digest.append(file_sha256(tmp))

        try:
            files.atomic_write_path(target, fill_and_hash)
            if self.mark:
                _write_mark(target, digest[0], self.command)
        except OSError as exc:
            raise output_error(target, exc) from exc
        if target == claimed.path:
            claimed.found = digest[0]
        self.digests[target] = digest[0]
        return target

    def digest(self, path: Path) -> str:
        """The SHA-256 of what :meth:`write` wrote at ``path`` (where it returned)."""
        return self.digests[Path(path)]

    def write_bytes(self, option: str, data: bytes) -> Path:
        """:meth:`write` of ``data``."""
        return self.write(option, lambda tmp: tmp.write_bytes(data))

    def write_text(self, option: str, text: str) -> Path:
        """:meth:`write` of ``text`` (UTF-8)."""
        return self.write(option, lambda tmp: tmp.write_text(text, encoding="utf-8"))

    def release(self) -> None:
        """Unlock every claimed file (their lock files go)."""
        for claimed in self.claimed.values():
            claimed.lock.release()

    def __enter__(self: _Outputs) -> _Outputs:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def named(option: str, path: Path | str) -> str:
    """How a message names an output: ``--png sheet.png``; an output that is no option of its own
    (a file of an output folder, keyed by its name) by its path alone."""
    return f"{option} {path}" if option.startswith("-") else str(path)


def _claim_one(option: str, path: Path, overwrite: bool, overwrite_option: str) -> _Claimed:
    name = named(option, path)
    if path.is_dir():
        raise OutputError(21, f"{name} is a folder; give a file name")
    folder = path.parent if str(path.parent) else Path(".")
    try:
        files.probe_writable(folder)
    except OSError as exc:
        raise OutputError(
            exc.errno or 5, f"{option} {folder} cannot be written: {exc.strerror or exc}"
        ) from None
    lock = RunLock(folder, name=lock_name(path), whole_folder=False, subject=name)
    lock.acquire()
    try:
        if path.exists() and not path.is_file():
            raise OutputRefusedError(f"{name} exists and is not a regular file")
        found = _state(path)
        if found is not None and not overwrite:
            mark = read_mark(path)
            if mark is None:
                raise OutputRefusedError(
                    f"{name} exists and was not written by this tool; pass {overwrite_option} to replace it"
                )
            if mark["sha256"] != found:
                raise OutputRefusedError(
                    f"{name} was written by this tool ({mark.get('written', 'earlier')}) and has "
                    f"changed since; pass {overwrite_option} to replace it"
                )
    except OSError as exc:
        lock.release()
        raise output_error(path, exc) from exc
    except BaseException:
        lock.release()
        raise
    return _Claimed(option, path, lock, found)


def _beside(path: Path) -> Path:
    """A free name beside ``path``: ``<stem>.new<suffix>``, then ``<stem>.new2<suffix>``, ..."""
    for k in range(1, 1000):
        candidate = path.with_name(f"{path.stem}.new{'' if k == 1 else k}{path.suffix}")
        if not candidate.exists():
            return candidate
    raise OSError(17, f"no free name beside {path}")


def _write_mark(path: Path, sha256: str, command: str) -> None:
    mark = {
        "format": MARK_FORMAT,
        "file": path.name,
        "sha256": sha256,
        "bytes": path.stat().st_size,
        "command": command,
        "argv": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]])[:300],
        "written": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
    }
    files.atomic_write_text(mark_path(path), json.dumps(mark, indent=1) + "\n")
