"""Building a scene: draw its objects, arrange them on the seed's table, settle them with physics.

Three arrangements (numbers and sources in :class:`annotator.config.SceneConfig`):

- ``pile`` (VGN's pile): inside a box of walls around the workspace, each object is dropped in a
  uniformly random orientation from above the central third and left to come to rest; then the
  walls are removed and everything settles again.
- ``packed`` (VGN's packed): each object upright (the stable pose nearest its mesh's +z), random
  yaw, over the central part of the workspace, just above the table, where it overlaps no object
  already placed; a few attempts, then it is left out.
- ``table`` (ACRONYM's random arrangement): each object in a stable pose drawn by its probability,
  random yaw, anywhere on the workspace's square with clearance from its sides, overlapping none;
  up to 100 attempts.

After arranging, objects settle until at rest (or a time limit); an object whose centre of mass
left the workspace is removed and the rest settle again, until none leaves and all are at rest
(VGN's ``remove_and_wait``, which stops at its time limit even if something still moves; here an
object still moving after ``settle_rounds`` is removed, so a recorded scene is always at rest).

Determinism: the object count, the objects (drawn from the sorted pool, with replacement, as VGN
draws) and every pose come from one Generator keyed on (seed, scene_id); each scene is built in a
fresh world (PyBullet's contact memory and body ids then never depend on what was built before),
so a scene is bit for bit the same on any worker, in any order.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from annotator.cell.placement import StablePose, place, stable_poses
from annotator.cell.world import Cell, build_cell
from annotator.config import CellConfig, PhysicsConfig, SceneConfig
from annotator.dataset import keyed_rng
from annotator.geometry import Transform, quat_normalize
from annotator.objects import ObjectModel, create_body, get_object_pose, reset_object_pose
from annotator.scenes.records import (
    KEPT,
    LEFT_WORKSPACE,
    NOT_AT_REST,
    NOT_PLACED,
    Instance,
    SceneRecord,
    SceneSpec,
    Workspace,
)
from annotator.sim import rigid
from annotator.sim.contacts import closest_points
from annotator.sim.world import World

log = logging.getLogger(__name__)

WALL_THICKNESS = 0.01  # m: the pile's walls (static boxes); any thickness holds a dropped object
DROP_CLEARANCE = 0.005  # m: a pile drop starts this far above the objects already there


def workspace_on(cell: Cell, scenes: SceneConfig) -> Workspace:
    """The workspace on ``cell``'s table: centred over the cell's placement point."""
    point_world = np.array([cell.config.placement_x, cell.config.placement_y, cell.top.z])
    center = cell.top.T_world_top.inverse().apply(point_world)[:2]
    return Workspace(scenes.workspace_size, center)


def draw_objects(spec: SceneSpec, pool: list[str], rng: np.random.Generator) -> list[str]:
    """The scene's object ids: a count uniform in the spec's range, ids drawn with replacement
    from ``pool`` (sorted, so the draw does not depend on the caller's order)."""
    if not pool:
        raise ValueError("no objects to draw scenes from")
    count = int(rng.integers(spec.min_objects, spec.max_objects + 1))
    ordered = sorted(pool)
    return [ordered[i] for i in rng.integers(len(ordered), size=count)]


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random rotation as a unit quaternion (4,) xyzw (a normalised Gaussian 4-vector)."""
    return quat_normalize(rng.standard_normal(4))


@dataclass
class _Body:
    instance_id: int
    object_id: str
    uid: int
    model: ObjectModel


@dataclass
class _Build:
    """One scene under construction: its world, table, workspace and the bodies placed so far."""

    world: World
    cell: Cell
    workspace: Workspace
    scenes: SceneConfig
    rng: np.random.Generator
    bodies: list[_Body] = field(default_factory=list)
    status: dict[int, str] = field(default_factory=dict)

    @property
    def client(self) -> int:
        return self.world.client

    @property
    def T_world_table(self) -> Transform:
        return self.cell.top.T_world_top

    def table_to_world(self, p_table: np.ndarray) -> np.ndarray:
        return self.T_world_table.apply(np.asarray(p_table, dtype=np.float64))

    def add(self, instance_id: int, object_id: str, model: ObjectModel, T_world_obj: Transform) -> _Body:
        body = _Body(instance_id, object_id, create_body(self.client, model, T_world_obj), model)
        self.bodies.append(body)
        return body

    def drop(self, body: _Body, status: str) -> None:
        """Take ``body`` out of the scene, recording why."""
        self.world.remove_body(body.uid)
        self.bodies.remove(body)
        self.status[body.instance_id] = status

    def clear_of_others(self, body: _Body, gap: float) -> bool:
        """Whether ``body`` is at least ``gap`` m from every other placed body."""
        for other in self.bodies:
            if other is not body and closest_points(self.client, body.uid, other.uid, gap):
                return False
        return True


def _com_world(client: int, uid: int) -> np.ndarray:
    return np.asarray(rigid.pose(client, uid)[0], dtype=np.float64)


def settle(build: _Build, seconds: float) -> bool:
    """Simulate until every body is at rest (VGN's rule, checked every ``rest_check_time``) or
    ``seconds`` of simulated time have passed; whether all came to rest."""
    world, scenes = build.world, build.scenes
    chunk = max(1, round(scenes.rest_check_time / world.dt))
    elapsed = 0
    limit = round(seconds / world.dt)
    world.set_gravity(True)
    while elapsed < limit:
        world.step(chunk)
        elapsed += chunk
        if all(_at_rest(build.client, b.uid, scenes.rest_speed) for b in build.bodies):
            return True
    return False


def _at_rest(client: int, uid: int, speed: float) -> bool:
    linear, angular = rigid.velocity(client, uid)
    return math.sqrt(sum(v * v for v in (*linear, *angular))) < speed


def remove_outside_and_settle(build: _Build) -> None:
    """VGN's ``remove_and_wait``, until the scene is at rest: settle; remove bodies whose centre of
    mass left the workspace; repeat while one was removed or one still moves, at most
    ``settle_rounds`` times; a body still moving then (a can rolling on its side) is removed."""
    T_table_world = build.T_world_table.inverse()
    for _ in range(build.scenes.settle_rounds):
        at_rest = settle(build, build.scenes.settle_time)
        outside = [
            b
            for b in build.bodies
            if not build.workspace.contains(T_table_world.apply(_com_world(build.client, b.uid)))[0]
        ]
        for body in outside:
            log.debug("instance %d (%s) left the workspace; removed", body.instance_id, body.object_id)
            build.drop(body, LEFT_WORKSPACE)
        if at_rest and not outside:
            return
    for body in [b for b in build.bodies if not _at_rest(build.client, b.uid, build.scenes.rest_speed)]:
        log.debug("instance %d (%s) still moves; removed", body.instance_id, body.object_id)
        build.drop(body, NOT_AT_REST)


# --- pile -------------------------------------------------------------------------------------------


def _add_walls(build: _Build) -> list[int]:
    """Four static walls around the workspace, ``pile_box_margin`` in from its sides."""
    scenes, ws = build.scenes, build.workspace
    inner = ws.size / 2 - scenes.pile_box_margin
    half_h = scenes.pile_box_height / 2
    half_t = WALL_THICKNESS / 2
    walls = []
    for axis in (0, 1):
        for sign in (-1.0, 1.0):
            half = [inner + WALL_THICKNESS, inner + WALL_THICKNESS, half_h]
            half[axis] = half_t
            centre = np.array([ws.center[0], ws.center[1], half_h])
            centre[axis] += sign * (inner + half_t)
            shape = rigid.collision_shape(build.client, "box", halfExtents=half)
            pos = build.table_to_world(centre).tolist()
            quat = build.T_world_table.quat.tolist()
            walls.append(
                rigid.multibody(
                    build.client,
                    baseMass=0.0,
                    baseCollisionShapeIndex=shape,
                    baseVisualShapeIndex=-1,
                    basePosition=pos,
                    baseOrientation=quat,
                )
            )
    return walls


def _pile_top(build: _Build) -> float:
    """Height of the highest point of the objects placed so far above the table top (0 if none)."""
    top = 0.0
    for b in build.bodies:
        aabb_max = rigid.aabb(build.client, b.uid)[1]
        top = max(top, float(aabb_max[2]) - build.cell.top.z)
    return top


def arrange_pile(build: _Build, drawn: list[tuple[int, str, ObjectModel]]) -> None:
    """Drop each object into the walled workspace (random orientation, central third), letting it
    come to rest after each; then remove the walls."""
    scenes, ws, rng = build.scenes, build.workspace, build.rng
    walls = _add_walls(build)
    for instance_id, object_id, model in drawn:
        quat = random_rotation(rng)
        xy = ws.center + (rng.uniform(size=2) - 0.5) * scenes.pile_drop_region * ws.size
        c = np.asarray(model.center_mass, dtype=np.float64)
        radius = float(np.linalg.norm(np.asarray(model.mesh.vertices) - c, axis=1).max())
        height = max(scenes.pile_drop_height, _pile_top(build) + radius + DROP_CLEARANCE)
        com_world = build.table_to_world(np.array([xy[0], xy[1], height]))
        R = build.T_world_table.rotation @ Transform((0, 0, 0), quat).rotation
        T_world_obj = Transform.from_rotation(R, com_world - R @ c)
        build.add(instance_id, object_id, model, T_world_obj)
        settle(build, scenes.drop_settle_time)
    for wall in walls:
        build.world.remove_body(wall)


# --- packed and table -----------------------------------------------------------------------------


class PoseCatalogue:
    """Each object's merged stable poses (trimesh, as the cell merges them), computed once."""

    def __init__(self, cell: CellConfig) -> None:
        self._cell = cell
        self._poses: dict[str, list[StablePose]] = {}

    def poses(self, model: ObjectModel) -> list[StablePose]:
        """Stable poses of at least the cell's minimum probability (else the most probable one)."""
        if model.object_id not in self._poses:
            cfg = self._cell
            poses = stable_poses(model.mesh, cfg.placement_merge_angle, cfg.placement_min_probability)
            if not poses:
                poses = stable_poses(model.mesh, cfg.placement_merge_angle)[:1]
            if not poses:
                raise ValueError(f"{model.object_id}: no stable pose on a table")
            self._poses[model.object_id] = poses
        return self._poses[model.object_id]

    def upright(self, model: ObjectModel) -> StablePose:
        """The stable pose whose up direction is nearest the mesh's own +z (ties: the more probable)."""
        poses = self.poses(model)
        return max(poses, key=lambda p: (round(float(p.up_in_object[2]), 9), p.probability))


def _try_places(build: _Build, body: _Body, pose_of, attempts: int, half_range: float) -> bool:
    """Move ``body`` to up to ``attempts`` random places (``pose_of(rng)`` gives its stable pose,
    then a yaw and a point within ``half_range`` of the workspace centre are drawn) until it is
    ``placement_gap`` clear of the others; True when placed."""
    rng, ws, gap = build.rng, build.workspace, build.scenes.placement_gap
    c = np.asarray(body.model.center_mass, dtype=np.float64)
    for _ in range(attempts):
        pose = pose_of(rng)
        yaw = float(rng.uniform(0.0, 2.0 * math.pi))
        xy = ws.center + rng.uniform(-half_range, half_range, size=2)
        T = place(pose, build.cell.top, build.table_to_world(np.array([xy[0], xy[1], 0.0]))[:2], yaw, c)
        T = Transform(T.pos + gap * build.T_world_table.rotation[:, 2], T.quat)
        reset_object_pose(build.client, body.uid, T)
        if build.clear_of_others(body, gap):
            return True
    return False


def arrange_packed(
    build: _Build, drawn: list[tuple[int, str, ObjectModel]], catalogue: PoseCatalogue
) -> None:
    """Each object upright, random yaw, in the central ``packed_region`` of the workspace, clear
    of the others; left out after ``packed_attempts``."""
    scenes = build.scenes
    half = scenes.packed_region * build.workspace.size / 2
    for instance_id, object_id, model in drawn:
        body = build.add(instance_id, object_id, model, Transform((0.0, 0.0, -10.0), (0, 0, 0, 1)))
        upright = catalogue.upright(model)
        if not _try_places(build, body, lambda rng, p=upright: p, scenes.packed_attempts, half):
            build.drop(body, NOT_PLACED)


def arrange_table(build: _Build, drawn: list[tuple[int, str, ObjectModel]], catalogue: PoseCatalogue) -> None:
    """ACRONYM's arrangement: each object in a stable pose drawn by probability, random yaw,
    anywhere on the workspace less ``table_edge_clearance``, clear of the others; left out after
    ``table_attempts``."""
    scenes = build.scenes
    half = max(0.0, build.workspace.size / 2 - scenes.table_edge_clearance)
    for instance_id, object_id, model in drawn:
        body = build.add(instance_id, object_id, model, Transform((0.0, 0.0, -10.0), (0, 0, 0, 1)))
        poses = catalogue.poses(model)
        p = np.array([pose.probability for pose in poses])
        p = p / p.sum()

        def by_probability(rng: np.random.Generator, poses=poses, p=p) -> StablePose:
            return poses[int(rng.choice(len(poses), p=p))]

        if not _try_places(build, body, by_probability, scenes.table_attempts, half):
            build.drop(body, NOT_PLACED)


# --- the whole scene --------------------------------------------------------------------------------


class SceneBuilder:
    """Builds scenes from a pool of loaded objects (object id -> ObjectModel, as
    :func:`annotator.objects.load_object` gives them), each in a fresh world with ``physics``.
    ``models`` may load lazily (a Mapping whose keys are the pool): only the objects a scene draws
    are looked up.

    ``build(spec)`` returns the settled :class:`SceneRecord`; the builder keeps the objects' stable
    poses between scenes (they depend on the mesh only).
    """

    def __init__(
        self,
        models: Mapping[str, ObjectModel],
        *,
        scenes: SceneConfig | None = None,
        physics: PhysicsConfig | None = None,
        cell: CellConfig | None = None,
    ) -> None:
        self.models = models
        self.scenes = scenes or SceneConfig()
        self.physics = physics or PhysicsConfig()
        self.cell = cell or CellConfig()
        self.catalogue = PoseCatalogue(self.cell)

    def build(self, spec: SceneSpec) -> SceneRecord:
        rng = keyed_rng("scene", int(spec.seed), int(spec.scene_id))
        ids = draw_objects(spec, list(self.models), rng)
        drawn = [(k, oid, self.models[oid]) for k, oid in enumerate(ids)]
        with World(self.physics) as world:
            cell = build_cell(world, self.cell, robot=False, kinect=False)
            build = _Build(world, cell, workspace_on(cell, self.scenes), self.scenes, rng)
            if spec.arrangement == "pile":
                arrange_pile(build, drawn)
            elif spec.arrangement == "packed":
                arrange_packed(build, drawn, self.catalogue)
            else:
                arrange_table(build, drawn, self.catalogue)
            remove_outside_and_settle(build)
            return self._record(spec, build, drawn)

    def _record(
        self, spec: SceneSpec, build: _Build, drawn: list[tuple[int, str, ObjectModel]]
    ) -> SceneRecord:
        T_table_world = build.T_world_table.inverse()
        poses = {
            b.instance_id: _as_recorded(T_table_world * get_object_pose(build.client, b.uid))
            for b in build.bodies
        }
        instances = tuple(
            Instance(
                k,
                oid,
                KEPT if k in poses else build.status.get(k, NOT_PLACED),
                poses.get(k),
                float(model.scale),
                float(model.mass),
            )
            for k, oid, model in drawn
        )
        kept = sum(i.kept for i in instances)
        log.debug(
            "scene %d (%s): %d of %d objects kept", spec.scene_id, spec.arrangement, kept, len(instances)
        )
        return SceneRecord(
            spec.scene_id,
            spec.seed,
            spec.arrangement,
            instances,
            build.workspace,
            _as_recorded(build.T_world_table),
        )


def _as_recorded(T: Transform) -> Transform:
    """``T`` from its position and quaternion alone, as a scene table reads it back: a product of
    transforms keeps the rotation matrix it was multiplied with, whose last bits can differ from
    the quaternion's, and a scene loaded from its file must be the scene that was built."""
    return Transform.exact(T.pos, T.quat)
