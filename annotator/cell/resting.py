"""Given grasps on an object resting on the table (``evaluate --resting``): as real trials are run.

Real grasps are executed on objects lying on a table, which holds them while the fingers close
and is in the way of a low grasp. With ``--resting`` each object is put on the seed's table
(:mod:`annotator.cell`) in a given orientation, settles under gravity, and every given grasp moves
with it: a grasp is a pose in the object's mesh frame, so its TCP in the world is
``T_world_obj(settled) · T_obj_tcp``. The trial is the cell's (:class:`annotator.trial.GraspTrial`
with the table as an obstacle of the kinematic checks and gravity on while the gripper closes).

The orientation is the mesh frame's in the table frame (z up): by default the identity, the mesh's
own +z up; a grasp table may give it per row (``rest_qx rest_qy rest_qz rest_qw``, xyzw), so an
object whose mesh +z pointed down on a real board rests upside down, as it lay. Yaw only turns
the object about the vertical. Each row records the orientation it was given (``rest_q*``), the
settled pose (``obj_x .. obj_qw``, world, as the cell's labels) and ``settle_drift``.

For each orientation: the object's centre of mass over the cell's placement point, its lowest
vertex on the table top, lowered or raised until its collision shape touches the top
(:func:`annotator.cell.batch._touching`), settled for ``placement_settle_time`` from a snapshot
with no contact memory. The settled pose depends only on (object, orientation, configuration),
never on the other orientations or on which worker settles it, so rows stay bit for bit the same
for any split of the work. An orientation the object does not keep (a ball, a banana on its tip)
is simulated where it comes to rest; its drift (``settle_drift``, the largest movement of a corner
of the mesh's bounding box) is recorded on every row.
"""

from __future__ import annotations

import logging

import numpy as np

from annotator.cell.batch import _settle, _touching, _zero_velocity
from annotator.cell.views import OBJECT_POSE_COLUMNS
from annotator.cell.world import build_cell
from annotator.config import AnnotatorConfig
from annotator.geometry import Transform, canonical_quat, quat_to_matrix
from annotator.objects import ObjectModel, reset_object_pose
from annotator.sim.hand import FloatingGripper
from annotator.sim.world import World
from annotator.trial import GraspTrial

log = logging.getLogger(__name__)

# Where the floating gripper waits while no trial runs: 2 m above the world origin, as in the cell.
PARKED = Transform([0.0, 0.0, 2.0], [0.0, 0.0, 0.0, 1.0])
UPRIGHT = (0.0, 0.0, 0.0, 1.0)  # the mesh frame's own orientation: +z up
# Columns of resting rows: the orientation given (xyzw, mesh frame in the table frame), the settled
# object pose (world, as the cell's labels) and how far it moved while settling (m).
REST_COLUMNS = ("rest_qx", "rest_qy", "rest_qz", "rest_qw")
RESTING_COLUMNS = (*REST_COLUMNS, *OBJECT_POSE_COLUMNS, "settle_drift")


def orientation_key(quat: np.ndarray) -> tuple[float, float, float, float]:
    """An xyzw quaternion as a key: w >= 0 (q and -q are one orientation), floats as given."""
    q = canonical_quat(np.asarray(quat, dtype=np.float64).reshape(4))
    if q[3] == 0 and next((v for v in q[:3] if v != 0), 0.0) < 0:  # w = 0: the first other one > 0
        q = -q
    return tuple(float(v) for v in q)  # type: ignore[return-value]


class RestingWorld:
    """A worker's table for ``--resting``: the seed's table in the trial world (beside the floating
    gripper), built once per configuration."""

    def __init__(
        self, world: World, hand: FloatingGripper, config: AnnotatorConfig, grasps: str = "object"
    ) -> None:
        self.world = world
        self.hand = hand
        self.config = config
        self.grasps = grasps  # "object": the grasps move with the settling object; "table": they stay
        self.table_cell = build_cell(world, config.cell, robot=False, kinect=False)

    @property
    def table(self) -> int:
        return self.table_cell.table.uid

    def close(self) -> None:
        """Nothing of its own to free: the table is a body of the trial world."""

    def load(self, model: ObjectModel, uid: int) -> RestingObject:
        return RestingObject(self, model, uid)


