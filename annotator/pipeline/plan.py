"""Which spans of candidates are still to simulate, generated lazily (memory independent of N);
the order they are handed out in is :mod:`annotator.pipeline.schedule`'s."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass

from annotator.objects import ObjectSource
from annotator.pipeline.tasks import GivenGrasps, Span

# Candidates per unit of work (and per chunk file): small enough that the first labels are on disk
# within seconds, that 2..64 workers stay balanced and that an interrupt loses little; large enough
# that the per-span overhead (a task, a chunk file, a manifest save) stays ~ 1 %.
CHUNK_SIZE = 10
# Chunks per object at most: for very large N the chunk grows so that the manifest (one entry
# per finished chunk of an unfinished object) and the planning stay small.
MAX_CHUNKS_PER_OBJECT = 2000
# Units whose first span a plan may hand out before the rest of a unit's spans (a plan that
# interleaves units so that workers start on different ones): few enough that a worker still holds
# a unit when it comes back for the rest of it. Objects no longer need it: each object's
# decomposition task runs ahead of its spans (annotator.pipeline.schedule).
FIRST_SPANS_AHEAD = 8
# Candidates per object at most: a worker holds an object's N candidates (~190 bytes each) and one
# object at 1e6 candidates is about 14 core-hours; more belongs in several runs (other seeds).
MAX_N = 1_000_000


def chunk_size_for(n: int) -> int:
    """Candidates per chunk for N candidates per object (CHUNK_SIZE unless N is very large)."""
    return max(CHUNK_SIZE, math.ceil(n / MAX_CHUNKS_PER_OBJECT))


@dataclass(frozen=True)
class PlannedObject:
    """An object of the run and the chunks of it already on disk, (start, stop) pairs.

    ``n``: its number of candidates when it has its own (given grasps), else the run's N;
    ``given``: where its spans' poses come from (a candidate source's ``given``), None when the
    workers sample them.
    """

    source: ObjectSource
    done: frozenset[tuple[int, int]] = frozenset()
    n: int | None = None
    given: Callable[[str, int, int], GivenGrasps | None] | None = None

    def count(self, n: int) -> int:
        return n if self.n is None else self.n

    def span(self, start: int, stop: int, scale: float | None) -> Span:
        oid = self.source.object_id
        given = self.given(oid, start, stop) if self.given is not None else None
        return Span(oid, self.source, scale, start, stop, given)


def _missing(obj: PlannedObject, n: int, chunk: int) -> Iterator[tuple[int, int]]:
    n = obj.count(n)
    for start in range(0, n, chunk):
        rng = (start, min(n, start + chunk))
        if rng not in obj.done:
            yield rng


def object_spans(obj: PlannedObject, n: int, chunk: int, scale: float | None) -> Iterator[Span]:
    """The spans of ``obj`` still to simulate, in order; lazy (memory independent of N)."""
    for rng in _missing(obj, n, chunk):
        yield obj.span(*rng, scale)


def spans_left(done: frozenset[tuple[int, int]], n: int, chunk: int) -> int:
    """How many spans of a unit of ``n`` candidates are missing when the chunks ``done`` (start,
    stop) are on disk (without listing them)."""
    total = math.ceil(n / chunk)
    return total - sum(1 for a, b in done if a % chunk == 0 and b == min(n, a + chunk))


def candidates_left(done: frozenset[tuple[int, int]], n: int, chunk: int) -> int:
    """How many candidates of a unit of ``n`` are missing when the chunks ``done`` are on disk."""
    return n - sum(b - a for a, b in done if a % chunk == 0 and b == min(n, a + chunk))


def spans_to_do(obj: PlannedObject, n: int, chunk: int) -> int:
    """How many spans of ``obj`` are missing (without listing them)."""
    return spans_left(obj.done, obj.count(n), chunk)


def candidates_to_do(obj: PlannedObject, n: int, chunk: int) -> int:
    """How many candidates of ``obj`` are missing."""
    return candidates_left(obj.done, obj.count(n), chunk)
