"""The worker side of the job: one world per process, objects loaded on demand, spans labelled.

A worker builds its world once (PyBullet DIRECT, floating gripper) and keeps it between spans. Before
any span of an object, one worker runs the object's decomposition task (:class:`Prepare`): it loads
the object, which makes its collision shape and writes it to the content-addressed cache unless the
cache holds it already, and keeps the model for its own spans of it. When a span of an object
arrives the worker takes the object it keeps, or loads it (the collision shape from the cache),
samples its N candidates (the same on every worker: the Generator is keyed on seed and object id)
and creates its body. Each candidate starts from a restored snapshot with no contact memory
(:meth:`annotator.sim.world.World.restore_state`), so a label depends only on (object, seed,
candidate), never on which worker ran it or what it ran before.

With ``--cell`` (:class:`CellOptions`) the world also holds the seed's table, the object rests on
it in its placements and each row gains the cell's columns (annotator.cell.batch); with
``--views K`` the span holding grasp ``p`` also renders placement ``p``'s K Kinect views, returned
as files for the main process to write.
"""

from __future__ import annotations

import logging
import os
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from annotator.config import AnnotatorConfig
from annotator.geometry import Transform
from annotator.grippers import GripperDescription, GripperFiles, resolve_gripper
from annotator.objects import (
    ObjectError,
    ObjectModel,
    create_body,
    default_cache_dir,
    load_object,
    physics_for,
)
from annotator.pipeline import status
from annotator.pipeline.modes import UPRIGHT, PlacedObject, WorkerMode, build_mode
from annotator.pipeline.process import check_versions, cpu_seconds, task_stats, watch_parent
from annotator.pipeline.simulate import object_candidates, simulate
from annotator.pipeline.tasks import (
    CellOptions,
    GivenGrasps,
    Prepare,
    PreparedObject,
    Span,
    SpanGrasps,
    SpanResult,
    SpanTask,
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
    "Span",
    "SpanGrasps",
    "SpanResult",
    "SpanTask",
    "WorkerState",
    "WorkerStats",
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


@dataclass
class LoadedObject:
    """The object a worker has in its world: model, body, the object ``placed`` in the worker's
    mode (:mod:`annotator.pipeline.modes`: its trials), sampled candidates by (seed, n)."""

    key: tuple
    model: ObjectModel
    uid: int
    placed: PlacedObject
    candidates: dict[tuple[int, int], Candidates] = field(default_factory=dict)

    def release(self) -> None:
        """Free its trials and snapshots; the trial world's body is the caller's."""
        self.placed.release()


def _footprint(model: ObjectModel, candidates: dict[tuple[int, int], Candidates]) -> int:
    """About how many bytes a kept object holds: its mesh and collision parts, its candidates."""
    faces = len(model.mesh.faces) + sum(len(part.faces) for part in model.parts)
    arrays = (v for c in candidates.values() for v in vars(c).values() if isinstance(v, np.ndarray))
    return BYTES_PER_FACE * faces + sum(a.nbytes for a in arrays)


def object_info(model: ObjectModel) -> dict[str, Any]:
    """What the object was simulated as, for the manifest (JSON-ready)."""
    return {
        "source": str(model.path),
        "scale": float(model.scale),
        "mass": float(model.mass),
        "volume": float(model.volume),
        "mesh_sha256": model.mesh_sha256,
        "watertight": bool(model.watertight),
        "convex": bool(model.convex),
        "parts": len(model.parts),
        "lateral_friction": float(model.friction),
        "collision_error_mean": float(model.collision_error.mean),
        "collision_error_max": float(model.collision_error.max),
        "geometry": model.geometry_record(),  # dataset.load_geometry reads these back
        "warnings": list(model.warnings),  # reported once per object per run
    }


class WorkerState:
    """This process's world, gripper and current object, built on first use and kept between spans."""

    def __init__(self) -> None:
        self.config: AnnotatorConfig | None = None
        self.mode: tuple[bool, str | None] = (False, None)  # (cell, resting mode) of the world built
        self.world = None  # annotator.sim.world.World
        self.hand = None  # annotator.sim.hand.FloatingGripper
        self.gripper_key: tuple[str, str] | None = None  # (name, digest) of the gripper in the world
        self.world_mode: WorkerMode | None = None  # the mode's part of the world (annotator.pipeline.modes)
        self.obj: LoadedObject | None = None
        # objects this world had: key -> (model, its candidates by (seed, n)), most recent last
        self.recent: OrderedDict[tuple, tuple[ObjectModel, dict]] = OrderedDict()
        self.failed: dict[tuple, str] = {}  # object key -> its error (other spans fail at once)

    # --- the world ------------------------------------------------------------------------------

    def world_for(
        self,
        config: AnnotatorConfig,
        cell: bool = False,
        gripper: GripperDescription | GripperFiles | None = None,
        cache_dir: str | None = None,
        resting: bool | str = False,
    ):
        """The world and floating gripper for ``config`` (rebuilt only when the config, the gripper
        or the mode changes: a floating world never holds the table)."""
        from annotator.cell.resting import resting_mode
        from annotator.sim.hand import FloatingGripper
        from annotator.sim.world import World

        resting = resting_mode(resting)

        if isinstance(gripper, GripperFiles) and self.hand is not None and gripper.key == self.gripper_key:
            gripper = self.hand.description  # unpacked already
        else:
            gripper = resolve_gripper(gripper, cache_dir if cache_dir is not None else default_cache_dir())
        changed = self.config != config or self.gripper_key != gripper.key
        if changed or self.mode != (cell, resting) or self.world is None:
            # loaded models and candidates depend on these only: a calibration grid, which changes
            # the gripper's or the protocol's numbers from task to task, keeps them
            kept = (config.objects, config.sampler, config.cell, gripper.key, cell, resting)
            previous = None
            if self.config is not None:
                previous = (self.config.objects, self.config.sampler, self.config.cell, self.gripper_key)
                previous += self.mode
            if previous == kept and self.obj is not None:
                # its model and candidates serve the new world too
                self._keep(self.obj.key, self.obj.model, self.obj.candidates)
            self.close()
            self.world = World(config.physics)
            self.hand = FloatingGripper(self.world, config.gripper, gripper)
            self.gripper_key = gripper.key
            self.world_mode = build_mode((cell, resting), self.world, self.hand, config)
            self.config = config
            self.mode = (cell, resting)
            if previous != kept:  # the keys do not hold the configuration
                self.failed = {}
                self.recent.clear()
        return self.world, self.hand

    def close(self) -> None:
        if self.world_mode is not None:
            self.world_mode.close()
        if self.world is not None:
            self.world.close()
        self.world = self.hand = self.obj = self.world_mode = None

    # --- objects ---------------------------------------------------------------------------------

    def object_for(self, task: SpanTask) -> LoadedObject:
        """The span's object in this world (its body is created once per object); ObjectError."""
        world, _ = self.world_for(
            task.config, task.cell is not None, task.gripper, task.cache_dir, task.resting
        )
        key = self._key(task)
        if key in self.failed:
            raise ObjectError(self.failed[key])
        if self.obj is not None and self.obj.key == key:
            return self.obj
        if self.obj is not None:
            self._keep(self.obj.key, self.obj.model, self.obj.candidates)
            self.obj.release()
            world.remove_body(self.obj.uid)
            self.obj = None
        model, candidates = self._kept(key)
        if model is None:
            model = self._load(task, key)
        self.obj = self._create(model, key, candidates)
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
        if model is not None and model.collision_file is not None and not model.collision_file.exists():
            model, candidates = None, {}  # its collision file left the cache: load it again
        return model, candidates

    def _load(self, task: SpanTask, key: tuple) -> ObjectModel:
        unit, config = task.span, task.config
        status.write(task.status_dir, f"loading {unit.object_id}")
        status_dir = task.status_dir
        try:
            cache = Path(task.cache_dir) if task.cache_dir is not None else None
            return load_object(
                unit.source,
                config.objects,
                scale=unit.scale,
                cache_dir=cache,
                progress=lambda oid, message: status.write(status_dir, f"{oid}: {message}"),
            )
        except ObjectError as exc:
            self.failed[key] = str(exc)
            raise

    def _keep(self, key: tuple, model: ObjectModel, candidates: dict) -> None:
        """Remember an object this worker leaves or prepared (its model and candidates) within the
        memory budget, most recent last."""
        self.recent.pop(key, None)
        self.recent[key] = (model, candidates)
        total = sum(_footprint(*kept) for kept in self.recent.values())
        while self.recent and total > RECENT_OBJECT_BYTES:
            total -= _footprint(*self.recent.popitem(last=False)[1])

    def prepare(self, task: SpanTask) -> SpanResult:
        """A decomposition task (``task.span`` a :class:`Prepare`): load the object (its collision
        shape made and cached unless the cache holds it) and keep it for this worker's spans of it.
        Returns what was found (:class:`PreparedObject`), or the object's one-line error."""
        t0, cpu0 = time.perf_counter(), cpu_seconds()
        watch_parent(task.parent_pid, task.status_dir)
        unit = task.span
        try:
            check_versions(task.versions)
            self.world_for(task.config, task.cell is not None, task.gripper, task.cache_dir, task.resting)
            key = self._key(task)
            if key in self.failed:
                raise ObjectError(self.failed[key])
            made = False
            if self.obj is not None and self.obj.key == key:
                model = self.obj.model
            else:
                model, candidates = self._kept(key)
                if model is None:
                    model, candidates = self._load(task, key), {}
                    made = not model.from_cache
                self._keep(key, model, candidates)
        except ObjectError as exc:
            return SpanResult(unit, None, str(exc), task_stats(t0, 0.0))
        except Exception as exc:  # an unexpected failure is this object's, not the run's
            log.exception("%s: unexpected error while loading", unit.object_id)
            return SpanResult(unit, None, f"{type(exc).__name__}: {exc}", task_stats(t0, 0.0))
        finally:
            status.write(task.status_dir, None)
        prepared = PreparedObject.of(model, made, cpu_seconds() - cpu0)
        return SpanResult(unit, None, None, task_stats(t0, 0.0), prepared=prepared)

    def _create(self, model: ObjectModel, key: tuple, candidates: dict) -> LoadedObject:
        """The object's body in this world, its trial (or its placements on the table)."""
        config = self.config
        world, hand = self.world, self.hand
        physics = physics_for(model, config.physics)  # a light object needs a finer time step
        if world.physics != physics:
            world.physics = physics
            world.configure()
        hand.teleport(PARKED, hand.gripper.max_width)
        uid = create_body(world.client, model)
        assert self.world_mode is not None
        try:
            placed = self.world_mode.place(model, uid)
        except ObjectError as exc:  # no stable placement on the table
            world.remove_body(uid)
            self.failed[key] = str(exc)
            raise
        except BaseException:
            world.remove_body(uid)
            raise
        return LoadedObject(key, model, uid, placed, candidates)

    def candidates(self, loaded: LoadedObject, seed: int, n: int, config: AnnotatorConfig) -> Candidates:
        """The object's N candidates, sampled once per (seed, N) and kept."""
        cands = loaded.candidates.get((seed, n))
        if cands is None:
            cands = loaded.placed.candidates(loaded.model, n, seed, config, self.hand.gripper.max_width)
            loaded.candidates[(seed, n)] = cands
        return cands

    # --- a span ---------------------------------------------------------------------------------

    def label(self, task: SpanTask) -> SpanResult:
        """Labels of one span, or its object's one-line error (a :class:`Prepare`: :meth:`prepare`)."""
        if isinstance(task.span, Prepare):
            return self.prepare(task)
        t0 = time.perf_counter()
        watch_parent(task.parent_pid, task.status_dir)
        span = task.span
        try:
            check_versions(task.versions)
            loaded = self.object_for(task)
            grasps = self._grasps(task, loaded)
        except ObjectError as exc:
            return SpanResult(span, None, str(exc), task_stats(t0, 0.0))
        except Exception as exc:  # an unexpected failure is this object's, not the run's
            log.exception("%s: unexpected error while loading", span.object_id)
            return SpanResult(span, None, f"{type(exc).__name__}: {exc}", task_stats(t0, 0.0))
        status.write(task.status_dir, f"simulating {span.object_id}")
        world = self.world
        assert world is not None and self.hand is not None
        steps0 = world.step_seconds
        rows = simulate(
            loaded,
            grasps.T_obj_tcp,
            grasps.width,
            span.start,
            task.config,
            task.seed,
            task.trials,
            span.object_id,
            grasps.quat,
            placements=grasps.placements,
            rest_quats=grasps.rest_quat,
            gripper=self.hand.description.name,
            reasons=span.given is not None,
        )
        artifacts = None
        if task.cell is not None and task.cell.views > 0:
            views, seed = task.cell.views, task.seed
            artifacts = loaded.placed.views(span.start, span.stop, task.n, views, seed, task.status_dir)
        stats = task_stats(t0, world.step_seconds - steps0)
        status.write(task.status_dir, None)
        info = {**object_info(loaded.model), **loaded.placed.info()}
        return SpanResult(span, rows, None, stats, info, artifacts)

    def _grasps(self, task: SpanTask, loaded: LoadedObject) -> SpanGrasps:
        """What the span simulates: its share of the object's sampled candidates, or its given grasps."""
        span = task.span
        if span.given is not None:
            g = span.given
            if loaded.placed.mode != "resting" and g.rest_quat is not None:
                raise ObjectError("grasps given with resting orientations, but the run is not --resting")
            return SpanGrasps(g.T_obj_tcp, g.width, g.quat, None, g.rest_quat)
        cands = self.candidates(loaded, task.seed, task.n, task.config)
        placements = None if cands.placement is None else cands.placement[span.start : span.stop]
        return SpanGrasps(
            cands.T_obj_tcp[span.start : span.stop],
            cands.width_expected[span.start : span.stop],
            None,
            placements,
        )


class _State:
    """The one WorkerState of this process (created on first use in a worker)."""

    instance: WorkerState | None = None


def worker_state() -> WorkerState:
    if _State.instance is None:
        _State.instance = WorkerState()
    return _State.instance


def label_span(task: SpanTask) -> SpanResult:
    """Entry point of a worker process (loky or Dask): label one span with this process's state."""
    return worker_state().label(task)


def max_width(config: AnnotatorConfig, gripper: GripperDescription | str | None = None) -> float:
    """The gripper's stroke from its model's FK (default the RG2; a throwaway DIRECT client)."""
    from annotator.sim.hand import FloatingGripper
    from annotator.sim.world import World

    with World(config.physics) as world:
        return FloatingGripper(world, config.gripper, gripper).gripper.max_width
