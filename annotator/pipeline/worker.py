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
import socket
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from annotator.config import AnnotatorConfig
from annotator.dataset import Outcome
from annotator.geometry import Transform, matrix_to_quat
from annotator.grippers import DEFAULT_GRIPPER, GripperDescription, GripperFiles, resolve_gripper
from annotator.objects import (
    ObjectError,
    ObjectModel,
    ObjectSource,
    create_body,
    load_object,
    physics_for,
)
from annotator.pipeline import status
from annotator.rng import object_rng, trial_rng
from annotator.sampler import Candidates, sample_candidates
from annotator.store.manifest import bound_versions
from annotator.trial import GraspTrial, Perturbation

if TYPE_CHECKING:
    from annotator.cell.batch import CellObject, CellWorlds
    from annotator.cell.resting import RestingObject, RestingWorld

log = logging.getLogger(__name__)

# How often (s) a local worker checks that the process that started it is still alive and has not
# asked it to stop: a worker outlives a killed or interrupted main process by at most this long.
PARENT_CHECK_SECONDS = 0.2
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


@dataclass(frozen=True)
class GivenGrasps:
    """Poses to simulate instead of sampled candidates (``evaluate``, benches, tests).

    T_obj_tcp : (k, 4, 4) float, TCP poses in the object's mesh frame; width : (k,) float, the
    expected chord between the contacts (m). quat : (k, 4) float xyzw or None: the rotations bit
    for bit (a label's ``cmd_q*`` replayed exactly); without it they come from ``T_obj_tcp``.
    rest_quat : (k, 4) float xyzw or None: with ``--resting``, the orientation each grasp's object
    rests in on the table (its mesh frame in the table frame); None: the mesh frame's own, +z up.
    """

    T_obj_tcp: np.ndarray
    width: np.ndarray
    quat: np.ndarray | None = None
    rest_quat: np.ndarray | None = None


@dataclass(frozen=True)
class SpanGrasps:
    """The grasps a worker simulates for one span: as :class:`GivenGrasps`, plus ``placements``
    (k,) int, the cell placement each sampled candidate rests in (None: not in the cell)."""

    T_obj_tcp: np.ndarray
    width: np.ndarray
    quat: np.ndarray | None = None
    placements: np.ndarray | None = None
    rest_quat: np.ndarray | None = None


@dataclass(frozen=True)
class Span:
    """A unit of work: candidates ``start..stop-1`` of one object (or ``given`` poses, numbered so)."""

    object_id: str
    source: ObjectSource
    scale: float | None
    start: int
    stop: int
    given: GivenGrasps | None = None

    @property
    def size(self) -> int:
        return self.stop - self.start

    @property
    def key(self) -> tuple[str, int]:
        return (self.object_id, self.start)

    def describe(self) -> str:
        """What a worker does with it, for a reason: ``simulating candidates 0-9``."""
        return f"simulating candidates {self.start}-{self.stop - 1}"


@dataclass(frozen=True)
class Prepare:
    """A decomposition task: load one object in a worker, ahead of its spans, so that its collision
    shape is made (and written to the cache) once, by one worker, while other workers label.

    A worker that runs it keeps the model for its own spans of the object; every other worker
    reads the shape from the cache. It simulates nothing (``size`` 0); its result carries a
    :class:`PreparedObject`, or the object's one-line error (an unusable mesh).
    """

    object_id: str
    source: ObjectSource
    scale: float | None

    size = 0

    @property
    def key(self) -> tuple[str, int]:
        return (self.object_id, -1)  # before the object's spans

    def describe(self) -> str:
        return "loading (decomposing) the object"


@dataclass(frozen=True)
class CellOptions:
    """``annotate --cell``: objects rest on the seed's table; ``views`` Kinect views per placement."""

    views: int = 0

    def to_json(self) -> dict[str, Any]:
        """What the manifest binds (RunSpec.inputs['cell'])."""
        return {"views": int(self.views)}


