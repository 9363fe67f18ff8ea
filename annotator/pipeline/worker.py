"""The worker side of the job: one state per process (:class:`WorkerState`), its mode with its
world (:mod:`annotator.pipeline.modes`), objects loaded on demand, spans labelled.

Every task (a :class:`SpanTask` of an object, a :class:`SceneTask` of a scene) runs through
:meth:`WorkerState.label`, which makes the checks a task needs once for every mode (the parent
watch, the label-shaping versions, the gripper resolved in the cache), builds the task's mode when
it is not the one the worker holds (:func:`build_mode`), has the mode load the task's unit and the
unit label the span, and turns a unit's error into the span's one-line error.

A worker builds its world once and keeps it between spans. Before any span of an object, one worker
runs the object's decomposition task (:class:`Prepare`): it loads the object, which makes its
collision shape and writes it to the content-addressed cache unless the cache holds it already,
and keeps the model for its own spans of it. When a span of an object arrives the worker takes the
object it keeps, or loads it (the collision shape from the cache), samples its N candidates (the
same on every worker: the Generator is keyed on seed and object id) and creates its body. Each
candidate starts from a restored snapshot with no contact memory
(:meth:`annotator.sim.world.World.restore_state`), so a label depends only on (object, seed,
candidate), never on which worker ran it or what it ran before.

With ``--cell`` (:class:`CellOptions`) the world also holds the seed's table, the object rests on
it in its placements and each row gains the cell's columns (annotator.cell.batch); with
``--views K`` the span holding grasp ``p`` also renders placement ``p``'s K Kinect views, returned
as files for the main process to write. A scene's span (:mod:`annotator.pipeline.scene_mode`)
builds or takes its scene and labels its grasps.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from collections import OrderedDict

import numpy as np

from annotator.config import AnnotatorConfig
from annotator.geometry import Transform
from annotator.grippers import GripperDescription, GripperFiles, resolve_gripper
from annotator.objects import (
    ObjectError,
    ObjectModel,
    create_body,
    default_cache_dir,
    physics_for,
)
from annotator.pipeline import status
from annotator.pipeline.loaded import LoadedObject, load_model, object_info
from annotator.pipeline.modes import WorkerMode
from annotator.pipeline.object_modes import UPRIGHT, ObjectMode, build_object_mode
from annotator.pipeline.process import check_versions, cpu_seconds, task_stats, watch_parent
from annotator.pipeline.simulate import TrialSettings, object_candidates, simulate
from annotator.pipeline.tasks import (
    UNUSABLE_OBJECT,
    CellOptions,
    GivenGrasps,
    Prepare,
    PreparedObject,
    SceneRequest,
    SceneSpan,
    SceneTask,
    Span,
    SpanGrasps,
    SpanResult,
    SpanTask,
    UnusableObject,
    WorkerStats,
)
from annotator.sampler import Candidates
from annotator.schema import REASON_COLUMNS

# The tasks and results a worker takes and returns (annotator.pipeline.tasks) and its trials
# (annotator.pipeline.simulate) are named here too, where callers have always found them.
__all__ = [
    "UPRIGHT",
    "CellOptions",
    "GivenGrasps",
    "LoadedObject",
    "Prepare",
    "PreparedObject",
    "REASON_COLUMNS",
    "SceneRequest",
    "SceneSpan",
    "SceneTask",
    "Span",
    "SpanGrasps",
    "SpanResult",
    "SpanTask",
    "TrialSettings",
    "WorkerState",
    "WorkerStats",
    "build_mode",
    "label_span",
    "max_width",
    "object_candidates",
    "object_info",
    "simulate",
    "worker_state",
]

log = logging.getLogger(__name__)

# Objects a worker keeps in memory (model and sampled candidates, not the body) after it moves to
# another one, up to about this many bytes in all: the objects whose decomposition tasks it ran
# (their spans reach it later, after spans of other objects) and those it labelled, which it may
# meet again; without them it loaded and sampled such an object again (sampling was 4.4 % of a
# span's time on the sample objects, bench/profile_worker.py). 128 MB holds 14 objects under
# ~8 MB each (about 40,000 faces) and keeps a worker within its memory target; a larger object is
# loaded again, as before.
RECENT_OBJECT_BYTES = 128 * 2**20
# Memory of a mesh or collision-part face with its vertices and trimesh's cached normals, about.
BYTES_PER_FACE = 200
# Where the floating gripper waits while no trial runs: 2 m above the object's mesh frame.
PARKED = Transform([0.0, 0.0, 2.0], [0.0, 0.0, 0.0, 1.0])

Task = SpanTask | SceneTask


def _footprint(model: ObjectModel, candidates: dict[tuple[int, int], Candidates]) -> int:
    """About how many bytes a kept object holds: its mesh and collision parts, its candidates."""
    faces = len(model.mesh.faces) + sum(len(part.faces) for part in model.parts)
    arrays = (v for c in candidates.values() for v in vars(c).values() if isinstance(v, np.ndarray))
    return BYTES_PER_FACE * faces + sum(a.nbytes for a in arrays)


def build_mode(key: tuple, config: AnnotatorConfig, gripper: GripperDescription) -> WorkerMode:
    """The mode of ``key`` (a task's ``mode_key``: ``("object", cell, resting mode)`` or
    ``("scene", cell)``) with its world, for ``config`` and the resolved ``gripper``."""
    if key[0] == "scene":
        from annotator.pipeline.scene_mode import SceneMode

        return SceneMode(config, gripper, cell=key[1])
    return build_object_mode(key, config, gripper)


class WorkerState:
    """This process's mode with its world, gripper and objects, built on first use and kept between
    tasks; the one place the checks every task needs are made (:meth:`label`)."""

    def __init__(self) -> None:
        self.config: AnnotatorConfig | None = None
        self.gripper: GripperDescription | None = None  # the gripper of the mode built, resolved
        self.mode: WorkerMode | None = None  # the task's mode with its world (annotator.pipeline.modes)
        # what the loaded models and candidates depend on: (objects, sampler and cell config,
        # gripper key, mode key) of the mode built; a change forgets them
        self.memory_key: tuple | None = None
        self.obj: LoadedObject | None = None
        # objects this world had: key -> (model, its candidates by (seed, n)), most recent last
        self.recent: OrderedDict[tuple, tuple[ObjectModel, dict]] = OrderedDict()
        # the footprint of each object in ``recent`` when it was kept, and their sum: a kept
        # object is not measured again each time another is kept (thousands of small objects fit)
        self.recent_bytes: dict[tuple, int] = {}
        self.recent_total = 0
        self.failed: dict[tuple, str] = {}  # object key -> its error (other spans fail at once)

    # --- the checks and the mode ------------------------------------------------------------------

    def begin(self, task: Task) -> WorkerMode:
        """The checks before a task (its label-shaping versions: ObjectError when they are not the
        run's) and its mode (:meth:`mode_for`)."""
        check_versions(task.versions)
        return self.mode_for(task)

    def gripper_for(self, task: Task) -> GripperDescription:
        """The task's gripper, frozen in the cache (:func:`annotator.grippers.resolve_gripper`):
        the files a cluster's main process sent are unpacked once and then taken as held."""
        gripper = task.gripper
        if isinstance(gripper, GripperFiles) and self.gripper is not None and gripper.key == self.gripper.key:
            return self.gripper  # unpacked already
        return resolve_gripper(gripper, task.cache_dir if task.cache_dir is not None else default_cache_dir())

    def mode_for(self, task: Task) -> WorkerMode:
        """The task's mode with its world (rebuilt only when the config, the gripper or the mode
        changes: a floating world never holds the table)."""
        config, key = task.config, task.mode_key
        gripper = self.gripper_for(task)
        changed = self.config != config or self.gripper is None or self.gripper.key != gripper.key
        if changed or self.mode is None or self.mode.key != key:
            # loaded models and candidates depend on these only: a calibration grid, which changes
            # the gripper's or the protocol's numbers from task to task, keeps them
            kept = (config.objects, config.sampler, config.cell, gripper.key, key)
            if kept == self.memory_key and self.obj is not None:
                # its model and candidates serve the new world too
                self._keep(self.obj.key, self.obj.model, self.obj.candidates)
            self.close()
            self.mode = build_mode(key, config, gripper)
            self.config, self.gripper = config, gripper
            if kept != self.memory_key:  # the keys do not hold the configuration
                self.failed = {}
                self._forget_recent()
            self.memory_key = kept
        return self.mode

    def close(self) -> None:
        """Free the mode and its world (the objects kept in memory stay)."""
        if self.mode is not None:
            self.mode.close()
        self.mode = self.obj = None

    # --- objects ---------------------------------------------------------------------------------

    def object_for(self, task: SpanTask, mode: ObjectMode) -> LoadedObject:
        """The span's object placed in ``mode``'s world (its body is created once per object);
        ObjectError."""
        key = self._key(task)
        if key in self.failed:
            raise ObjectError(self.failed[key])
        if self.obj is not None and self.obj.key == key:
            return self.obj
        if self.obj is not None:
            self._keep(self.obj.key, self.obj.model, self.obj.candidates)
            self.obj.release()
            mode.world.remove_body(self.obj.uid)
            self.obj = None
        model, candidates = self._kept(key)
        if model is None:
            model = self._load(task, key)
        self.obj = self._create(model, key, candidates, mode)
        return self.obj

    def _key(self, task: SpanTask) -> tuple:
        """What identifies the task's object in this worker. Worker processes outlive a run (they
        are reused), so the key is the object's source as it is now: its digest (a mesh behind an
        unchanged URDF included), else the file's stat."""
        unit = task.span
        version = task.source_sha256
        if version is None:
            try:
                stat = os.stat(unit.source.path)
            except OSError as exc:
                raise ObjectError(f"cannot read {unit.source.path}: {exc.strerror or exc}") from exc
            version = f"{stat.st_mtime_ns}-{stat.st_size}"
        return (unit.object_id, str(unit.source.path), version, unit.scale, unit.source.properties)

    def _kept(self, key: tuple) -> tuple[ObjectModel | None, dict]:
        """The model and candidates this worker kept of ``key`` (taken out of ``recent``), if any."""
        model, candidates = self.recent.pop(key, (None, {}))
        self.recent_total -= self.recent_bytes.pop(key, 0)
        if model is not None and model.collision_file is not None and not model.collision_file.exists():
            model, candidates = None, {}  # its collision file left the cache: load it again
        return model, candidates

    def _load(self, task: SpanTask, key: tuple) -> ObjectModel:
        """The task's object loaded (:func:`annotator.pipeline.loaded.load_model`); its error is
        kept, so its other spans fail at once."""
        unit = task.span
        try:
            return load_model(unit.source, task.config.objects, unit.scale, task.cache_dir, task.status_dir)
        except ObjectError as exc:
            self.failed[key] = str(exc)
            raise

    def _keep(self, key: tuple, model: ObjectModel, candidates: dict) -> None:
        """Remember an object this worker leaves or prepared (its model and candidates) within the
        memory budget, most recent last."""
        self.recent.pop(key, None)
        self.recent_total -= self.recent_bytes.pop(key, 0)
        self.recent[key] = (model, candidates)
        self.recent_bytes[key] = _footprint(model, candidates)
        self.recent_total += self.recent_bytes[key]
        while self.recent and self.recent_total > RECENT_OBJECT_BYTES:
            oldest, _ = self.recent.popitem(last=False)
            self.recent_total -= self.recent_bytes.pop(oldest)

    def _forget_recent(self) -> None:
        self.recent.clear()
        self.recent_bytes.clear()
        self.recent_total = 0

    def prepare(self, task: SpanTask) -> SpanResult:
        """A decomposition task (``task.span`` a :class:`Prepare`): load the object (its collision
        shape made and cached unless the cache holds it), keep it for this worker's spans of it and
        label the task's first span. Returns what was found (:class:`PreparedObject`) with the first
        span's rows, or the object's one-line error."""
        t0, cpu0 = time.perf_counter(), cpu_seconds()
        watch_parent(task.parent_pid, task.status_dir)
        unit = task.span
        assert isinstance(unit, Prepare)  # label() sends it only these
        try:
            self.begin(task)
            key = self._key(task)
            if key in self.failed:
                raise ObjectError(self.failed[key])
            made = False
            if self.obj is not None and self.obj.key == key:
                model = self.obj.model
            else:
                kept, candidates = self._kept(key)
                if kept is None:
                    model, candidates = self._load(task, key), {}
                    made = not model.from_cache
                else:
                    model = kept
                self._keep(key, model, candidates)
        except Exception as exc:
            return self._failed(task, exc, t0)
        finally:
            status.write(task.status_dir, None)
        prepared = PreparedObject.of(model, made, cpu_seconds() - cpu0)
        if unit.first is None:
            return SpanResult(unit, None, None, task_stats(t0, 0.0), prepared=prepared)
        # the object's first span, here, where the object is loaded
        first = self.label(dataclasses.replace(task, span=unit.first))
        stats = task_stats(t0, first.stats.step_seconds)
        return SpanResult(unit, first.rows, first.error, stats, first.info, first.artifacts, prepared)

    def _create(self, model: ObjectModel, key: tuple, candidates: dict, mode: ObjectMode) -> LoadedObject:
        """The object's body in ``mode``'s world, placed in the mode (its trial, or its placements
        on the table)."""
        world, hand = mode.world, mode.hand
        physics = physics_for(model, mode.config.physics)  # a light object needs a finer time step
        if world.physics != physics:
            world.physics = physics
            world.configure()
        hand.teleport(PARKED, hand.gripper.max_width)
        uid = create_body(world.client, model)
        try:
            placed = mode.place(model, uid)
        except ObjectError as exc:  # no stable placement on the table
            world.remove_body(uid)
            self.failed[key] = str(exc)
            raise
        except BaseException:
            world.remove_body(uid)
            raise
        return LoadedObject(key, model, uid, placed, candidates)

    # --- a span ---------------------------------------------------------------------------------

    def label(self, task: Task) -> SpanResult:
        """Labels of one span (of an object or a scene), or its unit's one-line error (a
        :class:`Prepare`: :meth:`prepare`)."""
        if isinstance(task, SpanTask) and isinstance(task.span, Prepare):
            return self.prepare(task)
        t0 = time.perf_counter()
        watch_parent(task.parent_pid, task.status_dir)
        try:
            unit = self.begin(task).load(self, task)
        except Exception as exc:
            return self._failed(task, exc, t0)
        labelled = unit.label(task)
        stats = task_stats(t0, labelled.step_seconds)
        status.write(task.status_dir, None)
        return SpanResult(task.span, labelled.rows, None, stats, labelled.info, labelled.artifacts)

    @staticmethod
    def _failed(task: Task, exc: Exception, t0: float) -> SpanResult:
        """The unit's one-line error: an ObjectError's text (an object's names it; a scene's is
        prefixed with the scene), or an unexpected failure's type and text (the unit's, not the
        run's)."""
        unit = task.span
        if isinstance(exc, ObjectError):
            error = str(exc)
        else:
            log.exception("%s: unexpected error while loading", unit.object_id)
            error = f"{type(exc).__name__}: {exc}"
        if isinstance(task, SceneTask):
            error = f"{unit.object_id}: {error}"
        info = {UNUSABLE_OBJECT: exc.object_id} if isinstance(exc, UnusableObject) else None
        return SpanResult(unit, None, error, task_stats(t0, 0.0), info)


class _State:
    """The one WorkerState of this process (created on first use in a worker)."""

    instance: WorkerState | None = None


def worker_state() -> WorkerState:
    if _State.instance is None:
        _State.instance = WorkerState()
    return _State.instance


def label_span(task: Task) -> SpanResult:
    """Entry point of a worker process (loky or Dask): label one span (of an object or a scene), or
    run an object's decomposition task, with this process's state."""
    return worker_state().label(task)


def max_width(config: AnnotatorConfig, gripper: GripperDescription | str | None = None) -> float:
    """The gripper's stroke from its model's FK (default the RG2; a throwaway DIRECT client)."""
    from annotator.sim.hand import FloatingGripper
    from annotator.sim.world import World

    with World(config.physics) as world:
        return FloatingGripper(world, config.gripper, gripper).gripper.max_width
