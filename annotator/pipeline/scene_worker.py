"""The worker side of ``annotate --scenes``: a span is grasps ``start..stop-1`` of one scene.

A worker keeps what it loaded between spans: the objects of the pool it has met (models, with
their convex decompositions from the cache), the scenes it built (their records), and the scene it
labels now (its trial world, the arm's world with ``--cell``, and the scene's candidates). A span
of a scene the worker holds costs its trials only.

A scene is built (:class:`annotator.scenes.SceneBuilder`) by the worker of its first span, which
also returns the scene's record and views as artifacts. The main process passes the record to the
scene's later spans (read back from the artifact on a resume: the Parquet round trip is exact),
so they do not settle the scene again; a span given no record builds it, bit for bit the same
(the scene depends on (seed, scene id) and the pool only).
"""

from __future__ import annotations

import io
import logging
import time
from collections import OrderedDict
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from annotator.config import AnnotatorConfig
from annotator.grippers import GripperDescription, resolve_gripper
from annotator.objects import ObjectError, ObjectModel, ObjectSource, default_cache_dir, load_object
from annotator.pipeline import status
from annotator.pipeline.process import check_versions, task_stats, watch_parent
from annotator.pipeline.tasks import SpanResult
from annotator.pipeline.worker import object_info
from annotator.scenes.arrange import SceneBuilder
from annotator.scenes.labels import SceneArm, SceneCandidates, SceneTrials, label_scene
from annotator.scenes.records import SceneRecord, SceneSpec, scene_table, scenes_from_table
from annotator.scenes.views import render_views, view_files
from annotator.store.names import scene_unit

log = logging.getLogger(__name__)

# The scene table of a scene, an artifact of its first span (beside its views).
SCENE_FILE = "scene.parquet"
# Scene records a worker keeps (a few kilobytes each) so that coming back to a scene never settles
# it again.
RECENT_SCENES = 64
# Objects a worker keeps loaded, at most: the sample objects are 10; a large pool is loaded again
# as scenes draw it (each model is a few MB with its decomposition).
RECENT_MODELS = 32


@dataclass(frozen=True)
class SceneRequest:
    """What every span of a scene run shares: the ``pool`` of objects (sorted by id) with their
    source ``digests``, the scenes asked for (``arrangement``, objects per scene
    ``min_objects``..``max_objects``), grasps per scene ``n``, ``seed``, ``trials`` per grasp,
    ``views`` per scene, ``cell`` (the UR3's reachability) and the mesh ``scale``."""

    pool: tuple[ObjectSource, ...]
    digests: Mapping[str, str] | None
    arrangement: str
    min_objects: int
    max_objects: int
    n: int
    seed: int
    trials: int = 1
    views: int = 0
    cell: bool = False
    scale: float | None = None

    def spec(self, scene_id: int) -> SceneSpec:
        return SceneSpec(scene_id, self.seed, self.arrangement, self.min_objects, self.max_objects)

    def to_json(self) -> dict[str, Any]:
        """What the manifest binds (RunSpec.inputs['scenes']): everything that shapes a scene's labels
        except the number of scenes (a run with more scenes extends a folder)."""
        return {
            "arrangement": self.arrangement,
            "per_scene": [int(self.min_objects), int(self.max_objects)],
            "pool": [s.object_id for s in self.pool],
            "views": int(self.views),
            "cell": bool(self.cell),
        }


@dataclass(frozen=True)
class SceneSpan:
    """Grasps ``start..stop-1`` of scene ``scene_id``; ``object_id`` is its store unit id."""

    scene_id: int
    start: int
    stop: int

    @property
    def object_id(self) -> str:
        return scene_unit(self.scene_id)

    @property
    def size(self) -> int:
        return self.stop - self.start

    @property
    def key(self) -> tuple[str, int]:
        return (self.object_id, self.start)


@dataclass(frozen=True)
class SceneTask:
    """A span with what the worker needs: the request, the configuration, the scene's ``record`` when
    the main process has it, and the checks of :class:`annotator.pipeline.worker.SpanTask`."""

    span: SceneSpan
    request: SceneRequest
    config: AnnotatorConfig
    record: SceneRecord | None = None
    versions: dict[str, str] | None = None
    parent_pid: int | None = None
    status_dir: str | None = None
    cache_dir: str | None = None
    gripper: GripperDescription | None = None


