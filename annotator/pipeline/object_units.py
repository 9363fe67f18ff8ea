"""Jobs whose units of work are objects (``annotate``, ``annotator evaluate``): the main process
discovers the objects and their digests, binds the run and hands out each object's decomposition
task and then its label spans (:mod:`annotator.pipeline.schedule`); it never loads a mesh, so work
starts at once and every object's decomposition runs in a worker, in parallel with the others and
with the labelling. The jobs differ in where the candidates come from (sampled, given) and the
worker's mode (floating, cell, resting): :class:`ObjectUnitsJob` is their common part.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Any

from annotator.config import AnnotatorConfig
from annotator.grippers import GripperDescription, gripper_record, is_shipped
from annotator.objects import ObjectSource
from annotator.pipeline.execution import UsageError
from annotator.pipeline.inputs import digest_sources, discover, sent_gripper
from annotator.pipeline.lifecycle import Binding, Collector, TaskContext, WorkPlan, loaded_gripper
from annotator.pipeline.modes import FLOATING, Mode
from annotator.pipeline.options import RunOptions
from annotator.pipeline.plan import MAX_N, PlannedObject, candidates_to_do, chunk_size_for, spans_to_do
from annotator.pipeline.schedule import Schedule
from annotator.pipeline.source import GivenCandidates, SampledCandidates
from annotator.pipeline.summary import Summary
from annotator.pipeline.tasks import Prepare, Span, SpanResult, SpanTask
from annotator.pipeline.worker import label_span
from annotator.store import Resume, RunSpec, Store

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FoundInputs:
    """What an object job's :meth:`ObjectUnitsJob.bind` found: the run's ``options``, where the
    ``candidates`` come from, the ``gripper``, the objects (``sources``) and the digests of those
    that can be read."""

    options: RunOptions
    candidates: SampledCandidates | GivenCandidates
    gripper: GripperDescription
    sources: list[ObjectSource]
    digests: dict[str, str]


class ObjectUnitsJob:
    """A job over objects with ``candidates`` from a source (given, or None: ``n`` sampled per
    object), labelled in ``mode`` (:mod:`annotator.pipeline.modes`: floating, the robot cell,
    resting)."""

    unit = "object"
    noun = "candidates"
    worker = staticmethod(label_span)

    def __init__(
        self,
        config: AnnotatorConfig,
        candidates: SampledCandidates | GivenCandidates | None = None,
        *,
        mode: Mode = FLOATING,
    ) -> None:
        self.config = config
        self.given = candidates
        self.mode = mode
        self.inputs_found: FoundInputs | None = None  # bind() sets them
        self.fields: dict[str, Any] | None = None  # what every task carries, made once

    def source(self, n: int) -> SampledCandidates | GivenCandidates:
        """Where the candidates come from: the given ones, else ``n`` sampled per object."""
        return self.given if self.given is not None else SampledCandidates(n)

    # --- the job interface ---------------------------------------------------------------------------

    def check(self, options: RunOptions) -> None:
        if not 1 <= options.n <= MAX_N:
            raise UsageError(f"--n must be between 1 and {MAX_N:,} candidates per object, got {options.n}")
        if self.mode.unit != "object":
            raise UsageError(f"{self.mode.flags()} labels {self.mode.unit}s, not objects")
        if self.given is None and not self.mode.sampled:
            raise UsageError(f"{self.mode.flags()} simulates given grasps only")
        loaded_gripper(options.gripper)

    def bind(self, options: RunOptions, summary: Summary) -> Binding:
        candidates = self.source(options.n)
        gripper = loaded_gripper(options.gripper)
        sources, missing = candidates.select(discover(options, self.config))
        summary.failed.update(missing)
        digests, unreadable = digest_sources(sources, self.config)
        summary.failed.update(unreadable)
        self.inputs_found = FoundInputs(options, candidates, gripper, sources, digests)
        spec = RunSpec(
            options.seed,
            options.n,
            options.trials,
            options.scale,
            chunk_size_for(options.n),
            self.config.to_dict(trials=options.trials),
            inputs=self.inputs(candidates),
            gripper=gripper_record(gripper),
        )
        folder = None if is_shipped(gripper) else str(gripper.folder.resolve())
        return Binding(spec, digests, sorted(set(digests) | set(summary.failed)), folder)

    def inputs(self, candidates: SampledCandidates | GivenCandidates) -> dict[str, Any]:
        """RunSpec.inputs: the candidate source's, and what the mode binds (a floating run binds
        nothing, so folders made before the modes existed still resume; a folder of one mode never
        resumes as another)."""
        return {**candidates.inputs(), **self.mode.binds()}

    def plan(self, options: RunOptions, store: Store, resume: Resume) -> WorkPlan:
        found = self._found()
        digests, candidates = found.digests, found.candidates
        n, chunk = options.n, store.spec.chunk_size
        planned = [
            PlannedObject(
                s,
                frozenset(resume.chunks.get(s.object_id, set())),
                candidates.count(s.object_id),
                candidates.given,
            )
            for s in found.sources
            if s.object_id in digests and s.object_id not in resume.done
        ]
        remaining = {p.source.object_id: spans_to_do(p, n, chunk) for p in planned}
        todo = [p for p in planned if remaining[p.source.object_id] > 0]
        return WorkPlan(
            sum(candidates_to_do(p, n, chunk) for p in planned),
            len(planned),
            remaining,
            lambda workers: Schedule(todo, n, chunk, options.scale, workers),
            decompositions=len(todo),
            left={p.source.object_id: candidates_to_do(p, n, chunk) for p in todo},
            complete=[p.source.object_id for p in planned if remaining[p.source.object_id] == 0],
            kept=sum(len(p.done) for p in planned),
        )

    def make_task(self, unit: Span | Prepare, context: TaskContext) -> SpanTask:
        found = self._found()
        if self.fields is None:
            options = found.options
            self.fields = {
                "config": self.config,
                "seed": options.seed,
                "n": options.n,
                "trials": options.trials,
                "mode": self.mode,
                "gripper": sent_gripper(found.gripper, context),
                **context.fields(),
            }
        return SpanTask(span=unit, source_sha256=found.digests[unit.object_id], **self.fields)

    def _found(self) -> FoundInputs:
        if self.inputs_found is None:
            raise RuntimeError("the job's inputs are found by bind(), before it plans or makes tasks")
        return self.inputs_found

    def take(self, result: SpanResult, collector: Collector) -> None:
        oid = result.span.unit_id
        summary, progress = collector.summary, collector.progress
        collector.account(result)
        if oid in summary.failed:  # another task of it failed first: the object is failed
            return
        if result.error is not None:
            collector.fail(oid, result.error)
            progress.advance(collector.left.pop(oid, 0))
            if isinstance(result.span, Prepare):
                progress.prepared(oid, None)
            progress.object_done(oid, "failed")
        else:
            if isinstance(result.span, Prepare):
                self._prepared(oid, result, collector)
            span = result.labelled
            if span is not None and result.rows is not None:  # a span's labels (a decomposition's first)
                progress.advance(span.size)
                collector.left[oid] = collector.left.get(oid, 0) - span.size
                collector.write(result)

    def _prepared(self, oid: str, result: SpanResult, collector: Collector) -> None:
        summary, prepared = collector.summary, result.prepared
        summary.prepare_seconds += result.stats.seconds
        if result.rows is None:  # else the object's time comes with its labels (Collector.write)
            collector.seconds[oid] = collector.seconds.get(oid, 0.0) + result.stats.seconds
        if prepared is not None:
            summary.prepared[oid] = prepared
            if prepared.warnings:
                summary.warnings[oid] = list(prepared.warnings)
        summary.ready_seconds = time.perf_counter() - summary.started
        line = prepared.line() if prepared is not None and prepared.decomposed else None
        collector.progress.prepared(oid, line)