@dataclass(frozen=True)
class SpanTask:
    """What a worker is asked to do (``span``: a :class:`Span` to label, or a :class:`Prepare`), with
    what it needs to check that it may.

    ``source_sha256``: the object's source digest (a worker keeps a loaded object only while it is
    the same); ``versions``: the label-shaping versions the run expects (a cluster worker with
    others fails the span instead of mixing); ``parent_pid``: the local main process (a worker
    exits when it dies), None on a cluster; ``status_dir``: where a local worker says what it is
    doing; ``cache_dir``: the decomposition cache the main process chose (None: the worker's
    default, as on a cluster); ``cell``: label in the robot cell (None: the floating gripper);
    ``gripper``: the gripper simulated (None: the default, the RG2), or its files
    (:class:`annotator.grippers.GripperFiles`, a run on a cluster: unpacked into the worker's cache);
    ``resting``: the object rests on the cell's table while the given grasps close (``evaluate
    --resting``, :mod:`annotator.cell.resting`): True or ``"object"``, the grasps move with it as it
    settles; ``"table"``, they stay where they were given in the table frame.
    """

    span: Span | Prepare
    config: AnnotatorConfig
    seed: int
    n: int
    trials: int = 1
    source_sha256: str | None = None
    versions: dict[str, str] | None = None
    parent_pid: int | None = None
    status_dir: str | None = None
    cache_dir: str | None = None
    cell: CellOptions | None = None
    gripper: GripperDescription | GripperFiles | None = None
    resting: bool | str = False


@dataclass(frozen=True)
class WorkerStats:
    """Worker time of one span (s), of which inside stepSimulation, peak memory (MB), the worker."""

    seconds: float
    step_seconds: float
    peak_rss_mb: float
    pid: int
    host: str


@dataclass(frozen=True)
class PreparedObject:
    """What a decomposition task (:class:`Prepare`) reports about its object.

    ``method``: the collision method (hull, shells, coacd, vhacd); ``parts``: convex parts;
    ``made``: the collision shape was made by this task (False: read from the cache, or held by the
    worker already); ``decomposition_cpu_s``: CPU seconds of the decomposition ladder when it ran
    (0 otherwise); ``cpu_s``: CPU seconds of the whole load in the worker (its process and the
    decomposition processes it waited for); ``error_mean`` / ``error_max``: collision error (m);
    ``warnings``: the object's warnings, one line each, without its id.
    """

    method: str
    parts: int
    made: bool
    decomposition_cpu_s: float
    cpu_s: float
    error_mean: float
    error_max: float
    ladder: str = ""
    warnings: tuple[str, ...] = ()

    @classmethod
    def of(cls, model: ObjectModel, made: bool, cpu_s: float) -> PreparedObject:
        err = model.collision_error
        return cls(
            model.collision_method,
            len(model.parts),
            made,
            float(model.decomposition_seconds) if made else 0.0,
            cpu_s,
            float(err.mean),
            float(err.max),
            model.collision_ladder,
            tuple(model.warnings),
        )

    @property
    def decomposed(self) -> bool:
        """Its shape was made by the decomposition ladder in this task (not a hull or the shells
        of a convex object, not read from the cache)."""
        return self.made and bool(self.ladder)

    def line(self) -> str:
        """One line, e.g. ``decomposed by coacd into 34 parts in 14.2 CPU-s (collision error 0.15 /
        1.82 mm)``."""
        plural = "s" if self.parts != 1 else ""
        if self.decomposed:
            how = (
                f"decomposed by {self.method} into {self.parts} part{plural} in "
                f"{self.decomposition_cpu_s:.1f} CPU-s"
            )
        else:
            how = f"{self.method}, {self.parts} part{plural}" + ("" if self.made else ", from the cache")
        return f"{how} (collision error {self.error_mean * 1e3:.2f} / {self.error_max * 1e3:.2f} mm)"


@dataclass(frozen=True)
class SpanResult:
    """A span's labels (``rows``), or the object's one-line ``error``; ``info`` describes the object
    as simulated (mass, scale, ...) for the manifest; ``artifacts``: files that belong with the
    span's labels (file name -> bytes: the Kinect views it rendered), written by the main process;
    ``prepared``: what a decomposition task (``span`` a :class:`Prepare`) found."""

    span: Span | Prepare
    rows: pd.DataFrame | None
    error: str | None
    stats: WorkerStats
    info: dict[str, Any] | None = None
    artifacts: dict[str, bytes] | None = None
    prepared: PreparedObject | None = None


