"""How a run shows its progress: a bar on a terminal, one line per finished object elsewhere.

A bar redraws itself in place with ``\\r``; written into a log file (a cluster job, ``> log 2>&1``)
that becomes thousands of updates on one line. So on a terminal the run draws tqdm's bar, and
when its output goes anywhere else it writes one line per finished or failed object instead.
"""

from __future__ import annotations

import sys
from typing import IO


class Progress:
    """``total`` candidates to do; ``objects`` objects they belong to. ``quiet``: show nothing."""

    def __init__(self, total: int, objects: int, *, quiet: bool, stream: IO[str] | None = None) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.quiet = quiet
        self.objects = objects
        self.finished = 0
        self.bar = None
        if not quiet and _is_terminal(self.stream):
            from tqdm.auto import tqdm

            self.bar = tqdm(total=total, unit="grasp", smoothing=0.1, dynamic_ncols=True, file=self.stream)

    def advance(self, candidates: int) -> None:
        if self.bar is not None:
            self.bar.update(candidates)

    def status(self, text: str) -> None:
        """What the workers are busy with (shown beside the bar; not logged line by line)."""
        if self.bar is not None:
            self.bar.set_postfix_str(text[:80], refresh=True)

    def object_done(self, object_id: str, text: str) -> None:
        """``object_id`` finished (``text``: its figures) or failed (``text``: its reason)."""
        self.finished += 1
        if self.bar is None and not self.quiet:
            print(f"[{self.finished}/{self.objects}] {object_id}: {text}", file=self.stream, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _is_terminal(stream: IO[str]) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):  # a closed or odd stream
        return False
