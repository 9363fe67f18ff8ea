"""The worker side of the job: one state per process (:class:`WorkerState`), its mode's strategy
with its world (:mod:`annotator.pipeline.strategies`), objects kept on demand
(:mod:`annotator.pipeline.object_cache`), spans labelled. The main process imports only this
module's entry point, :func:`label_span`; the tasks and results are :mod:`annotator.pipeline.tasks`.

Every task (a :class:`SpanTask` of an object, a :class:`SceneTask` of a scene) runs through
:meth:`WorkerState.label`, which makes the checks a task needs once for every mode (the parent
watch, the label-shaping versions, the gripper resolved in the cache), builds the task's mode's
strategy when it is not the one the worker holds
(:func:`annotator.pipeline.strategies.build_strategy`), has the strategy load the task's unit and
the unit label the span, and turns a unit's error into the span's one-line error.

A worker builds its world once and keeps it between spans. Before any span of an object, one worker
runs the object's decomposition task (:class:`Prepare`): it loads the object, which makes its
collision shape and writes it to the content-addressed cache unless the cache holds it already,
and keeps the model for its own spans of it. When a span of an object arrives the worker takes the
object it keeps, or loads it (the collision shape from the cache), samples its N candidates (the
same on every worker: the Generator is keyed on seed and object id) and creates its body. Each
candidate starts from a restored snapshot with no contact memory
(:meth:`annotator.sim.world.World.restore_state`), so a label depends only on (object, seed,
candidate), never on which worker ran it or what it ran before.

With ``--cell`` (:class:`annotator.pipeline.modes.CellMode`) the world also holds the seed's
table, the object rests on it in its placements and each row gains the cell's columns
(annotator.cell.batch); with
``--views K`` the span holding grasp ``p`` also renders placement ``p``'s K Kinect views, returned
as files for the main process to write. A scene's span (:mod:`annotator.pipeline.scene_mode`)
builds or takes its scene and labels its grasps.
"""

from __future__ import annotations

import dataclasses
import logging
import time

from annotator.config import AnnotatorConfig
from annotator.grippers import GripperDescription, GripperFiles, resolve_gripper
from annotator.objects import ObjectError, default_cache_dir
from annotator.pipeline import status
from annotator.pipeline.object_cache import ObjectCache
from annotator.pipeline.process import check_versions, cpu_seconds, current_watch, task_stats, watch_parent
from annotator.pipeline.strategies import Strategy, build_strategy
from annotator.pipeline.tasks import (
    UNUSABLE_OBJECT,
    Call,
    Performed,
    Prepare,
    PreparedObject,
    SceneTask,
    SpanResult,
    SpanTask,
    UnusableObject,
)

log = logging.getLogger(__name__)

Task = SpanTask | SceneTask


class WorkerState:
    """This process's strategy with its world and gripper, built on first use and kept between
    tasks, and its objects (one :class:`annotator.pipeline.object_cache.ObjectCache` for every
    mode); the one place the checks every task needs are made (:meth:`label`)."""

    def __init__(self) -> None:
        self.config: AnnotatorConfig | None = None
        self.gripper: GripperDescription | None = None  # the gripper of the strategy built, resolved
        self.strategy: Strategy | None = None  # the task's mode's strategy with its world
        self.objects = ObjectCache()

    # --- the checks and the strategy --------------------------------------------------------------

    def begin(self, task: Task) -> Strategy:
        """The checks before a task (its label-shaping versions: ObjectError when they are not the
        run's) and its mode's strategy (:meth:`strategy_for`)."""
        check_versions(task.versions)
        return self.strategy_for(task)

    def gripper_for(self, task: Task) -> GripperDescription:
        """The task's gripper, frozen in the cache (:func:`annotator.grippers.resolve_gripper`):
        the files a cluster's main process sent are unpacked once and then taken as held."""
        gripper = task.gripper
        if isinstance(gripper, GripperFiles) and self.gripper is not None and gripper.key == self.gripper.key:
            return self.gripper  # unpacked already
        return resolve_gripper(gripper, task.cache_dir if task.cache_dir is not None else default_cache_dir())

    def strategy_for(self, task: Task) -> Strategy:
        """The task's mode's strategy with its world (rebuilt only when the config, the gripper or
        the mode's world changes: a floating world never holds the table). The objects stay."""
        config, mode = task.config, task.mode
        gripper = self.gripper_for(task)
        changed = self.config != config or self.gripper is None or self.gripper.key != gripper.key
        if changed or self.strategy is None or self.strategy.world_key != mode.world():
            self.close()
            self.strategy = build_strategy(mode, config, gripper)
            self.config, self.gripper = config, gripper
        return self.strategy

    def close(self) -> None:
        """Free the strategy and its world (the objects kept in memory stay)."""
        if self.strategy is not None:
            self.strategy.close()
        self.strategy = None

    # --- a task ---------------------------------------------------------------------------------

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
            got = self.objects.of(task)
        except Exception as exc:
            return self._failed(task, exc, t0)
        finally:
            status.write(task.status_dir, None)
        made = got.loaded and not got.model.from_cache
        prepared = PreparedObject.of(got.model, made, cpu_seconds() - cpu0)
        if unit.first is None:
            return SpanResult(unit, None, None, task_stats(t0, 0.0), prepared=prepared)
        # the object's first span, here, where the object is loaded
        first = self.label(dataclasses.replace(task, span=unit.first))
        stats = task_stats(t0, first.stats.step_seconds)
        return SpanResult(unit, first.rows, first.error, stats, first.info, first.artifacts, prepared)

    def label(self, task: Task) -> SpanResult:
        """Labels of one span (of an object or a scene), or its unit's one-line error (a
        :class:`Prepare`: :meth:`prepare`)."""
        if isinstance(task, SpanTask) and isinstance(task.span, Prepare):
            return self.prepare(task)
        t0 = time.perf_counter()
        watch_parent(task.parent_pid, task.status_dir)
        try:
            unit = self.begin(task).load(self.objects, task)
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
            log.exception("%s: unexpected error while loading", unit.unit_id)
            error = f"{type(exc).__name__}: {exc}"
        if isinstance(task, SceneTask):
            error = f"{unit.unit_id}: {error}"
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


def label_span_within(task: SpanTask) -> SpanResult:
    """:func:`label_span` of a span that a :class:`Call`'s function labels within its task (a bench
    timing the span in the worker): the span keeps the call's watch on the main process and its stop
    folder (:func:`~annotator.pipeline.process.current_watch`), which a task built before the run
    does not carry, so a stop request reaches it as it reaches the call."""
    parent_pid, stop_folder = current_watch()
    return label_span(dataclasses.replace(task, parent_pid=parent_pid, status_dir=stop_folder))


def perform(call: Call) -> Performed:
    """Entry point of a worker process for a :class:`Call` (:mod:`annotator.pipeline.in_memory`):
    the checks every task gets (the watch on the main process, the label-shaping versions: an
    ObjectError when they are not the run's), then the call; what it raises comes back with it."""
    watch_parent(call.parent_pid, call.status_dir)
    try:
        check_versions(call.versions)
        return Performed(call.index, call.fn(*call.args))
    except Exception as exc:  # the call's own failure: raised again where the result is taken
        return Performed(call.index, error=exc)
