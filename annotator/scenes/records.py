"""What a scene is, as data: its request (:class:`SceneSpec`), its workspace and its settled objects.

Frames. The *table frame* is the seed's table top (:class:`annotator.cell.TableTop`): origin at
the centre of its top surface, +z up, x and y along the table's sides. Every pose of a scene is an
object's mesh frame (the frame its labels use) in the table frame: ``T_table_obj``. The scene
records ``T_world_table`` too, so ``T_world_obj = T_world_table * T_table_obj``.

A scene's objects are *instances*: the k-th object drawn for the scene has ``instance_id`` k
(0-based, in draw order), whatever happens to it. An instance that is not in the settled scene
keeps its id with a status saying why (it left the workspace, found no free place, or was still
moving when settling ended), so the ids
of the others do not depend on it and a gap in the kept ids shows where one went.

:func:`scene_table` / :func:`scenes_from_table` turn records into one flat table (one row per
instance) and back, exactly (float64 poses, bit for bit): what a Parquet file of scenes holds.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import pandas as pd

from annotator.geometry import Transform

ARRANGEMENTS = ("pile", "packed", "table")
KEPT, LEFT_WORKSPACE, NOT_PLACED, NOT_AT_REST = "kept", "left_workspace", "not_placed", "not_at_rest"
STATUSES = (KEPT, LEFT_WORKSPACE, NOT_PLACED, NOT_AT_REST)
POSE_COLUMNS = ("x", "y", "z", "qx", "qy", "qz", "qw")  # T_table_obj: metres, quaternion xyzw
TABLE_POSE_COLUMNS = tuple(f"table_{c}" for c in POSE_COLUMNS)  # T_world_table
SCENE_COLUMNS = (
    "scene_id",
    "seed",
    "arrangement",
    "instance_id",
    "object_id",
    "status",
    *POSE_COLUMNS,
    "scale",
    "mass",
    "workspace_size",
    "workspace_x",
    "workspace_y",
    *TABLE_POSE_COLUMNS,
)


@dataclass(frozen=True)
class SceneSpec:
    """A scene to build: ``scene_id`` (>= 0) of a run with ``seed``, ``arrangement`` (one of
    ARRANGEMENTS) and the object count, drawn uniformly from ``min_objects``..``max_objects``
    (inclusive). Everything random about the scene comes from a Generator keyed on
    (seed, scene_id) alone (:func:`annotator.dataset.keyed_rng`)."""

    scene_id: int
    seed: int = 0
    arrangement: str = "pile"
    min_objects: int = 5
    max_objects: int = 5

    def __post_init__(self) -> None:
        if self.arrangement not in ARRANGEMENTS:
            raise ValueError(f"arrangement must be one of {list(ARRANGEMENTS)}, got {self.arrangement!r}")
        if not 1 <= self.min_objects <= self.max_objects:
            raise ValueError(f"object count {self.min_objects}-{self.max_objects}: need 1 <= min <= max")
        if self.scene_id < 0:
            raise ValueError(f"scene_id must be >= 0, got {self.scene_id}")


@dataclass(frozen=True)
class Workspace:
    """The cube objects are arranged in: side ``size`` (m), centred at ``center`` (2,) (x, y in the
    table frame) on the table top. Its box in the table frame is
    [cx - s/2, cx + s/2] x [cy - s/2, cy + s/2] x [-s/6, 5 s/6] (VGN's, whose task frame puts the
    table s/6 above the cube's floor)."""

    size: float
    center: np.ndarray

    @property
    def lower(self) -> np.ndarray:
        """The box's lower corner (3,), table frame, m."""
        return np.array([self.center[0] - self.size / 2, self.center[1] - self.size / 2, -self.size / 6])

    @property
    def upper(self) -> np.ndarray:
        """The box's upper corner (3,), table frame, m."""
        return self.lower + self.size

    def contains(self, points_table: np.ndarray) -> np.ndarray:
        """Which points (n, 3) (table frame) lie inside the box: (n,) bool."""
        p = np.atleast_2d(np.asarray(points_table, dtype=np.float64))
        return np.all((p >= self.lower) & (p <= self.upper), axis=1)

    @property
    def T_table_task(self) -> Transform:
        """VGN's task frame (its TSDF volume and grasp frame): origin at the box's lower corner,
        axes of the table frame."""
        return Transform(self.lower, (0.0, 0.0, 0.0, 1.0))


@dataclass(frozen=True)
class Instance:
    """One drawn object of a scene. ``T_table_obj``: its mesh frame in the table frame after
    settling (None unless ``status`` is ``kept``); ``scale``: the object's scale (file units to
    metres, as loaded); ``mass`` kg."""

    instance_id: int
    object_id: str
    status: str
    T_table_obj: Transform | None
    scale: float
    mass: float

    @property
    def kept(self) -> bool:
        return self.status == KEPT


@dataclass(frozen=True)
class SceneRecord:
    """A settled scene: its spec's id, seed and arrangement, every drawn instance (kept or not),
    the workspace and the table frame in the world."""

    scene_id: int
    seed: int
    arrangement: str
    instances: tuple[Instance, ...]
    workspace: Workspace
    T_world_table: Transform

    @property
    def kept(self) -> tuple[Instance, ...]:
        """The instances in the settled scene, by instance id."""
        return tuple(i for i in self.instances if i.kept)

    def instance(self, instance_id: int) -> Instance:
        for inst in self.instances:
            if inst.instance_id == instance_id:
                return inst
        raise KeyError(f"scene {self.scene_id} has no instance {instance_id}")

    def T_world_obj(self, instance_id: int) -> Transform:
        """The kept instance's mesh frame in the world."""
        inst = self.instance(instance_id)
        if inst.T_table_obj is None:
            raise ValueError(
                f"scene {self.scene_id} instance {instance_id} is {inst.status}, not in the scene"
            )
        return self.T_world_table * inst.T_table_obj


def _pose_values(T: Transform | None) -> list[float]:
    if T is None:
        return [float("nan")] * 7
    return [*map(float, T.pos), *map(float, T.quat)]


def scene_table(records: list[SceneRecord] | tuple[SceneRecord, ...]) -> pd.DataFrame:
    """One row per instance of every record (SCENE_COLUMNS), ordered by scene and instance id.
    Poses of instances not kept are NaN."""
    rows = []
    for rec in sorted(records, key=lambda r: r.scene_id):
        table_pose = _pose_values(rec.T_world_table)
        for inst in sorted(rec.instances, key=lambda i: i.instance_id):
            rows.append(
                [
                    rec.scene_id,
                    rec.seed,
                    rec.arrangement,
                    inst.instance_id,
                    inst.object_id,
                    inst.status,
                    *_pose_values(inst.T_table_obj),
                    inst.scale,
                    inst.mass,
                    rec.workspace.size,
                    float(rec.workspace.center[0]),
                    float(rec.workspace.center[1]),
                    *table_pose,
                ]
            )
    df = pd.DataFrame(rows, columns=list(SCENE_COLUMNS))
    for c in ("scene_id", "seed", "instance_id"):
        df[c] = df[c].astype(np.int64)
    return df


def _exact_pose(row: pd.Series, columns: tuple[str, ...]) -> Transform:
    values = [float(row[c]) for c in columns]
    return Transform.exact(values[:3], values[3:])


def scenes_from_table(df: pd.DataFrame) -> list[SceneRecord]:
    """The records of :func:`scene_table`'s rows (as read back from Parquet), by scene id."""
    missing = [c for c in SCENE_COLUMNS if c not in df.columns]
    if missing:
        raise ValueError(f"not a scene table: missing columns {missing}")
    records = []
    for scene_id, rows in df.sort_values(["scene_id", "instance_id"]).groupby("scene_id", sort=True):
        first = rows.iloc[0]
        instances = tuple(
            Instance(
                int(r["instance_id"]),
                str(r["object_id"]),
                str(r["status"]),
                _exact_pose(r, POSE_COLUMNS) if r["status"] == KEPT else None,
                float(r["scale"]),
                float(r["mass"]),
            )
            for _, r in rows.iterrows()
        )
        workspace = Workspace(
            float(first["workspace_size"]), np.array([first["workspace_x"], first["workspace_y"]], float)
        )
        records.append(
            SceneRecord(
                int(scene_id),
                int(first["seed"]),
                str(first["arrangement"]),
                instances,
                workspace,
                _exact_pose(first, TABLE_POSE_COLUMNS),
            )
        )
    return records


def same_scene(a: SceneRecord, b: SceneRecord) -> bool:
    """Whether two records are the same scene bit for bit (every pose's floats equal)."""
    if (a.scene_id, a.seed, a.arrangement, len(a.instances)) != (
        b.scene_id,
        b.seed,
        b.arrangement,
        len(b.instances),
    ):
        return False
    if a.workspace.size != b.workspace.size or not np.array_equal(a.workspace.center, b.workspace.center):
        return False
    if _pose_values(a.T_world_table) != _pose_values(b.T_world_table):
        return False
    for x, y in zip(a.instances, b.instances, strict=True):
        if dataclasses.replace(x, T_table_obj=None) != dataclasses.replace(y, T_table_obj=None):
            return False
        if (x.T_table_obj is None) != (y.T_table_obj is None):
            return False
        if x.T_table_obj is not None and _pose_values(x.T_table_obj) != _pose_values(y.T_table_obj):
            return False
    return True