class RestingObject:
    """One object on the table: a settled pose and a :class:`GraspTrial` per orientation, made when
    a grasp first needs it."""

    def __init__(self, worlds: RestingWorld, model: ObjectModel, uid: int) -> None:
        self.worlds = worlds
        self.model = model
        self.uid = uid
        self.corners = np.array(np.meshgrid(*model.mesh.bounds.T, indexing="ij")).reshape(3, -1).T
        # orientation key -> (trial, settled T_world_obj, drift m, T_world_obj before settling)
        self.placed: dict[tuple[float, ...], tuple[GraspTrial, Transform, float, Transform]] = {}

    def close(self) -> None:
        for trial, *_ in self.placed.values():
            trial.close()
        self.placed = {}

    def initial_pose(self, quat_table_obj: np.ndarray) -> Transform:
        """``T_world_obj`` before settling: turned by ``quat_table_obj`` (xyzw), the centre of mass
        over the placement point, the lowest vertex on the table top, then moved along the
        vertical until the collision shape touches the top."""
        cell = self.worlds.table_cell
        config = self.worlds.config.cell
        R = quat_to_matrix(np.asarray(quat_table_obj, dtype=np.float64)).reshape(3, 3)
        R_world = cell.top.T_world_top.rotation @ R
        vertices = self.model.mesh.vertices @ R_world.T
        com = R_world @ np.asarray(self.model.center_mass, dtype=np.float64)
        top = cell.top.T_world_top
        pos = np.array(
            [
                config.placement_x - com[0],
                config.placement_y - com[1],
                top.pos[2] - float(vertices[:, 2].min()),
            ]
        )
        T = Transform.from_rotation(R_world, pos)
        return _touching(
            self.worlds.world.client, self.uid, self.worlds.table, T, self.worlds.config.cell.touch_search
        )

    def trial_for(self, quat_table_obj: np.ndarray) -> tuple[GraspTrial, Transform, float, Transform]:
        """The trial of the object resting in this orientation, its settled ``T_world_obj``, its
        drift (m) and ``T_world_obj`` as it was put down, before settling."""
        key = orientation_key(quat_table_obj)
        if key not in self.placed:
            world, hand, uid = self.worlds.world, self.worlds.hand, self.uid
            hand.teleport(PARKED, hand.gripper.max_width)  # out of the way, the same for every settle
            T_start = self.initial_pose(np.array(key))
            T_settled, drift = _settle(
                world, uid, T_start, self.worlds.config.cell.placement_settle_time, self.corners
            )
            if drift > self.worlds.config.cell.placement_max_drift:
                log.info(
                    "%s: resting as given (quaternion %s) it moved %.1f mm while settling",
                    self.model.object_id,
                    np.round(key, 4).tolist(),
                    drift * 1e3,
                )
            reset_object_pose(world.client, uid, T_settled)
            _zero_velocity(world.client, uid)
            trial = GraspTrial(
                world, hand, uid, self.worlds.config, obstacles=(self.worlds.table,), resting=True
            )
            self.placed[key] = (trial, T_settled, drift, T_start)
        return self.placed[key]

    def grasp(self, quat_table_obj: np.ndarray, T_obj_tcp: Transform) -> Transform:
        """The grasp to run, in the settled object's frame: ``T_obj_tcp`` itself when the grasps move
        with the object; else the pose that keeps it where it was given in the table frame,
        ``T_settled^-1 · T_start · T_obj_tcp``."""
        if self.worlds.grasps == "object":
            return T_obj_tcp
        _, T_settled, _, T_start = self.trial_for(quat_table_obj)
        return T_settled.inverse() * T_start * T_obj_tcp

    def columns(self, quat_table_obj: np.ndarray) -> dict[str, float]:
        """The resting columns of a row: the orientation given (as given, so the row replays
        exactly), the settled object pose in the world and its drift."""
        _, T, drift, _ = self.trial_for(quat_table_obj)
        q = T.quat if T.quat[3] >= 0 else -T.quat
        pose = [*T.pos.tolist(), *q.tolist()]
        given = [float(v) for v in np.asarray(quat_table_obj, dtype=np.float64).reshape(4)]
        return {
            **dict(zip(REST_COLUMNS, given, strict=True)),
            **dict(zip(OBJECT_POSE_COLUMNS, pose, strict=True)),
            "settle_drift": float(drift),
        }