@dataclass
class LoadedObject:
    """The object a worker has in its world: model, body, trial runner, sampled candidates;
    ``cell``: its placements on the table (``--cell``), whose trials replace ``trial``;
    ``resting``: the object resting on the table in the orientations given (``evaluate --resting``),
    whose trials replace ``trial`` (then None)."""

    key: tuple
    model: ObjectModel
    uid: int
    trial: GraspTrial | None
    candidates: dict[tuple[int, int], Candidates] = field(default_factory=dict)  # (seed, n) -> ...
    cell: CellObject | None = None
    resting: RestingObject | None = None

    def release(self) -> None:
        """Free its snapshots (and the cell's copy of it); the trial world's body is the caller's."""
        if self.cell is not None:
            self.cell.close()
        elif self.resting is not None:
            self.resting.close()
        elif self.trial is not None:
            self.trial.close()


def _footprint(model: ObjectModel, candidates: dict[tuple[int, int], Candidates]) -> int:
    """About how many bytes a kept object holds: its mesh and collision parts, its candidates."""
    faces = len(model.mesh.faces) + sum(len(part.faces) for part in model.parts)
    arrays = (v for c in candidates.values() for v in vars(c).values() if isinstance(v, np.ndarray))
    return BYTES_PER_FACE * faces + sum(a.nbytes for a in arrays)


def _cpu_seconds() -> float:
    """CPU seconds of this process and of the children it waited for (the decompositions)."""
    import resource

    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def _peak_rss_mb() -> float:
    """This process's peak resident memory (MB); 0 where the platform does not say."""
    try:
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux
    except (ImportError, OSError):  # pragma: no cover - Windows
        return 0.0


