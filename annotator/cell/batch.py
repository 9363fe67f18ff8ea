"""The cell in the batch job (``annotate --cell``): objects resting on the table, reach, views.

A worker keeps two worlds for the cell, built once:

- the *trial world*: the floating gripper and the seed's table. The object rests on the table in each
  of its placements (one saved state each); a candidate runs the usual protocol there, with the
  table in the kinematic collision checks (a gripper that would touch it is a ``collision``) and
  gravity on from the start (the object rests on the table while the fingers close).
- the *arm world*: the table, the UR3 with the same gripper on its flange and a still copy of the object. Each
  candidate's commanded grasp is checked for reachability there (:mod:`annotator.cell.reach`:
  closed-form IK along the approach from the arm's READY branch, arm-table and arm-object
  collisions), and the Kinect views are rendered there (the arm at READY is in the picture).

Placements (:func:`settle_placements`): the object's most probable stable poses (trimesh, merged),
each put on the table with its centre of mass over the cell's placement point, lowered or raised
until its collision shape touches the table, then settled under gravity; a pose that moves more
than ``placement_max_drift`` while settling is skipped for the next one.

The candidates are sampled per placement, knowing the table (:mod:`annotator.cell.candidates`):
the object's N rows shared among its placements by stable-pose probability, approaches from above,
the fingers clear of the table top; each row's ``placement_id`` is the placement it was sampled
for. On the sample objects (``--n 100``) 360 of 1,000 held this way, 306 of them reachable; with
the floating run's candidates, each resting in the placement where it approached most from above,
68 held (58 reachable). Grasps given from outside (``evaluate``, benches) still rest where they
approach most from above (:meth:`CellObject.placement_for`).

Every trial and every reach check starts from its placement's saved state with no contact memory
(:meth:`annotator.sim.world.World.restore_state`), so a row depends on (object, seed, grasp) only.
"""

from __future__ import annotations

import io
import logging
from dataclasses import dataclass

import numpy as np
import pandas as pd

from annotator.cell.candidates import TableSide, sample_cell_candidates
from annotator.cell.kinect import depth_to_png_array, look_at
from annotator.cell.placement import place, stable_poses
from annotator.cell.reach import READY, Reach, check_reach
from annotator.cell.views import OBJECT_POSE_COLUMNS, SEG_NOTHING, SEG_OBJECT, SEG_ROBOT, SEG_TABLE
from annotator.cell.world import Cell, build_cell
from annotator.config import AnnotatorConfig
from annotator.geometry import Transform, canonical_quat
from annotator.objects import ObjectError, ObjectModel, create_body, get_object_pose, reset_object_pose
from annotator.rng import keyed_rng
from annotator.sampler import Candidates
from annotator.sim import rigid
from annotator.sim.contacts import closest_points
from annotator.sim.hand import FloatingGripper
from annotator.sim.world import World
from annotator.store.names import artifact_relpath
from annotator.trial import GraspTrial

log = logging.getLogger(__name__)

# Where the floating gripper waits while no trial runs: 2 m above the world origin (the arm's
# base), 2 m above the table top and far from any object on it.
PARKED = Transform([0.0, 0.0, 2.0], [0.0, 0.0, 0.0, 1.0])
JOINT_COLUMNS = tuple(f"q_grasp_{i}" for i in range(6))  # ur3.JOINT_NAMES order, rad
REACH_ERROR = "error"  # unreachable_reason when the check itself failed (logged)


@dataclass(frozen=True)
class SettledPlacement:
    """The object at rest on the table: ``T_world_obj`` (its mesh frame, after settling), from
    stable pose ``pose_index`` (:func:`annotator.cell.placement.stable_poses` order) with its
    merged ``probability``; ``drift`` m, how far it moved while settling."""

    placement_id: int
    T_world_obj: Transform
    pose_index: int
    probability: float
    drift: float


def _zero_velocity(client: int, uid: int) -> None:
    rigid.reset_velocity(client, uid, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])