class UnusableObject(ObjectError):
    """An object of the pool that a worker cannot load although its file passed the main process's
    checks (size, header): a degenerate mesh, one that cleaning leaves empty. ``object_id`` goes
    back with the failed span, so that the main process reports the object once, not each scene
    that draws it."""

    def __init__(self, object_id: str, reason: str) -> None:
        super().__init__(reason if reason.startswith(f"{object_id}:") else f"{object_id}: {reason}")
        self.object_id = object_id


# SpanResult.info key of a failed span: the pool object the scene could not load (UnusableObject).
UNUSABLE_OBJECT = "unusable_object"


def record_from_artifact(data: bytes) -> SceneRecord:
    """The scene of a :data:`SCENE_FILE` artifact's bytes."""
    records = scenes_from_table(pd.read_parquet(io.BytesIO(data)))
    if len(records) != 1:
        raise ValueError(f"a scene file holds one scene, this one {len(records)}")
    return records[0]


def _table_bytes(record: SceneRecord) -> bytes:
    buffer = io.BytesIO()
    scene_table([record]).to_parquet(buffer, index=False)
    return buffer.getvalue()


class _Pool(Mapping[str, ObjectModel]):
    """The request's objects as a Mapping that loads each on first use (a scene looks up what it draws)."""

    def __init__(self, state: SceneWorkerState, task: SceneTask) -> None:
        self.state, self.task = state, task
        self.sources = {s.object_id: s for s in task.request.pool}

    def __getitem__(self, object_id: str) -> ObjectModel:
        try:
            return self.state.model(self.task, self.sources[object_id])
        except UnusableObject:
            raise
        except ObjectError as exc:
            raise UnusableObject(object_id, str(exc)) from exc

    def __iter__(self) -> Iterator[str]:
        return iter(self.sources)

    def __len__(self) -> int:
        return len(self.sources)


@dataclass
class _Current:
    """The scene a worker labels now: its trials, arm (``--cell``), candidates."""

    key: tuple
    trials: SceneTrials
    arm: SceneArm | None
    candidates: SceneCandidates

    def close(self) -> None:
        self.trials.close()
        if self.arm is not None:
            self.arm.close()