def _canonical(q: np.ndarray) -> np.ndarray:
    return -q if q[3] < 0 else q


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
        self.cell: CellWorlds | None = None  # the table and the arm world, --cell only
        self.resting: RestingWorld | None = None  # the table, evaluate --resting only
        self.obj: LoadedObject | None = None
        # objects this world had: key -> (model, its candidates by (seed, n)), most recent last
        self.recent: OrderedDict[tuple, tuple[ObjectModel, dict]] = OrderedDict()
        self.failed: dict[tuple, str] = {}  # object key -> its error (other spans fail at once)
        self._watched_parent: int | None = None
        self._stop_folder: str | None = None
        self._versions_ok: dict[str, str] | None = None

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
            gripper = resolve_gripper(gripper, cache_dir)
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
            if cell:
                from annotator.cell.batch import CellWorlds

                self.cell = CellWorlds(self.world, self.hand, config)
            elif resting:
                from annotator.cell.resting import RestingWorld

                self.resting = RestingWorld(self.world, self.hand, config, resting)
            self.config = config
            self.mode = (cell, resting)
            if previous != kept:  # the keys do not hold the configuration
                self.failed = {}
                self.recent.clear()
        return self.world, self.hand

    def close(self) -> None:
        if self.cell is not None:
            self.cell.close()
        if self.world is not None:
            self.world.close()
        self.world = self.hand = self.obj = self.cell = self.resting = None

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
        t0, cpu0 = time.perf_counter(), _cpu_seconds()
        self._watch_parent(task.parent_pid, task.status_dir)
        unit = task.span
        try:
            self._check_versions(task.versions)
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
            return SpanResult(unit, None, str(exc), self._stats(t0, 0.0))
        except Exception as exc:  # an unexpected failure is this object's, not the run's
            log.exception("%s: unexpected error while loading", unit.object_id)
            return SpanResult(unit, None, f"{type(exc).__name__}: {exc}", self._stats(t0, 0.0))
        finally:
            status.write(task.status_dir, None)
        prepared = PreparedObject.of(model, made, _cpu_seconds() - cpu0)
        return SpanResult(unit, None, None, self._stats(t0, 0.0), prepared=prepared)

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
        if self.resting is not None:
            return LoadedObject(key, model, uid, None, candidates, resting=self.resting.load(model, uid))
        if self.cell is None:
            world.set_gravity(False)
            return LoadedObject(key, model, uid, GraspTrial(world, hand, uid, config), candidates)
        try:
            placed = self.cell.load(model, uid)
        except ObjectError as exc:
            world.remove_body(uid)
            self.failed[key] = str(exc)
            raise
        except BaseException:
            world.remove_body(uid)
            raise
        return LoadedObject(key, model, uid, placed.trials[0], candidates, cell=placed)

    def candidates(self, loaded: LoadedObject, seed: int, n: int, config: AnnotatorConfig) -> Candidates:
        """The object's N candidates, sampled once per (seed, N) and kept."""
        cands = loaded.candidates.get((seed, n))
        if cands is None:
            if loaded.cell is not None:  # per placement, knowing the table
                cands = loaded.cell.candidates(n, seed)
            else:
                cands = object_candidates(loaded.model, n, seed, config, self.hand.gripper.max_width)
            loaded.candidates[(seed, n)] = cands
        return cands

    # --- a span ---------------------------------------------------------------------------------

    def label(self, task: SpanTask) -> SpanResult:
        """Labels of one span, or its object's one-line error (a :class:`Prepare`: :meth:`prepare`)."""
        if isinstance(task.span, Prepare):
            return self.prepare(task)
        t0 = time.perf_counter()
        self._watch_parent(task.parent_pid, task.status_dir)
        span = task.span
        try:
            self._check_versions(task.versions)
            loaded = self.object_for(task)
            grasps = self._grasps(task, loaded)
        except ObjectError as exc:
            return SpanResult(span, None, str(exc), self._stats(t0, 0.0))
        except Exception as exc:  # an unexpected failure is this object's, not the run's
            log.exception("%s: unexpected error while loading", span.object_id)
            return SpanResult(span, None, f"{type(exc).__name__}: {exc}", self._stats(t0, 0.0))
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
        )
        artifacts = None
        if task.cell is not None and task.cell.views > 0 and loaded.cell is not None:
            # placement p's views come with the span holding grasp min(p, N - 1): exactly one span
            # renders each placement, whatever the spans are (the first, unless P > chunk size)
            artifacts = {}
            for p in range(len(loaded.cell.placements)):
                if span.start <= min(p, task.n - 1) < span.stop:
                    status.write(task.status_dir, f"rendering {span.object_id}")
                    artifacts.update(loaded.cell.render_views(p, task.cell.views, task.seed))
        stats = self._stats(t0, world.step_seconds - steps0)
        status.write(task.status_dir, None)
        info = object_info(loaded.model)
        if loaded.cell is not None:
            info["placements"] = [
                {
                    "placement_id": p.placement_id,
                    "stable_pose": p.pose_index,
                    "probability": float(p.probability),
                    "settle_drift": float(p.drift),
                }
                for p in loaded.cell.placements
            ]
        return SpanResult(span, rows, None, stats, info, artifacts)

    def _grasps(self, task: SpanTask, loaded: LoadedObject) -> SpanGrasps:
        """What the span simulates: its share of the object's sampled candidates, or its given grasps."""
        span = task.span
        if span.given is not None:
            g = span.given
            if loaded.resting is None and g.rest_quat is not None:
                raise ObjectError("grasps given with resting orientations, but the run is not --resting")
            return SpanGrasps(g.T_obj_tcp, g.width, g.quat, None, g.rest_quat)
        if loaded.resting is not None:
            raise ObjectError("--resting simulates given grasps only")
        cands = self.candidates(loaded, task.seed, task.n, task.config)
        placements = None if cands.placement is None else cands.placement[span.start : span.stop]
        return SpanGrasps(
            cands.T_obj_tcp[span.start : span.stop],
            cands.width_expected[span.start : span.stop],
            None,
            placements,
        )

    def _stats(self, t0: float, step_seconds: float) -> WorkerStats:
        seconds = time.perf_counter() - t0
        return WorkerStats(seconds, step_seconds, _peak_rss_mb(), os.getpid(), socket.gethostname())

    def _check_versions(self, expected: dict[str, str] | None) -> None:
        if expected is None or self._versions_ok == expected:
            return
        mine = bound_versions()
        diffs = [f"{k} {mine.get(k)} (run: {v})" for k, v in sorted(expected.items()) if mine.get(k) != v]
        if diffs:
            raise ObjectError(f"worker on {socket.gethostname()} has other versions: {', '.join(diffs)}")
        self._versions_ok = expected

    def _watch_parent(self, parent_pid: int | None, status_dir: str | None) -> None:
        """End this worker's process soon after the local main process is gone (killed, even by
        SIGKILL) or has asked its workers to stop (:func:`status.request_stop`, on Ctrl-C/SIGTERM)."""
        self._stop_folder = status_dir  # the current run's; a reused worker serves several runs
        if parent_pid is None or self._watched_parent == parent_pid:
            return
        self._watched_parent = parent_pid

        def watch() -> None:
            while True:
                time.sleep(PARENT_CHECK_SECONDS)
                if os.getppid() != parent_pid or status.stop_requested(self._stop_folder):
                    os._exit(0)

        threading.Thread(target=watch, name="rg2-parent-watch", daemon=True).start()


