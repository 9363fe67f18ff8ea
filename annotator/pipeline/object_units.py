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
from typing import Any

from annotator.config import AnnotatorConfig
from annotator.grippers import (
    DescriptionError,
    GripperDescription,
    GripperFiles,
    gripper_record,
    is_shipped,
)
from annotator.objects import ObjectDiscoveryError, ObjectError, ObjectSource, discover_objects, source_digest
from annotator.pipeline.execution import UsageError
from annotator.pipeline.lifecycle import Collector, TaskContext, WorkPlan, loaded_gripper, merged, resumed
from annotator.pipeline.options import RunOptions
from annotator.pipeline.plan import MAX_N, PlannedObject, candidates_to_do, chunk_size_for, spans_to_do
from annotator.pipeline.schedule import Schedule
from annotator.pipeline.source import GivenCandidates, SampledCandidates
from annotator.pipeline.summary import Summary
from annotator.pipeline.tasks import CellOptions, Prepare, Span, SpanResult, SpanTask
from annotator.pipeline.worker import label_span
from annotator.store import Resume, RunSpec, Store

log = logging.getLogger(__name__)


def _gripper_files(gripper: GripperDescription) -> GripperFiles:
    try:
        return GripperFiles.of(gripper)
    except DescriptionError as exc:
        raise UsageError(f"--gripper: {exc}") from exc


class ObjectUnitsJob:
    """A job over objects with ``candidates`` from a source (given, or None: ``n`` sampled per
    object), in the worker mode
    ``cell`` (the robot cell, None: not) or ``resting`` (False, True/"object", "table")."""

    unit = "object"
    noun = "candidates"
    worker = staticmethod(label_span)

    def __init__(
        self,
        config: AnnotatorConfig,
        candidates: SampledCandidates | GivenCandidates | None = None,
        *,
        cell: CellOptions | None = None,
        resting: bool | str = False,
    ) -> None:
        self.config = config
        self.candidates = candidates
        self.cell = cell
        self.resting = resting
        self.gripper: GripperDescription | None = None
        self.sources: list[ObjectSource] = []
        self.digests: dict[str, str] = {}
        self._sent: GripperDescription | GripperFiles | None = None
        self._options: RunOptions | None = None  # the run's, from check()

    # --- the job interface ---------------------------------------------------------------------------

    def check(self, options: RunOptions) -> None:
        self._options = options
        if self.candidates is None:
            self.candidates = SampledCandidates(options.n)
        if not 1 <= options.n <= MAX_N:
            raise UsageError(f"--n must be between 1 and {MAX_N:,} candidates per object, got {options.n}")
        self.gripper = loaded_gripper(options.gripper)

    def bind(self, options: RunOptions, summary: Summary) -> tuple[RunSpec, dict[str, str]]:
        assert self.gripper is not None and self.candidates is not None
        try:
            sources = discover_objects(options.objects_dir, self.config.objects)
        except ObjectDiscoveryError as exc:
            raise UsageError(str(exc)) from exc
        sources, missing = self.candidates.select(sources)
        summary.failed.update(missing)
        for source in sources:
            try:
                self.digests[source.object_id] = source_digest(source, self.config.objects.memory_budget)
            except ObjectError as exc:
                summary.failed[source.object_id] = str(exc)
        self.sources = sources
        spec = RunSpec(
            options.seed,
            options.n,
            options.trials,
            options.scale,
            chunk_size_for(options.n),
            self.config.to_dict(trials=options.trials),
            inputs=self.inputs(),
            gripper=gripper_record(self.gripper),
        )
        return spec, self.digests

    def inputs(self) -> dict[str, Any]:
        """RunSpec.inputs: the candidate source's, and the worker mode when not floating (a
        floating run records nothing new, so folders made before the modes existed still resume;
        a folder of one mode never resumes as another)."""
        assert self.candidates is not None
        return dict(self.candidates.inputs())

    def plan(self, options: RunOptions, store: Store, resume: Resume, summary: Summary) -> WorkPlan | None:
        assert self.gripper is not None and self.candidates is not None
        digests, candidates = self.digests, self.candidates
        store.manifest.objects_planned = sorted(set(digests) | set(summary.failed))
        gripper = self.gripper
        store.manifest.gripper_folder = None if is_shipped(gripper) else str(gripper.folder.resolve())
        for oid, error in summary.failed.items():
            store.fail_object(oid, error)
        resumed(store, summary, resume.done)
        n, chunk = options.n, store.spec.chunk_size
        planned = [
            PlannedObject(
                s,
                frozenset(resume.chunks.get(s.object_id, set())),
                candidates.count(s.object_id),
                candidates.given,
            )
            for s in self.sources
            if s.object_id in digests and s.object_id not in resume.done
        ]
        remaining = {p.source.object_id: spans_to_do(p, n, chunk) for p in planned}
        for p in planned:
            if remaining[p.source.object_id] == 0:  # every chunk on disk: only the merge was missing
                merged(store, summary, p.source.object_id, digests[p.source.object_id])
        total = sum(candidates_to_do(p, n, chunk) for p in planned)
        if resume.done or any(p.done for p in planned):
            log.info(
                "resuming %s: %d objects done earlier, %d chunks of unfinished objects kept; "
                "%d candidates to do",
                options.out_dir,
                len(resume.done),
                sum(len(p.done) for p in planned),
                total,
            )
        if total <= 0:
            return None
        todo = [p for p in planned if remaining[p.source.object_id] > 0]
        return WorkPlan(
            total,
            len(planned),
            remaining,
            lambda workers: Schedule(todo, n, chunk, options.scale, workers),
            decompositions=len(todo),
            left={p.source.object_id: candidates_to_do(p, n, chunk) for p in todo},
        )

    def make_task(self, unit: Span | Prepare, context: TaskContext) -> SpanTask:
        options = self._options
        assert options is not None and self.gripper is not None
        if self._sent is None:
            # a cluster's workers may not see the gripper's folder: they get its files
            self._sent = self.gripper if context.local else _gripper_files(self.gripper)
        return SpanTask(
            span=unit,
            config=self.config,
            seed=options.seed,
            n=options.n,
            trials=options.trials,
            source_sha256=self.digests[unit.object_id],
            versions=context.versions,
            parent_pid=context.parent_pid,
            status_dir=context.status_dir,
            cache_dir=context.cache_dir,
            cell=self.cell,
            gripper=self._sent,
            resting=self.resting,
        )

    def take(self, result: SpanResult, collector: Collector) -> None:
        oid = result.span.object_id
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
