"""The order work reaches the workers: each object's decomposition task, then its label spans.

Every object of a run gets one decomposition task (:class:`~annotator.pipeline.tasks.Prepare`):
a worker loads it, making its collision shape (a concave object's convex decomposition, up to a
minute of a reference machine's CPU) and writing it to the cache unless the cache holds it
already, then labels the object's first span (an object of one span costs one task and one load).
None of an object's other label spans is handed out before that task has finished, so no worker
decomposes an object that another is decomposing, and no worker waits for one. The main process
never loads an object.

What a free worker gets, in this order of preference:

1. while objects wait for their decomposition and none is running, there is more than one
   worker and fewer ready objects than workers have no span started yet: the next decomposition
   (one worker keeps decomposing alongside the labelling, so the decompositions do not all wait
   for the end, but no further ahead of it than one object per worker);
2. a label span (after the first) of the first object in plan order whose decomposition has
   finished;
3. the next decomposition, when no span can start (at most one per worker at a time).

So at the start every worker decomposes a different object (the objects the first spans need
first, in plan order); as soon as the first object is ready its spans start, while the other
decompositions go on. The limit in 1. is for a warm cache, where a decomposition task only reads
its object (a fraction of a CPU-second): without it one worker ran through every object's task
ahead of the labelling, and a worker keeps only so many objects
(:data:`~annotator.pipeline.object_cache.RECENT_OBJECT_BYTES`), so the labelling loaded most of them
again. Spans are generated lazily per object (memory independent of N); an object that fails
(its decomposition or a span) hands out nothing more.
"""

from __future__ import annotations

import bisect
from collections import deque
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

from annotator.pipeline.plan import PlannedObject, object_spans
from annotator.pipeline.tasks import Prepare, Span, SpanResult


@dataclass(order=True)
class _Ready:
    """An object whose decomposition finished: its index in the plan, its next span and the rest."""

    index: int
    head: Span = field(compare=False)
    rest: Iterator[Span] = field(compare=False)
    started: bool = field(default=False, compare=False)  # a span of it handed out


@dataclass
class Schedule:
    """Decomposition tasks and label spans of ``objects`` (in plan order) for ``workers`` workers.

    ``n``, ``chunk``, ``scale``: the run's candidates per object, candidates per span and scale.
    :meth:`next` gives the next unit to submit (None: nothing can start now), :meth:`record` is told
    every result, :attr:`exhausted` says when nothing is left to hand out.
    """

    objects: Sequence[PlannedObject]
    n: int
    chunk: int
    scale: float | None
    workers: int
    waiting: deque[int] = field(init=False)  # objects whose decomposition is not handed out yet
    preparing: set[str] = field(default_factory=set)  # decompositions out
    ready: list[_Ready] = field(default_factory=list)  # in plan order
    failed: set[str] = field(default_factory=set)
    # the spans after the first of each decomposition out (the task labels its first)
    pending: dict[str, Iterator[Span]] = field(default_factory=dict)
    _index: dict[str, int] = field(init=False)

    def __post_init__(self) -> None:
        self.waiting = deque(range(len(self.objects)))
        self._index = {o.source.object_id: i for i, o in enumerate(self.objects)}

    @property
    def exhausted(self) -> bool:
        return not self.waiting and not self.preparing and not self.ready

    def next(self) -> Prepare | Span | None:
        """The next unit to submit, or None when nothing can start until a result comes back."""
        if self.waiting and not self.preparing and self.workers > 1 and self._ahead() < self.workers:
            return self._prepare()  # one worker keeps decomposing alongside the labelling
        span = self._span()
        if span is not None:
            return span
        if self.waiting and len(self.preparing) < self.workers:
            return self._prepare()
        return None

    def record(self, result: SpanResult) -> None:
        """A unit's result: a finished decomposition opens its object's spans; an error closes them."""
        unit = result.span
        oid = unit.unit_id
        if isinstance(unit, Prepare):
            self.preparing.discard(oid)
            spans = self.pending.pop(oid, iter(()))
            if result.error is None and oid not in self.failed:
                head = next(spans, None)
                if head is not None:
                    bisect.insort(self.ready, _Ready(self._index[oid], head, spans))
        if result.error is not None:
            self.failed.add(oid)
            self.ready = [r for r in self.ready if r.index != self._index.get(oid)]

    def _ahead(self) -> int:
        """Ready objects none of whose spans has been handed out yet."""
        return sum(1 for r in self.ready if not r.started)

    def _prepare(self) -> Prepare:
        obj = self.objects[self.waiting.popleft()]
        oid = obj.source.object_id
        spans = object_spans(obj, self.n, self.chunk, self.scale)
        self.preparing.add(oid)
        self.pending[oid] = spans
        return Prepare(oid, obj.source, self.scale, next(spans, None))

    def _span(self) -> Span | None:
        if not self.ready:
            return None
        first = self.ready[0]
        first.started = True
        span, following = first.head, next(first.rest, None)
        if following is None:
            self.ready.pop(0)
        else:
            first.head = following
        return span


class Stream:
    """Units handed out in the order of an iterator, none waiting for another (a plain list of
    spans, as a bench or a test gives :func:`annotator.pipeline.run.execute`)."""

    def __init__(self, units: Iterator[Prepare | Span]) -> None:
        self._units = iter(units)
        self._head: Prepare | Span | None = next(self._units, None)

    @property
    def exhausted(self) -> bool:
        return self._head is None

    def next(self) -> Prepare | Span | None:
        unit, self._head = self._head, next(self._units, None)
        return unit

    def record(self, result: SpanResult) -> None:
        """Nothing waits for a result."""