def _touching(client: int, uid: int, table: int, T_world_obj: Transform, search: float) -> Transform:
    """``T_world_obj`` moved vertically until the body's collision shape touches ``table`` when it
    is within ``search`` m of it (``[cell] touch_search``)."""
    reset_object_pose(client, uid, T_world_obj)
    pts = closest_points(client, uid, table, search)
    if not pts:
        return T_world_obj
    gap = min(p.distance for p in pts)
    return Transform(T_world_obj.pos - np.array([0.0, 0.0, gap]), T_world_obj.quat)


def _settle(world: World, uid: int, T_world_obj: Transform, seconds: float, corners: np.ndarray):
    """Let the object settle from ``T_world_obj`` under gravity for ``seconds``; (pose, drift m).

    Starts from a snapshot with no contact memory, so the result does not depend on what the
    world simulated before. ``corners`` (8, 3): the mesh's bounding box, for the drift.
    """
    client = world.client
    reset_object_pose(client, uid, T_world_obj)
    _zero_velocity(client, uid)
    state = world.save_state()
    try:
        world.restore_state(state)
        world.set_gravity(True)
        world.step(round(seconds / world.dt))
        T_settled = get_object_pose(client, uid)
    finally:
        world.remove_state(state)
    drift = float(np.linalg.norm(T_settled.apply(corners) - T_world_obj.apply(corners), axis=1).max())
    return T_settled, drift


def settle_placements(world: World, uid: int, cell: Cell, model: ObjectModel) -> list[SettledPlacement]:
    """The object's placements on ``cell``'s table, settled in ``world`` (body ``uid``), most
    probable first; ObjectError when no stable pose stays put. Leaves the body anywhere."""
    config = cell.config
    poses = stable_poses(model.mesh, config.placement_merge_angle, config.placement_min_probability)
    if not poses:  # every pose rarer than the threshold (a ball): the most probable one
        poses = stable_poses(model.mesh, config.placement_merge_angle)[:1]
    if not poses:
        raise ObjectError("no stable pose on a table (trimesh's compute_stable_poses found none)")
    xy = np.array([config.placement_x, config.placement_y])
    corners = np.array(np.meshgrid(*model.mesh.bounds.T, indexing="ij")).reshape(3, -1).T
    kept: list[SettledPlacement] = []
    drifts: list[float] = []
    for index, pose in enumerate(poses):
        if len(kept) == config.placements_per_object:
            break
        T = place(pose, cell.top, xy, 0.0, np.asarray(model.center_mass))
        T = _touching(world.client, uid, cell.table.uid, T, config.touch_search)
        T_settled, drift = _settle(world, uid, T, config.placement_settle_time, corners)
        if drift > config.placement_max_drift:
            log.info(
                "%s: stable pose %d moved %.1f mm while settling; skipped",
                model.object_id,
                index,
                drift * 1e3,
            )
            drifts.append(drift)
            continue
        kept.append(SettledPlacement(len(kept), T_settled, index, pose.probability, drift))
    if not kept:
        worst = min(drifts) * 1e3 if drifts else float("nan")
        raise ObjectError(
            f"no stable pose stays on the table: each of {len(poses)} moved at least {worst:.0f} mm while "
            "settling"
        )
    return kept


class CellWorlds:
    """A worker's worlds for ``--cell``: the trial world's table (beside the floating gripper) and
    the arm world (table, UR3 + the same gripper, views). Built once per configuration."""

    def __init__(self, world: World, hand: FloatingGripper, config: AnnotatorConfig) -> None:
        self.world = world
        self.hand = hand
        self.config = config
        self.table_cell = build_cell(world, config.cell, robot=False, kinect=False)
        self.envelope = hand.gripper.finger_envelope()  # the fingers, for the table-aware sampler
        self.arm_world = World(config.physics.whole_linkage())  # the arm's gripper: whole linkage
        self.arm = build_cell(
            self.arm_world,
            config.cell,
            robot=True,
            kinect=False,
            gripper=config.gripper,
            kinect_config=config.kinect,
            description=hand.description,
        )
        self.arm.reset_arm(READY)

    def close(self) -> None:
        self.arm_world.close()

    def load(self, model: ObjectModel, uid: int) -> CellObject:
        """The object (body ``uid`` of the trial world) in its placements, ready for labelling."""
        return CellObject(self, model, uid)


