"""How a run shows its progress: a bar on a terminal, one line per finished object elsewhere.

A bar redraws itself in place with ``\\r``; written into a log file (a cluster job, ``> log 2>&1``)
that becomes thousands of updates on one line. So on a terminal the run draws tqdm's bar, and
when its output goes anywhere else it writes one line per finished or failed object instead.

The decomposition stage has its own count: the bar's label says ``decomposing 3/16`` until every
object's decomposition task has finished; elsewhere each object the run decomposed is one line
with its method and CPU seconds (objects whose collision shape came from the cache, or that are
convex, are not listed).
"""

from __future__ import annotations

import sys
from typing import IO, TYPE_CHECKING

if TYPE_CHECKING:
    from tqdm.auto import tqdm


class Progress:
    """``total`` candidates to do; ``objects`` objects they belong to; ``decompositions``: objects
    whose decomposition task runs first. ``quiet``: show nothing."""

    def __init__(
        self,
        total: int,
        objects: int,
        *,
        quiet: bool,
        stream: IO[str] | None = None,
        decompositions: int = 0,
    ) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.quiet = quiet
        self.objects = objects
        self.finished = 0
        self.decompositions = decompositions
        self.ready = 0  # decomposition tasks finished
        self.bar = None
        if not quiet and _is_terminal(self.stream):
            from tqdm.auto import tqdm

            self.bar = tqdm(total=total, unit="grasp", smoothing=0.1, dynamic_ncols=True, file=self.stream)
            self._stage(self.bar)

    def advance(self, candidates: int) -> None:
        if self.bar is not None and candidates:
            self.bar.update(candidates)

    def status(self, text: str) -> None:
        """What the workers are busy with (shown beside the bar; not logged line by line)."""
        if self.bar is not None:
            self.bar.set_postfix_str(text[:80], refresh=True)

    def prepared(self, object_id: str, text: str | None) -> None:
        """``object_id``'s decomposition task finished; ``text``: how it was decomposed (None: it
        was not, or it failed; the failure is its object's line)."""
        self.ready += 1
        if self.bar is not None:
            self._stage(self.bar)
        elif text is not None and not self.quiet:
            print(
                f"[decomposed, {self.ready}/{self.decompositions} objects ready] {object_id}: {text}",
                file=self.stream,
                flush=True,
            )

    def object_done(self, object_id: str, text: str) -> None:
        """``object_id`` finished (``text``: its figures) or failed (``text``: its reason)."""
        self.finished += 1
        if self.bar is None and not self.quiet:
            print(f"[{self.finished}/{self.objects}] {object_id}: {text}", file=self.stream, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()

    def _stage(self, bar: tqdm) -> None:
        """``bar``'s label: the decomposition stage's count while it lasts."""
        if self.ready < self.decompositions:
            bar.set_description_str(f"decomposing {self.ready}/{self.decompositions}", refresh=True)
        else:
            bar.set_description_str("", refresh=True)


def _is_terminal(stream: IO[str]) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):  # a closed or odd stream
        return False
