"""``annotate --scenes N``: N scenes as units of work through the same store, workers and Dask.

Each scene is a unit of the store (``scene_000003``: its label files, resume, verification and
artifacts as an object's), its N grasps split into spans of :data:`SCENE_CHUNK_SIZE`. The main
process never loads a mesh: it discovers the pool, binds the run (the configuration with its
``[scenes]`` section, the scene request and the pool in the manifest) and hands out spans; the
worker of a scene's first span builds the scene and returns its record and views as artifacts
(``_views/scene_000003-<hash>/scene.parquet``, ``vVV_*.png``, ``cameras.parquet``), which the main
process then passes to the scene's later spans. A worker labels a scene's span in the scene mode
(:mod:`annotator.pipeline.scene_mode`) of the one worker state, as it labels an object's span.

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
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

from annotator.config import AnnotatorConfig
from annotator.grippers import GripperDescription, GripperFiles, gripper_record, is_shipped
from annotator.objects import ObjectDiscoveryError, ObjectError, discover_objects, source_digest
from annotator.pipeline.execution import UsageError
from annotator.pipeline.lifecycle import Collector, TaskContext, WorkPlan, loaded_gripper, merged, resumed
from annotator.pipeline.options import RunOptions
from annotator.pipeline.plan import FIRST_SPANS_AHEAD, MAX_N
from annotator.pipeline.scene_mode import SCENE_FILE, record_from_artifact
from annotator.pipeline.summary import Summary
from annotator.pipeline.tasks import UNUSABLE_OBJECT, SceneRequest, SceneSpan, SceneTask, SpanResult
from annotator.pipeline.worker import label_span
from annotator.scenes.records import ARRANGEMENTS, SceneRecord
from annotator.scenes.views import MAX_INSTANCE_ID
from annotator.store import Resume, RunSpec, Store
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


@dataclass(frozen=True)
class SceneOptions:
    """``annotate --scenes``' own options: ``scenes`` scenes of ``per_scene`` (min, max) objects in
    the ``arrangement``; ``views`` per scene; ``cell``: the UR3's reachability columns."""

    scenes: int
    per_scene: tuple[int, int] = (5, 5)
    arrangement: str = "pile"
    views: int = 0
    cell: bool = False


def check_scene_options(options: RunOptions, own: SceneOptions) -> None:
    """UsageError for scene options that cannot run."""
    lo, hi = own.per_scene
    if not 1 <= own.scenes <= MAX_SCENES:
        raise UsageError(f"--scenes must be between 1 and {MAX_SCENES:,}, got {own.scenes}")
    if not 1 <= options.n <= MAX_N:
        raise UsageError(f"--n must be between 1 and {MAX_N:,} grasps per scene, got {options.n}")
    if not 1 <= lo <= hi <= MAX_OBJECTS_PER_SCENE:
        raise UsageError(f"--per-scene {lo}-{hi}: need 1 <= A <= B <= {MAX_OBJECTS_PER_SCENE}")
    if own.arrangement not in ARRANGEMENTS:
        choices = ", ".join(ARRANGEMENTS)
        raise UsageError(f"--arrangement must be one of {choices}, got {own.arrangement!r}")
    if own.views < 0:
        raise UsageError(f"--views must be 0 or more, got {own.views}")


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


def _is_rg2(gripper: GripperDescription) -> bool:
    """The shipped RG2: the default, which a scene run binds as it did before grippers were data."""
    return gripper.name == "rg2" and is_shipped(gripper)


