"""The folder a run shares with its local workers: what each is doing, and a request to stop.

A worker writes one short line (``loading mug``) into ``<dir>/<pid>``; the main process reads the
folder while it waits. Best effort: a status that cannot be written or read is simply not shown.
When the run is interrupted the main process writes ``<dir>/stop`` (:func:`request_stop`); each
worker's watcher thread sees it and ends its process (:func:`stop_requested`).
"""

from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path

from annotator.files import atomic_write_text


def write(folder: str | None, text: str | None) -> None:
    """Say what this process is doing (``None``: nothing worth showing)."""
    if folder is None:
        return
    path = Path(folder) / str(os.getpid())
    with contextlib.suppress(OSError):
        if text is None:
            path.unlink(missing_ok=True)
        else:
            atomic_write_text(path, f"{time.time():.1f} {text}", durable=False)


STOP_NAME = "stop"


def request_stop(folder: str | Path | None) -> None:
    """Ask the run's local workers to end now (the run was interrupted)."""
    if folder is not None:
        with contextlib.suppress(OSError):
            (Path(folder) / STOP_NAME).touch()


def stop_requested(folder: str | Path | None) -> bool:
    return folder is not None and (Path(folder) / STOP_NAME).exists()


def read(folder: str | Path | None, older_than: float = 0.0) -> list[str]:
    """Current statuses older than ``older_than`` seconds, as ``text (12 s)``, sorted."""
    if folder is None:
        return []
    now, out = time.time(), []
    with contextlib.suppress(OSError):
        for path in Path(folder).iterdir():
            if path.suffix == ".tmp" or path.name == STOP_NAME:
                continue
            with contextlib.suppress(OSError, ValueError):
                since, text = path.read_text().split(" ", 1)
                age = now - float(since)
                if age >= older_than:
                    out.append(f"{text} ({age:.0f} s)")
    return sorted(out)