def object_candidates(model: ObjectModel, n: int, seed: int, config: AnnotatorConfig, max_width: float):
    """The object's N candidates: the same for every worker (Generator keyed on seed and id)."""
    return sample_candidates(model.mesh, n, object_rng(seed, model.object_id), config.sampler, max_width)


def simulate(
    loaded: LoadedObject,
    T_obj_tcp: np.ndarray,
    widths: np.ndarray,
    first_id: int,
    config: AnnotatorConfig,
    seed: int,
    trials: int,
    object_id: str,
    quats: np.ndarray | None = None,
    *,
    placements: np.ndarray | None = None,
    rest_quats: np.ndarray | None = None,
    gripper: str = DEFAULT_GRIPPER,
) -> pd.DataFrame:
    """Label rows of poses ``T_obj_tcp`` (k, 4, 4) with expected chords ``widths`` (k,), numbered
    from ``first_id``; ``quats`` (k, 4): their rotations bit for bit (see :class:`GivenGrasps`);
    ``placements`` (k,): in the cell, the placement each was sampled for (None: the placement
    where it approaches most from above, :meth:`annotator.cell.batch.CellObject.placement_for`);
    ``rest_quats`` (k, 4): resting (``loaded.resting``), the orientation each grasp's object rests
    in (None: upright); ``gripper``: the name written in every row's ``gripper`` column.

    Trial 0 of each candidate is unperturbed and gives ``success``, ``outcome``, ``width`` and the
    pose; trials 1..K-1 are perturbed from the candidate's own Generator (``trial_rng``) and
    ``score`` is the fraction of all K trials that held. A candidate whose unperturbed pose
    collides is never simulated: its score is 0 and no perturbed trial runs (the pose as given
    cannot be executed).
    """
    model = loaded.model
    mapping = config.confidence.mapping()  # a calibration: rows carry p_success
    if mapping is not None and mapping.trials != trials:
        raise ValueError(f"[confidence] fitted on --trials {mapping.trials} scores; this run has {trials}")
    rows = []
    # the rotations of all poses in one batch: row for row the floats of Transform.from_matrix
    sampled_quats = (
        matrix_to_quat(np.asarray(T_obj_tcp)[:, :3, :3]) if quats is None and len(widths) else None
    )
    for k in range(len(widths)):
        grasp_id = first_id + k
        if sampled_quats is not None:
            T = Transform(T_obj_tcp[k][:3, 3], sampled_quats[k])
        else:  # a recorded commanded pose: the very transform of the trial that recorded it
            T = Transform.exact(T_obj_tcp[k][:3, 3], quats[k])
        width_expected = float(widths[k])
        rest = None if loaded.resting is None else (UPRIGHT if rest_quats is None else rest_quats[k])
        trial, placement = _trial_for(loaded, T, None if placements is None else int(placements[k]), rest)
        run_T = T if loaded.resting is None else loaded.resting.grasp(rest, T)
        result = _run_trials(trial, run_T, width_expected, config, seed, trials, object_id, grasp_id)
        row = _row(result, T, width_expected, model, seed, object_id, grasp_id, gripper, trials, mapping)
        rows.append(row)
        if loaded.cell is not None:  # placement, object pose on the table, reachability
            rows[-1].update(loaded.cell.columns(placement, T, width_expected, grasp_id))
        elif loaded.resting is not None:  # the object's settled pose on the table
            rows[-1].update(loaded.resting.columns(rest))
    return pd.DataFrame(rows)


