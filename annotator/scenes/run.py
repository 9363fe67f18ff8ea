"""``annotate --scenes N``: N scenes as units of work through the same store, workers and Dask.

Each scene is a unit of the store (``scene_000003``: its label files, resume, verification and
artifacts as an object's), its N grasps split into spans of :data:`SCENE_CHUNK_SIZE`. The main
process never loads a mesh: it discovers the pool, binds the run (the configuration with its
``[scenes]`` section, the scene request and the pool in the manifest) and hands out spans; the
worker of a scene's first span builds the scene and returns its record and views as artifacts
(``_views/scene_000003-<hash>/scene.parquet``, ``vVV_*.png``, ``cameras.parquet``), which the main
process then passes to the scene's later spans (:mod:`annotator.scenes.worker`).

Every scene draws from the whole pool, so the pool is each scene's source: a changed, added or
removed object redoes every scene. The number of scenes is not bound: ``--scenes 20`` on a folder of
10 scenes labels 10 more; fewer set the rest aside in ``_stale/`` as for objects.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import math
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

from annotator.config import AnnotatorConfig
from annotator.dataset import Outcome
from annotator.objects import (
    ObjectDiscoveryError,
    ObjectError,
    default_cache_dir,
    discover_objects,
    source_digest,
)
from annotator.pipeline import status
from annotator.pipeline.plan import FIRST_SPANS_AHEAD, MAX_N
from annotator.pipeline.progress import Progress
from annotator.pipeline.run import (
    STATUS_AFTER,
    RunOptions,
    Terminated,
    UsageError,
    Workers,
    _check_workers,
    execute,
    open_store,
    running,
)
from annotator.pipeline.summary import ObjectStats, Summary
from annotator.pipeline.worker import SpanResult
from annotator.scenes.records import ARRANGEMENTS, SceneRecord
from annotator.scenes.views import MAX_INSTANCE_ID
from annotator.scenes.worker import (
    SCENE_FILE,
    SceneJob,
    SceneSpan,
    SceneTask,
    label_scene_span,
    record_from_artifact,
)
from annotator.store import RunSpec, Store
from annotator.store.names import scene_unit

log = logging.getLogger(__name__)

# Grasps per span of a scene: VGN's 120 in three spans. A span of another scene than the one a
# worker holds costs loading that scene (its world and candidates, ~0.1-0.3 s) and, when the main
# process does not have the scene yet, settling it (~0.5-3 s): a third of a scene keeps that within
# a few percent of the span's trials while a kill loses a third of a scene per worker at most.
SCENE_CHUNK_SIZE = 40
MAX_SCENES = 1_000_000
MAX_OBJECTS_PER_SCENE = MAX_INSTANCE_ID + 1  # instance ids must fit the uint8 segmentation


def scene_chunk_size(n: int) -> int:
    """Grasps per span and chunk file of a scene of ``n`` grasps."""
    return max(SCENE_CHUNK_SIZE, math.ceil(n / 2000))


def check_scene_options(options: RunOptions) -> None:
    """UsageError for scene options that cannot run."""
    lo, hi = options.per_scene
    if not 1 <= options.scenes <= MAX_SCENES:
        raise UsageError(f"--scenes must be between 1 and {MAX_SCENES:,}, got {options.scenes}")
    if not 1 <= options.n <= MAX_N:
        raise UsageError(f"--n must be between 1 and {MAX_N:,} grasps per scene, got {options.n}")
    if not 1 <= lo <= hi <= MAX_OBJECTS_PER_SCENE:
        raise UsageError(f"--per-scene {lo}-{hi}: need 1 <= A <= B <= {MAX_OBJECTS_PER_SCENE}")
    if options.arrangement not in ARRANGEMENTS:
        choices = ", ".join(ARRANGEMENTS)
        raise UsageError(f"--arrangement must be one of {choices}, got {options.arrangement!r}")
    if options.views < 0:
        raise UsageError(f"--views must be 0 or more, got {options.views}")


def pool_digest(digests: dict[str, str]) -> str:
    """One digest of every object's source: each scene's source digest in the manifest."""
    text = json.dumps(sorted(digests.items()))
    return hashlib.sha256(text.encode()).hexdigest()


def plan_scene_spans(
    scenes: Sequence[tuple[int, frozenset[tuple[int, int]]]], n: int, chunk: int, ahead: int
) -> Iterator[SceneSpan]:
    """The spans still to label: ``scenes`` are (scene id, its chunks on disk). Each scene's first
    missing span is planned ``ahead`` scenes before the rest of it, so the scene is usually built
    (and its record back in the main process) before its other spans are handed out. Lazy."""

    def missing(k: int) -> Iterator[tuple[int, int]]:
        scene_id, done = scenes[k]
        for start in range(0, n, chunk):
            if (start, min(n, start + chunk)) not in done:
                yield (start, min(n, start + chunk))

    firsts: dict[int, tuple[int, int] | None] = {}
    issued = 0
    for i in range(len(scenes)):
        while issued < len(scenes) and issued < i + max(1, ahead):
            firsts[issued] = first = next(missing(issued), None)
            if first is not None:
                yield SceneSpan(scenes[issued][0], *first)
            issued += 1
        first = firsts.pop(i)
        for rng in missing(i):
            if rng != first:
                yield SceneSpan(scenes[i][0], *rng)


def run_scenes(options: RunOptions, config: AnnotatorConfig) -> Summary:
    """The whole scene job; returns the summary (also printed). Exit conditions as
    :func:`annotator.pipeline.run.run`."""
    summary = Summary(unit="scene")
    check_scene_options(options)
    _check_workers(options)
    try:
        sources = discover_objects(options.objects_dir, config.objects)
    except ObjectDiscoveryError as exc:
        raise UsageError(str(exc)) from exc
    digests: dict[str, str] = {}
    unreadable = []
    for source in sources:
        try:
            digests[source.object_id] = source_digest(source, config.objects.memory_budget)
        except ObjectError as exc:
            unreadable.append(f"{source.object_id}: {exc}")
    if unreadable:
        raise UsageError(f"scenes draw from every object; {len(unreadable)} cannot be read: {unreadable[0]}")
    lo, hi = options.per_scene
    job = SceneJob(
        tuple(sources),
        digests,
        options.arrangement,
        lo,
        hi,
        options.n,
        options.seed,
        options.trials,
        options.views,
        options.cell,
        options.scale,
    )
    spec = RunSpec(
        options.seed,
        options.n,
        options.trials,
        options.scale,
        scene_chunk_size(options.n),
        config.to_dict(scenes=True),
        inputs={"scenes": job.to_json()},
    )
    units = {scene_unit(s): pool_digest(digests) for s in range(options.scenes)}
    store, resume = open_store(options, spec, units)
    with running(store, summary) as status_dir:
        _SceneRun(options, config, summary, store, job, units, status_dir).run(resume)
    return summary


@dataclass
class _SceneRun:
    """The body of :func:`run_scenes` once the folder is open: plan, hand out, write."""

    options: RunOptions
    config: AnnotatorConfig
    summary: Summary
    store: Store
    job: SceneJob
    units: dict[str, str]
    status_dir: str
    records: dict[int, SceneRecord] = field(default_factory=dict)
    remaining: dict[str, int] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)

    def run(self, resume) -> None:
        store, summary, n = self.store, self.summary, self.options.n
        chunk = store.spec.chunk_size
        store.manifest.objects_planned = sorted(self.units)
        for unit in sorted(resume.done):
            summary.resumed[unit] = ObjectStats.from_json(store.manifest.objects_done[unit]["stats"], None)
        todo = []
        for scene_id in range(self.options.scenes):
            unit = scene_unit(scene_id)
            if unit in resume.done:
                continue
            done = frozenset(resume.chunks.get(unit, set()))
            self.remaining[unit] = math.ceil(n / chunk) - sum(
                1 for a, b in done if a % chunk == 0 and b == min(n, a + chunk)
            )
            if self.remaining[unit] == 0:  # every chunk on disk: only the merge was missing
                summary.done[unit] = ObjectStats.from_json(store.finish_object(unit, self.units[unit]), 0.0)
                continue
            self._recorded_scene(scene_id)
            todo.append((scene_id, done))
        total = sum(n - sum(b - a for a, b in done) for _, done in todo)
        if resume.done or any(done for _, done in todo):
            log.info(
                "resuming %s: %d scenes done earlier, %d chunks of unfinished scenes kept; %d grasps to do",
                self.options.out_dir,
                len(resume.done),
                sum(len(done) for _, done in todo),
                total,
            )
        if todo:
            self._execute(todo, total)

    def _recorded_scene(self, scene_id: int) -> None:
        """The scene's record from its first chunk's artifact when that chunk is on disk (resume)."""
        entry = self.store.manifest.chunks_done.get(scene_unit(scene_id), {"files": {}})
        for record in entry["files"].values():
            artifact = record.get("artifacts", {}).get(SCENE_FILE)
            if artifact is not None:
                with contextlib.suppress(OSError, ValueError):
                    data = (self.store.out_dir / artifact["file"]).read_bytes()
                    self.records[scene_id] = record_from_artifact(data)

    def _execute(self, todo, total: int) -> None:
        options = self.options
        workers = Workers(options, self.status_dir)
        progress = Progress(total, len(todo), quiet=options.quiet)
        versions = self.store.spec.versions
        # read here, not in reused workers started under another env; a cluster's workers use
        # --cache when given (a shared filesystem), else their own default folder
        cache_dir = options.cache_dir or (default_cache_dir() if workers.client is None else None)

        def make_task(span: SceneSpan) -> SceneTask:
            local = workers.client is None
            return SceneTask(
                span,
                self.job,
                self.config,
                record=self.records.get(span.scene_id),
                versions=versions,
                parent_pid=workers.parent_pid,
                status_dir=self.status_dir if local else None,
                cache_dir=None if cache_dir is None else str(cache_dir),
            )

        def on_tick() -> None:
            if progress.bar is not None:
                busy = status.read(self.status_dir, older_than=STATUS_AFTER)
                progress.status("; ".join(busy) if busy else "")

        interrupted = True
        try:
            ahead = max(FIRST_SPANS_AHEAD, 2 * workers.count)
            spans = plan_scene_spans(todo, options.n, self.store.spec.chunk_size, ahead)
            on_result = lambda r: self.on_result(r, progress)  # noqa: E731
            execute(spans, make_task, workers, on_result, on_tick, label_scene_span)
            interrupted = False
        except (KeyboardInterrupt, Terminated):
            log.info("interrupted: %d grasps written this run", self.summary.candidates)
            raise
        finally:
            progress.close()
            workers.close(kill=interrupted)

    def on_result(self, result: SpanResult, progress: Progress) -> None:
        """Write a span's artifacts and labels (or fail its scene); merge a finished scene."""
        summary, store = self.summary, self.store
        span, unit = result.span, result.span.object_id
        progress.advance(span.size)
        summary.peak_rss_mb[result.stats.pid] = result.stats.peak_rss_mb
        summary.worker_seconds += result.stats.seconds
        if unit in summary.failed:
            return
        if result.error is not None:
            summary.failed[unit] = result.error
            store.fail_object(unit, result.error)
            log.error("%s", result.error)
            progress.object_done(unit, "failed")
            return
        df = result.rows
        assert df is not None
        self.seconds[unit] = self.seconds.get(unit, 0.0) + result.stats.seconds
        summary.step_seconds += result.stats.step_seconds
        summary.sim_steps += int(df["sim_steps"].sum())
        summary.candidates += len(df)
        summary.physics_trials += int((df["outcome"] != Outcome.COLLISION.label).sum())
        if result.info is not None and unit not in store.manifest.objects_info:
            store.record_info(unit, result.info)
        files = result.artifacts or {}
        if SCENE_FILE in files:
            self.records[span.scene_id] = record_from_artifact(files[SCENE_FILE])  # type: ignore[attr-defined]
        artifacts = {name: store.write_artifact(unit, name, data) for name, data in files.items()}
        store.write_chunk(unit, df, span.start, self.units[unit], artifacts)
        if summary.first_label_seconds is None:
            summary.first_label_seconds = time.perf_counter() - summary.started
        self.remaining[unit] -= 1
        if self.remaining[unit] == 0:
            stats = store.finish_object(unit, self.units[unit])
            summary.done[unit] = done = ObjectStats.from_json(stats, self.seconds[unit])
            progress.object_done(unit, done.line())