class SceneJob:
    """``annotate --scenes N``: the scenes are the units of work (a job of
    :mod:`annotator.pipeline.lifecycle`); the worker of a scene's first span builds it and returns
    its record, which this job passes to the scene's later spans."""

    unit = "scene"
    noun = "grasps"
    worker = staticmethod(label_span)

    def __init__(self, config: AnnotatorConfig, own: SceneOptions) -> None:
        self.config = config
        self.own = own
        self.request: SceneRequest | None = None
        self.units: dict[str, str] = {}
        self.records: dict[int, SceneRecord] = {}
        self.store: Store | None = None
        # objects left out of every scene (their files cannot be read): object id -> reason
        self.left_out: dict[str, str] = {}
        # objects a worker could not load: object id -> (reason, the scenes that draw it)
        self.unusable: dict[str, tuple[str, list[str]]] = {}
        self.failed_scenes: set[str] = set()
        self.gripper: GripperDescription | None = None  # the run's, from check()
        self._sent: GripperDescription | GripperFiles | None = None  # what the tasks carry

    def check(self, options: RunOptions) -> None:
        self.gripper = loaded_gripper(options.gripper)
        check_scene_options(options, self.own)

    def bind(self, options: RunOptions, summary: Summary) -> tuple[RunSpec, dict[str, str]]:
        own = self.own
        try:
            sources = discover_objects(options.objects_dir, self.config.objects)
        except ObjectDiscoveryError as exc:
            raise UsageError(str(exc)) from exc
        digests: dict[str, str] = {}
        for source in sources:
            try:
                digests[source.object_id] = source_digest(source, self.config.objects.memory_budget)
            except ObjectError as exc:  # a file that cannot be read: the scenes draw from the others
                self.left_out[source.object_id] = f"left out of every scene: {exc}"
        summary.failed.update(self.left_out)
        sources = [s for s in sources if s.object_id in digests]
        if not sources:
            first = next(iter(summary.failed.values()))
            raise UsageError(f"no object in {options.objects_dir} can be read: {first}")
        lo, hi = own.per_scene
        self.request = job = SceneRequest(
            tuple(sources),
            digests,
            own.arrangement,
            lo,
            hi,
            options.n,
            options.seed,
            options.trials,
            own.views,
            own.cell,
            options.scale,
        )
        spec = RunSpec(
            options.seed,
            options.n,
            options.trials,
            options.scale,
            scene_chunk_size(options.n),
            self.config.to_dict(scenes=True, trials=options.trials),
            inputs={"scenes": job.to_json()},
            # the RG2 is bound as before grippers were data, so folders made then still resume
            gripper=None if self.gripper is None or _is_rg2(self.gripper) else gripper_record(self.gripper),
        )
        self.units = {scene_unit(s): pool_digest(digests) for s in range(own.scenes)}
        return spec, self.units

    def plan(self, options: RunOptions, store: Store, resume: Resume, summary: Summary) -> WorkPlan | None:
        self.store = store
        n, chunk = options.n, store.spec.chunk_size
        store.manifest.objects_planned = sorted(self.units)
        for oid, error in self.left_out.items():  # one line per object in the manifest as in the summary
            store.fail_object(oid, error)
        resumed(store, summary, resume.done)
        todo = []
        remaining: dict[str, int] = {}
        for scene_id in range(self.own.scenes):
            unit = scene_unit(scene_id)
            if unit in resume.done:
                continue
            done = frozenset(resume.chunks.get(unit, set()))
            remaining[unit] = math.ceil(n / chunk) - sum(
                1 for a, b in done if a % chunk == 0 and b == min(n, a + chunk)
            )
            if remaining[unit] == 0:  # every chunk on disk: only the merge was missing
                merged(store, summary, unit, self.units[unit])
                continue
            self._recorded_scene(scene_id)
            todo.append((scene_id, done))
        total = sum(n - sum(b - a for a, b in done) for _, done in todo)
        if resume.done or any(done for _, done in todo):
            log.info(
                "resuming %s: %d scenes done earlier, %d chunks of unfinished scenes kept; %d grasps to do",
                options.out_dir,
                len(resume.done),
                sum(len(done) for _, done in todo),
                total,
            )
        if not todo:
            return None
        return WorkPlan(
            total,
            len(todo),
            remaining,
            lambda workers: plan_scene_spans(todo, n, chunk, max(FIRST_SPANS_AHEAD, 2 * workers)),
        )

    def _recorded_scene(self, scene_id: int) -> None:
        """The scene's record from its first chunk's artifact when that chunk is on disk (resume)."""
        assert self.store is not None
        entry = self.store.manifest.chunks_done.get(scene_unit(scene_id), {"files": {}})
        for record in entry["files"].values():
            artifact = record.get("artifacts", {}).get(SCENE_FILE)
            if artifact is not None:
                with contextlib.suppress(OSError, ValueError):
                    data = (self.store.out_dir / artifact["file"]).read_bytes()
                    self.records[scene_id] = record_from_artifact(data)

    def make_task(self, span: SceneSpan, context: TaskContext) -> SceneTask:
        assert self.request is not None
        if self._sent is None and self.gripper is not None and not _is_rg2(self.gripper):
            # a cluster's workers may not see the gripper's folder: they get its files
            self._sent = self.gripper if context.local else GripperFiles.of(self.gripper)
        return SceneTask(
            span=span,
            request=self.request,
            config=self.config,
            record=self.records.get(span.scene_id),
            versions=context.versions,
            parent_pid=context.parent_pid,
            status_dir=context.status_dir,
            cache_dir=context.cache_dir,
            gripper=self._sent,
        )

    def take(self, result: SpanResult, collector: Collector) -> None:
        """Write a span's artifacts and labels (or fail its scene); merge a finished scene."""
        span = result.span
        assert isinstance(span, SceneSpan)
        unit = span.object_id
        collector.progress.advance(span.size)
        collector.account(result)
        if unit in collector.summary.failed or unit in self.failed_scenes:
            return
        if result.error is not None:
            unusable = (result.info or {}).get(UNUSABLE_OBJECT)
            if unusable is None:
                collector.fail(unit, result.error)
                collector.progress.object_done(unit, "failed")
            else:
                self._fail_for_object(unit, unusable, result.error, collector)
            return
        files = result.artifacts or {}
        if SCENE_FILE in files:
            self.records[span.scene_id] = record_from_artifact(files[SCENE_FILE])
        collector.write(result)

    def _fail_for_object(self, unit: str, oid: str, error: str, collector: Collector) -> None:
        """Scene ``unit`` failed because a worker cannot load object ``oid`` (``error``: the span's
        line, the scene's id then the object's reason). The object is reported once, by its name,
        in the summary and the manifest, with the scenes that draw it; each such scene's own
        manifest entry (it failed: retried on a resume, an export needs --partial) names it."""
        assert self.store is not None
        reason = error.removeprefix(f"{unit}: ")
        self.failed_scenes.add(unit)
        self.store.fail_object(unit, f"draws {oid}, which cannot be loaded: {reason}")
        first = oid not in self.unusable
        scenes = self.unusable.setdefault(oid, (reason, []))[1]
        scenes.append(unit)
        why = reason.removeprefix(f"{oid}: ")
        drawn = _scenes_text(sorted(scenes))
        line = f"cannot be loaded in a worker ({why}); not labelled, as they draw it: {drawn}"
        collector.summary.failed[oid] = line
        self.store.fail_object(oid, line)
        if first:
            log.error("%s: %s", oid, line)
        collector.progress.object_done(unit, f"failed (draws {oid})")


# Scene ids a failure line names before it counts the rest.
NAMED_SCENES = 5


def _scenes_text(units: list[str]) -> str:
    """``scene_000000, scene_000003`` or, beyond :data:`NAMED_SCENES`, the first ones and a count."""
    named = ", ".join(units[:NAMED_SCENES])
    more = len(units) - NAMED_SCENES
    return f"{named} and {more} more scenes" if more > 0 else named
