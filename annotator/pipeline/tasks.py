"""What passes between the main process and a worker: units of work (a :class:`Span` of an object's
candidates, a :class:`Prepare` decomposition task, a :class:`SceneSpan` of a scene's grasps), the
task that carries one (:class:`SpanTask`, :class:`SceneTask`: both a :class:`WorkerTask`, what every
task carries for the worker's checks) and what comes back (:class:`SpanResult`). Plain records: they
travel by pickle to local workers and to a Dask cluster.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from annotator.config import AnnotatorConfig
from annotator.grippers import GripperDescription, GripperFiles
from annotator.objects import ObjectError, ObjectModel, ObjectSource
from annotator.pipeline.modes import FloatingMode, Mode, SceneMode
from annotator.store.names import scene_unit

if TYPE_CHECKING:
    from annotator.scenes.records import SceneRecord, SceneSpec


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


@dataclass(frozen=True, kw_only=True)
class SpanGrasps:
    """The grasps a worker simulates for one span: grasps ``first_id``.. of object ``object_id``
    (its store unit id), as :class:`GivenGrasps`, plus ``placements`` (k,) int, the cell placement
    each sampled candidate rests in (None: not in the cell)."""

    object_id: str
    first_id: int
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
    def unit_id(self) -> str:
        """Its object's unit of the store (the object id)."""
        return self.object_id

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
    reads the shape from the cache. ``first``: the object's first span still to do, labelled by the
    same task once the object is loaded (an object of one span is then loaded once, in one task;
    None: the task labels nothing). Its result carries a :class:`PreparedObject` and the first
    span's rows, or the object's one-line error (an unusable mesh).
    """

    object_id: str
    source: ObjectSource
    scale: float | None
    first: Span | None = None

    @property
    def size(self) -> int:
        """Candidates it simulates: its first span's."""
        return 0 if self.first is None else self.first.size

    @property
    def unit_id(self) -> str:
        """Its object's unit of the store (the object id)."""
        return self.object_id

    @property
    def key(self) -> tuple[str, int]:
        return (self.object_id, -1)  # before the object's spans

    def describe(self) -> str:
        text = "loading (decomposing) the object"
        return text if self.first is None else f"{text}, then {self.first.describe()}"


@dataclass(frozen=True, kw_only=True)
class WorkerTask:
    """What every task carries besides its unit, for the worker's checks before it labels
    (:class:`annotator.pipeline.worker.WorkerState`, the one place they are made).

    ``config``: the run's configuration; ``versions``: the label-shaping versions the run expects (a
    cluster worker with others fails the unit instead of mixing); ``parent_pid``: the local main
    process (a worker exits when it dies), None on a cluster; ``status_dir``: where a local worker
    says what it is doing; ``cache_dir``: the decomposition cache the main process chose (None: the
    worker's default, as on a cluster; the gripper's files are unpacked there too); ``gripper``:
    the gripper simulated (None: the default, the RG2), or its files
    (:class:`annotator.grippers.GripperFiles`, a run on a cluster: unpacked into the worker's cache).
    """

    config: AnnotatorConfig
    versions: dict[str, str] | None = None
    parent_pid: int | None = None
    status_dir: str | None = None
    cache_dir: str | None = None
    gripper: GripperDescription | GripperFiles | None = None


@dataclass(frozen=True, kw_only=True)
class SpanTask(WorkerTask):
    """What a worker is asked to do with an object (``span``: a :class:`Span` to label, or a
    :class:`Prepare`), with the run's checks (:class:`WorkerTask`).

    ``seed``, ``n`` candidates per object, ``trials`` per candidate: the run's; ``source_sha256``:
    the object's source digest (a worker keeps a loaded object only while it is the same);
    ``mode``: the mode it labels in (:mod:`annotator.pipeline.modes`: floating, the robot cell,
    resting on the table).
    """

    span: Span | Prepare
    seed: int
    n: int
    trials: int = 1
    source_sha256: str | None = None
    mode: Mode = FloatingMode()