class SceneWorkerState:
    """This process's objects, built scenes and current scene; the parent watch and the version
    check are the process's (:mod:`annotator.pipeline.process`)."""

    def __init__(self) -> None:
        self.models: OrderedDict[tuple, ObjectModel] = OrderedDict()
        self.records: OrderedDict[tuple, SceneRecord] = OrderedDict()
        self.current: _Current | None = None

    # --- objects and scenes -----------------------------------------------------------------------

    def model(self, task: SceneTask, source: ObjectSource) -> ObjectModel:
        """The object ``source`` loaded as the run loads it (kept: RECENT_MODELS); ObjectError."""
        digest = (task.request.digests or {}).get(source.object_id)
        key = (
            source.object_id,
            str(source.path),
            digest,
            task.request.scale,
            source.properties,
            task.config.objects,
        )
        if key in self.models:
            self.models.move_to_end(key)
            return self.models[key]
        status.write(task.status_dir, f"loading {source.object_id}")
        cache = Path(task.cache_dir) if task.cache_dir is not None else None
        model = load_object(source, task.config.objects, scale=task.request.scale, cache_dir=cache)
        self.models[key] = model
        while len(self.models) > RECENT_MODELS:
            self.models.popitem(last=False)
        return model

    def record(self, task: SceneTask) -> tuple[SceneRecord, bool]:
        """The task's scene (given, kept or built) and whether this span built it."""
        key = self._scene_key(task)
        if task.record is not None:
            self.records[key] = task.record
        if key in self.records:
            self.records.move_to_end(key)
            return self.records[key], False
        status.write(task.status_dir, f"building scene {task.span.scene_id}")
        builder = SceneBuilder(
            _Pool(self, task), scenes=task.config.scenes, physics=task.config.physics, cell=task.config.cell
        )
        record = builder.build(task.request.spec(task.span.scene_id))
        self.records[key] = record
        while len(self.records) > RECENT_SCENES:
            self.records.popitem(last=False)
        return record, True

    @staticmethod
    def _scene_key(task: SceneTask) -> tuple:
        request = task.request
        pool = tuple((s.object_id, str(s.path), s.properties) for s in request.pool)
        digests = tuple(sorted((request.digests or {}).items()))
        return (task.span.scene_id, request.spec(0), pool, digests, request.scale, task.config)

    def scene_for(self, task: SceneTask) -> tuple[_Current, bool]:
        """The task's scene loaded for labelling (kept while the spans are of it); ObjectError
        when none of its objects stayed on the table."""
        record, built = self.record(task)
        if not record.kept:
            raise ObjectError(_empty_scene(record))
        cache_dir = task.cache_dir if task.cache_dir is not None else default_cache_dir()
        gripper = resolve_gripper(task.gripper, cache_dir)  # the run's files, never the user's folder
        key = (self._scene_key(task), gripper.key, task.request.n, task.request.seed, task.request.cell)
        if self.current is not None and self.current.key == key:
            return self.current, built
        self.close_scene()
        pool = _Pool(self, task)
        models = {i.object_id: pool[i.object_id] for i in record.kept}
        trials = SceneTrials(record, models, task.config, gripper)
        try:
            arm = SceneArm(record, models, task.config, gripper) if task.request.cell else None
            candidates = trials.candidates(task.request.n, task.request.seed)
        except BaseException:
            trials.close()
            raise
        self.current = _Current(key, trials, arm, candidates)
        return self.current, built

    def close_scene(self) -> None:
        if self.current is not None:
            self.current.close()
            self.current = None

    # --- a span ---------------------------------------------------------------------------------------

    def label_span(self, task: SceneTask) -> SpanResult:
        """Labels of one span of a scene, or the scene's one-line error."""
        t0 = time.perf_counter()
        watch_parent(task.parent_pid, task.status_dir)
        span = task.span
        try:
            check_versions(task.versions)
            current, built = self.scene_for(task)
        except ObjectError as exc:
            unusable = exc.object_id if isinstance(exc, UnusableObject) else None
            return _failed(span, f"{span.object_id}: {exc}", task_stats(t0, 0.0), unusable)
        except Exception as exc:  # an unexpected failure is this scene's, not the run's
            log.exception("%s: unexpected error while building", span.object_id)
            return _failed(span, f"{span.object_id}: {type(exc).__name__}: {exc}", task_stats(t0, 0.0))
        artifacts = self._artifacts(task, current) if span.start == 0 else None
        status.write(task.status_dir, f"simulating {span.object_id}")
        trials = current.trials
        steps0 = trials.world.step_seconds
        request = task.request
        rows = label_scene(
            trials, current.candidates, span.start, span.stop, request.seed, request.trials, current.arm
        )
        stats = task_stats(t0, trials.world.step_seconds - steps0)
        status.write(task.status_dir, None)
        info = {
            "scene": {"kept": len(trials.record.kept), "built_by_this_span": built},
            "objects": {oid: object_info(m) for oid, m in sorted(trials.models.items())},
        }
        return SpanResult(span, rows, None, stats, info, artifacts)  # type: ignore[arg-type]

    def _artifacts(self, task: SceneTask, current: _Current) -> dict[str, bytes]:
        """The scene's table and, with ``views``, its views (rendered from the scene at rest, the
        arm at READY with ``--cell``; the floating gripper waits 2 m up, out of every view)."""
        record = current.trials.record
        files = {SCENE_FILE: _table_bytes(record)}
        if task.request.views > 0:
            status.write(task.status_dir, f"rendering {task.span.object_id}")
            if current.arm is not None:
                current.arm.reset()
                loaded = current.arm.scene
            else:
                current.trials.reset()
                loaded = current.trials.scene
            kinect = task.config.kinect
            views = render_views(
                loaded,
                task.request.views,
                scenes=task.config.scenes,
                kinect_config=kinect,
                noise=kinect.views_depth_noise,
                color_scale=kinect.views_color_scale,
            )
            files.update(view_files(views))
        return files


def _failed(span: SceneSpan, error: str, stats, unusable: str | None = None) -> SpanResult:
    info = None if unusable is None else {UNUSABLE_OBJECT: unusable}
    return SpanResult(span, None, error, stats, info)  # type: ignore[arg-type]


def _empty_scene(record: SceneRecord) -> str:
    why = ", ".join(f"{i.object_id} {i.status}" for i in record.instances)
    return f"no object stayed on the table ({why}); nothing to label"


class _SceneWorkerSlot:
    instance: SceneWorkerState | None = None


def scene_worker_state() -> SceneWorkerState:
    if _SceneWorkerSlot.instance is None:
        _SceneWorkerSlot.instance = SceneWorkerState()
    return _SceneWorkerSlot.instance


def label_scene_span(task: SceneTask) -> SpanResult:
    """Entry point of a worker process (loky or Dask): label one span of a scene."""
    return scene_worker_state().label_span(task)
