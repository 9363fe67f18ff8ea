"""What local workers are doing right now, for the progress display (a file per worker process).

A worker writes one short line (``loading mug``) into ``<dir>/<pid>``; the main process reads the
folder while it waits. Best effort: a status that cannot be written or read is simply not shown.
"""

from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path


def write(folder: str | None, text: str | None) -> None:
    """Say what this process is doing (``None``: nothing worth showing)."""
    if folder is None:
        return
    path = Path(folder) / str(os.getpid())
    with contextlib.suppress(OSError):
        if text is None:
            path.unlink(missing_ok=True)
        else:
            tmp = path.with_suffix(".tmp")
            tmp.write_text(f"{time.time():.1f} {text}")
            os.replace(tmp, path)


def read(folder: str | Path | None, older_than: float = 0.0) -> list[str]:
    """Current statuses older than ``older_than`` seconds, as ``text (12 s)``, sorted."""
    if folder is None:
        return []
    now, out = time.time(), []
    with contextlib.suppress(OSError):
        for path in Path(folder).iterdir():
            if path.suffix == ".tmp":
                continue
            with contextlib.suppress(OSError, ValueError):
                since, text = path.read_text().split(" ", 1)
                age = now - float(since)
                if age >= older_than:
                    out.append(f"{text} ({age:.0f} s)")
    return sorted(out)