class CellObject:
    """One object in the cell: its settled placements, a GraspTrial and an arm-world snapshot each."""

    def __init__(self, worlds: CellWorlds, model: ObjectModel, uid: int) -> None:
        self.worlds = worlds
        self.model = model
        self.uid = uid
        world, hand, config = worlds.world, worlds.hand, worlds.config
        self.placements = settle_placements(world, uid, worlds.table_cell, model)
        self.trials: list[GraspTrial] = []
        self.arm_uid = create_body(worlds.arm_world.client, model)
        self.arm_states: list[int] = []
        gripper = worlds.arm.gripper
        assert gripper is not None
        for placement in self.placements:
            reset_object_pose(world.client, uid, placement.T_world_obj)
            _zero_velocity(world.client, uid)
            hand.teleport(PARKED, hand.gripper.max_width)
            table = worlds.table_cell.table.uid
            self.trials.append(GraspTrial(world, hand, uid, config, obstacles=(table,), resting=True))
            reset_object_pose(worlds.arm_world.client, self.arm_uid, placement.T_world_obj)
            worlds.arm.reset_arm(READY)
            gripper.reset_width(gripper.max_width)
            self.arm_states.append(worlds.arm_world.save_state())

    def close(self) -> None:
        """Free the snapshots and the arm world's copy of the object (the trial body is the caller's)."""
        for trial in self.trials:
            trial.close()
        for state in self.arm_states:
            self.worlds.arm_world.remove_state(state)
        self.worlds.arm_world.remove_body(self.arm_uid)
        self.trials, self.arm_states = [], []

    # --- labels --------------------------------------------------------------------------------

    def candidates(self, n: int, seed: int) -> Candidates:
        """The object's N candidates, sampled per placement knowing the table
        (:func:`annotator.cell.candidates.sample_cell_candidates`); ``placement`` says where each rests."""
        worlds = self.worlds
        config = worlds.config
        sides = [
            TableSide(
                placement.T_world_obj,
                worlds.table_cell.top.z,
                worlds.envelope,
                config.protocol.pregrasp_clearance,
                worlds.hand.gripper.max_width,
            )
            for placement in self.placements
        ]
        probabilities = [placement.probability for placement in self.placements]
        return sample_cell_candidates(
            self.model.mesh, n, seed, self.model.object_id, sides, probabilities, config
        )

    def placement_for(self, T_obj_tcp: Transform) -> int:
        """The placement a given grasp (not one of :meth:`candidates`: ``evaluate``'s, a bench's)
        rests in: the one where its approach points most downwards (ties: the more probable)."""
        approach = T_obj_tcp.rotation[:, 2]
        down = np.round([-float(p.T_world_obj.rotation[2] @ approach) for p in self.placements], 9)
        return int(np.argmax(down))

    def reach(self, p: int, T_obj_tcp: Transform, width: float) -> Reach:
        """Can the arm execute the commanded grasp ``T_obj_tcp`` (pads ``width`` apart) in placement ``p``?"""
        worlds, protocol = self.worlds, self.worlds.config.protocol
        gripper = worlds.arm.gripper
        assert gripper is not None
        worlds.arm_world.restore_state(self.arm_states[p])
        return check_reach(
            worlds.arm,
            self.placements[p].T_world_obj * T_obj_tcp,
            width,
            open_width=min(gripper.max_width, width + 2 * protocol.pregrasp_clearance),
            approach_distance=protocol.approach_distance,
            approach_step=protocol.approach_step,
            obj=self.arm_uid,
            q_seed=READY,
        )

    def columns(self, p: int, T_obj_tcp: Transform, width: float, grasp_id: int) -> dict[str, object]:
        """The cell's label columns of a commanded grasp in placement ``p``: placement, object
        pose, reachability."""
        placement = self.placements[p]
        try:
            reach = self.reach(p, T_obj_tcp, width)
        except Exception as exc:  # one candidate's failure must not lose the others
            oid, kind = self.model.object_id, type(exc).__name__
            log.warning("%s grasp %d: reachability check failed: %s: %s", oid, grasp_id, kind, exc)
            reach = Reach(False, REACH_ERROR, str(exc))
        q = reach.q_grasp if reach.reachable else np.full(6, np.nan)
        T = placement.T_world_obj
        pose = [*T.pos.tolist(), *canonical_quat(T.quat).tolist()]
        return {
            "placement_id": p,
            "placement_probability": placement.probability,
            **dict(zip(OBJECT_POSE_COLUMNS, pose, strict=True)),
            "reachable": bool(reach.reachable),
            **dict(zip(JOINT_COLUMNS, map(float, q), strict=True)),
            "unreachable_reason": reach.reason,
        }

    # --- views ---------------------------------------------------------------------------------

    def camera_poses(self, placement_id: int, views: int) -> list[Transform]:
        """``T_world_camera`` (optical frames) of the ``views`` views of a placement: the seed's
        Kinect, then views-1 cameras around the object looking at its centre of mass (CellConfig
        view_*)."""
        cfg = self.worlds.config.cell
        arm = self.worlds.arm
        target = self.placements[placement_id].T_world_obj.apply(np.asarray(self.model.center_mass))
        poses = [arm.T_world_kinect_optical()]
        elevation = np.radians(cfg.view_elevation)
        extra = views - 1
        for k in range(extra):
            share = k / (extra - 1) - 0.5 if extra > 1 else 0.0
            azimuth = np.radians(cfg.view_azimuth + cfg.view_azimuth_span * share)
            direction = np.array(
                [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)]
            )
            poses.append(look_at(target + cfg.view_distance * direction, target))
        return poses

    def render_views(self, placement_id: int, views: int, seed: int) -> dict[str, bytes]:
        """The placement's views as files: name -> bytes (PNGs and ``pNN_cameras.parquet``)."""
        worlds = self.worlds
        kinect_config = worlds.config.kinect
        worlds.arm_world.restore_state(self.arm_states[placement_id])
        arm, oid = worlds.arm, self.model.object_id
        assert arm.robot is not None
        classes = {arm.table.uid: SEG_TABLE, self.arm_uid: SEG_OBJECT, arm.robot.uid: SEG_ROBOT}
        T_world_obj = self.placements[placement_id].T_world_obj
        files: dict[str, bytes] = {}
        rows = []
        for v, T_world_camera in enumerate(self.camera_poses(placement_id, views)):
            noise = (
                keyed_rng("views", seed, oid, placement_id, v) if kinect_config.views_depth_noise else None
            )
            view = arm.render_kinect(
                T_world_camera, color=True, color_scale=kinect_config.views_color_scale, rng=noise
            )
            seg = np.full(view.segmentation.shape, SEG_NOTHING, dtype=np.uint8)
            for body, label in classes.items():
                seg[view.segmentation == body] = label
            stem = f"p{placement_id:02d}_v{v:02d}"
            names = {kind: f"{stem}_{kind}.png" for kind in ("depth", "color", "segmentation")}
            files[names["depth"]] = _png(depth_to_png_array(view.depth))
            files[names["color"]] = _png(view.color)
            files[names["segmentation"]] = _png(seg)
            assert view.color_K is not None
            row: dict[str, object] = {"object_id": oid, "placement_id": placement_id, "view_id": v}
            row.update({kind: artifact_relpath(oid, name) for kind, name in names.items()})
            row.update(view.camera_row())
            cK = view.color_K
            row.update(
                {
                    "color_width": cK.width,
                    "color_height": cK.height,
                    "color_fx": cK.fx,
                    "color_fy": cK.fy,
                    "color_cx": cK.cx,
                    "color_cy": cK.cy,
                }
            )
            pose = [*T_world_obj.pos.tolist(), *canonical_quat(T_world_obj.quat).tolist()]
            row.update(dict(zip(OBJECT_POSE_COLUMNS, pose, strict=True)))
            rows.append(row)
        buffer = io.BytesIO()
        pd.DataFrame(rows).to_parquet(buffer, index=False)
        files[f"p{placement_id:02d}_cameras.parquet"] = buffer.getvalue()
        return files


def _png(image: np.ndarray) -> bytes:
    """PNG bytes of an (h, w) uint8/uint16 or (h, w, 3) uint8 image (readable by any image library)."""
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image)).save(buffer, format="PNG")
    return buffer.getvalue()