@dataclass(frozen=True, kw_only=True)
class Call(WorkerTask):
    """A module-level function ``fn`` to run on ``args`` in a worker, after the checks every task
    gets (:class:`WorkerTask`): what in-memory work that is not a labelling span runs (a clutter
    removal round). ``index``: its position among the tasks of its run."""

    fn: Callable[..., Any]
    args: tuple[Any, ...] = ()
    index: int = 0


@dataclass(frozen=True)
class Performed:
    """A :class:`Call`'s ``value``, or the exception it raised (``error``), with the call's ``index``."""

    index: int
    value: Any = None
    error: Exception | None = None


@dataclass(frozen=True)
class SceneSpan:
    """Grasps ``start..stop-1`` of scene ``scene_id``; ``unit_id`` is its store unit id."""

    scene_id: int
    start: int
    stop: int

    @property
    def unit_id(self) -> str:
        """Its scene's unit of the store (``scene_000003``)."""
        return scene_unit(self.scene_id)

    @property
    def size(self) -> int:
        return self.stop - self.start

    @property
    def key(self) -> tuple[str, int]:
        return (self.unit_id, self.start)


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
        from annotator.scenes.records import SceneSpec

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


@dataclass(frozen=True, kw_only=True)
class SceneTask(WorkerTask):
    """A span of a scene with what the worker needs: the ``request``, the scene's ``record`` when
    the main process has it (None: the worker builds it), and the run's checks (:class:`WorkerTask`)."""

    span: SceneSpan
    request: SceneRequest
    record: SceneRecord | None = None

    @property
    def mode(self) -> SceneMode:
        """The mode it labels in: a scene, with the arm's reachability when the request asks."""
        return SceneMode(cell=self.request.cell)


@dataclass(frozen=True)
class WorkerStats:
    """Worker time of one span (s), of which inside stepSimulation, peak memory (MB), the worker
    and its kind of machine (:func:`annotator.versions.machine_kind`; "" where none ran)."""

    seconds: float
    step_seconds: float
    peak_rss_mb: float
    pid: int
    host: str
    machine: str = ""


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
        assert err is not None  # a loaded model has its collision shape
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


class UnusableObject(ObjectError):
    """An object of a scene's pool that a worker cannot load although its file passed the main
    process's checks (size, header): a degenerate mesh, one that cleaning leaves empty.
    ``object_id`` goes back with the failed span (:data:`UNUSABLE_OBJECT`), so that the main
    process reports the object once, not each scene that draws it."""

    def __init__(self, object_id: str, reason: str) -> None:
        super().__init__(reason if reason.startswith(f"{object_id}:") else f"{object_id}: {reason}")
        self.object_id = object_id


# SpanResult.info key of a failed span: the pool object the scene could not load (UnusableObject).
UNUSABLE_OBJECT = "unusable_object"


@dataclass(frozen=True)
class SpanResult:
    """A span's labels (``rows``), or the object's one-line ``error``; ``info`` describes the object
    as simulated (mass, scale, ...) for the manifest; ``artifacts``: files that belong with the
    span's labels (file name -> bytes: the Kinect views it rendered), written by the main process;
    ``prepared``: what a decomposition task (``span`` a :class:`Prepare`) found. A scene's span
    (:class:`SceneSpan`) comes back the same way, its ``artifacts`` its scene file and views."""

    span: Span | Prepare | SceneSpan
    rows: pd.DataFrame | None
    error: str | None
    stats: WorkerStats
    info: dict[str, Any] | None = None
    artifacts: dict[str, bytes] | None = None
    prepared: PreparedObject | None = None

    @property
    def labelled(self) -> Span | SceneSpan | None:
        """The span whose labels ``rows`` are: the span itself, a decomposition task's first
        span, or None (a decomposition task without one)."""
        return self.span.first if isinstance(self.span, Prepare) else self.span