# The orientation an object rests in when none is given: its mesh frame's own (+z up), xyzw.
UPRIGHT = np.array([0.0, 0.0, 0.0, 1.0])


def _trial_for(
    loaded: LoadedObject, T: Transform, placement: int | None, rest: np.ndarray | None
) -> tuple[GraspTrial, int]:
    """The trial a grasp runs in, and its cell placement (0 outside the cell)."""
    if loaded.resting is not None:
        return loaded.resting.trial_for(rest)[0], 0
    if loaded.cell is None:
        assert loaded.trial is not None
        return loaded.trial, 0
    if placement is None:  # a given grasp: where it comes most from above
        placement = loaded.cell.placement_for(T)
    return loaded.cell.trials[placement], placement  # else the placement it was sampled for


@dataclass(frozen=True)
class _Trials:
    """What a candidate's trials gave: trial 0's outcome, pose, width and slip; all steps; how many held."""

    outcome: Outcome
    T_label: Transform
    width: float
    steps: int
    slip: float
    held: int


def _run_trials(
    trial: GraspTrial,
    T: Transform,
    width_expected: float,
    config: AnnotatorConfig,
    seed: int,
    trials: int,
    object_id: str,
    grasp_id: int,
) -> _Trials:
    """Trial 0 unperturbed, then the perturbed ones (none after a collision); a physics failure is
    an ``error`` row, never the loss of the other candidates."""
    try:
        r = trial.run(T, width_expected)
        held = int(r.outcome == Outcome.SUCCESS)
        steps = r.steps
        if r.outcome != Outcome.COLLISION and trials > 1:
            rng = trial_rng(seed, object_id, grasp_id)
            for _ in range(trials - 1):
                p = trial.run(T, width_expected, Perturbation.sample(rng, config.robust))
                held += int(p.outcome == Outcome.SUCCESS)
                steps += p.steps
        return _Trials(r.outcome, r.T_obj_tcp, r.width, steps, r.slip, held)
    except Exception as exc:  # a physics failure on one candidate must not lose the others
        log.warning("%s grasp %d: %s: %s", object_id, grasp_id, type(exc).__name__, exc)
        return _Trials(Outcome.ERROR, T, width_expected, 0, np.nan, 0)


def _row(
    r: _Trials,
    T: Transform,
    width_expected: float,
    model: ObjectModel,
    seed: int,
    object_id: str,
    grasp_id: int,
    gripper: str,
    trials: int,
    mapping=None,
) -> dict[str, Any]:
    """One label row (the columns of docs/labels.md, in their order); with a confidence
    ``mapping`` (annotator.confidence.Mapping) also ``p_success``."""
    return {
        "object_id": object_id,
        "grasp_id": grasp_id,
        **dict(zip(("x", "y", "z"), r.T_label.pos.tolist(), strict=True)),
        **dict(zip(("qx", "qy", "qz", "qw"), _canonical(r.T_label.quat).tolist(), strict=True)),
        "width": r.width,
        "success": r.outcome == Outcome.SUCCESS,
        "outcome": r.outcome.label,
        "score": r.held / trials,
        "object_scale": model.scale,
        "mesh_sha256": model.mesh_sha256,
        "seed": seed,
        "sim_steps": r.steps,
        "slip": r.slip,
        "object_mass": model.mass,
        # the commanded grasp: the TCP pose the gripper was placed at before closing (quaternion
        # as simulated, not sign-canonicalised) and the expected chord the close started
        # from; ``evaluate`` replays a label exactly from these
        **dict(zip(("cmd_x", "cmd_y", "cmd_z"), T.pos.tolist(), strict=True)),
        **dict(zip(("cmd_qx", "cmd_qy", "cmd_qz", "cmd_qw"), T.quat.tolist(), strict=True)),
        "cmd_width": width_expected,
        # distance between the simulated collision shape and the mesh surface (m)
        "collision_error": model.collision_error.max,
        "collision_error_mean": model.collision_error.mean,
        "gripper": gripper,  # the gripper description's name (docs/grippers.md)
        # P(the real grasp holds) of this score, [confidence] (annotator/confidence.py)
        **({} if mapping is None else {"p_success": float(mapping.p_success(r.held / trials))}),
    }


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
