"""Replay one label on the UR3 + its gripper in the seed's cell: place, reach, approach, close, lift, judge.

1. **Placement.** A label from ``annotate --cell`` carries the object's pose on the table
   (``obj_x obj_y obj_z obj_qx obj_qy obj_qz obj_qw``, the mesh frame in the world): it is used as
   is, with the grasp the label commanded (``cmd_*`` at ``cmd_width``), whose arm joints are the
   label's ``q_grasp``. A floating label has none, so one is chosen: among the object's stable
   poses on the table (trimesh, merged as the cell's placements) turned in 15 deg steps about the
   vertical, with the grasp point over the cell's placement point, the candidates are tried in
   order of how much the grasp approaches *from above* (then by the pose's probability); the first
   whose grasp the arm reaches (closed-form IK along the whole approach, no arm-table or
   arm-object collision) wins. A floating label may approach from any side; on a table only the
   grasps that come from above or the side can be executed, so the placement that turns the grasp
   most downwards is the one a user would set up.
2. **Execution** on the arm: approach, close, lift and judge, as
   :func:`annotator.cell.execute.execute_plan` describes.
"""

from __future__ import annotations

import logging
import math

import numpy as np
import pandas as pd

from annotator.cell.execute import Plan
from annotator.cell.placement import place, stable_poses
from annotator.cell.reach import READY, Reach, check_reach
from annotator.cell.world import Cell
from annotator.config import AnnotatorConfig
from annotator.dataset import poses_as_matrices
from annotator.geometry import Transform
from annotator.objects import ObjectModel, physics_for, reset_object_pose
from annotator.outcome import Outcome
from annotator.render import Camera, orbit_camera
from annotator.sim.world import World
from annotator.tools.given import CMD_COLUMNS

log = logging.getLogger(__name__)

PLACEMENT_COLUMNS = ("obj_x", "obj_y", "obj_z", "obj_qx", "obj_qy", "obj_qz", "obj_qw")
YAW_STEP = math.radians(15.0)  # turns tried about the vertical for a floating label's placement
MAX_PLACEMENT_TRIES = 60  # reachability checks at most (~0.1 s each) before giving up


def replay_world(model: ObjectModel, config: AnnotatorConfig, *, gui: bool = False) -> World:
    """The world a label of ``model`` is replayed in, with the physics the batch job gave it: an
    object under ``[physics] light_object_mass`` at its finer time step
    (:func:`annotator.objects.physics_for`); at 1/240 s a light object's contacts can disagree with
    its label. The arm's gripper simulates its whole linkage, with the iterations that needs
    (``PhysicsConfig.whole_linkage``)."""
    return World(physics_for(model, config.physics.whole_linkage()), gui=gui)


def find_label(labels: pd.DataFrame, object_id: str, grasp_id: int) -> pd.Series:
    """The label of ``object_id`` number ``grasp_id``; ``KeyError`` with a one-line reason if absent."""
    rows = labels[(labels["object_id"] == object_id) & (labels["grasp_id"] == grasp_id)]
    if rows.empty:
        known = labels.loc[labels["object_id"] == object_id, "grasp_id"]
        if known.empty:
            raise KeyError(f"no labels for object {object_id!r}")
        raise KeyError(
            f"object {object_id!r} has no grasp {grasp_id} (grasp ids {known.min()}..{known.max()})"
        )
    return rows.iloc[0]


def tcp_widths(row: pd.Series, config: AnnotatorConfig, max_width: float) -> tuple[float, float]:
    """(TCP frame width, open width) for a label: a collision row's ``width`` is already the open
    width (the expected chord + 2 x clearance); any other row's is the width reached."""
    clearance = config.protocol.pregrasp_clearance
    width = float(row["width"])
    if Outcome.from_label(str(row["outcome"])) == Outcome.COLLISION:
        return max(0.0, width - 2 * clearance), min(max_width, width)
    return width, min(max_width, width + 2 * clearance)


def _reach(
    cell: Cell, obj: int, T_world_tcp: Transform, width: float, open_width: float, config: AnnotatorConfig
) -> Reach:
    p = config.protocol
    return check_reach(
        cell,
        T_world_tcp,
        width,
        open_width=open_width,
        approach_distance=p.approach_distance,
        approach_step=p.approach_step,
        obj=obj,
        q_seed=READY,
    )


def plan_replay(cell: Cell, model: ObjectModel, obj: int, row: pd.Series, config: AnnotatorConfig) -> Plan:
    """Choose the object's placement (the label's own, or see the module docstring) and the arm path.

    Moves the object body ``obj`` to the chosen placement.
    """
    assert cell.gripper is not None
    max_width = cell.gripper.max_width
    T_obj_tcp = Transform.from_matrix(poses_as_matrices(pd.DataFrame([row]))[0])
    width, open_width = tcp_widths(row, config, max_width)
    if all(c in row.index and pd.notna(row[c]) for c in PLACEMENT_COLUMNS):
        values = [float(row[c]) for c in PLACEMENT_COLUMNS]
        T_world_obj = Transform(values[:3], values[3:])
        if all(c in row.index and pd.notna(row[c]) for c in CMD_COLUMNS):  # as the cell labelled it
            cmd = [float(row[c]) for c in CMD_COLUMNS]
            T_obj_tcp = Transform.exact(cmd[:3], cmd[3:7])
            width = cmd[7]
            open_width = min(max_width, width + 2 * config.protocol.pregrasp_clearance)
        reset_object_pose(cell.client, obj, T_world_obj)
        T_world_tcp = T_world_obj * T_obj_tcp
        reach = _reach(cell, obj, T_world_tcp, width, open_width, config)
        return Plan(T_world_obj, T_world_tcp, width, open_width, reach, "placement: the label's own")

    poses = stable_poses(model.mesh, cell.config.placement_merge_angle, cell.config.placement_min_probability)
    if not poses:
        poses = stable_poses(model.mesh, cell.config.placement_merge_angle)
    xy = np.array([cell.config.placement_x, cell.config.placement_y])
    candidates = []
    for i, pose in enumerate(poses):
        # every member of a merged placement (a can on any of its side facets) may serve: the
        # grasp's side of the object can face up in one and down in another
        for m, member in enumerate(pose.each_member()):
            for k in range(round(2 * math.pi / YAW_STEP)):
                T_world_obj = place(member, cell.top, xy, k * YAW_STEP, T_obj_tcp.pos)
                approach = (T_world_obj * T_obj_tcp).rotation[:, 2]
                downward = -float(approach[2])
                candidates.append((-round(downward, 2), -pose.probability, i, m, k, T_world_obj, downward))
    candidates.sort(key=lambda c: c[:5])
    first_failure: tuple | None = None
    for tries, (_, _, i, _, k, T_world_obj, downward) in enumerate(candidates[:MAX_PLACEMENT_TRIES], start=1):
        reset_object_pose(cell.client, obj, T_world_obj)
        T_world_tcp = T_world_obj * T_obj_tcp
        reach = _reach(cell, obj, T_world_tcp, width, open_width, config)
        tilt = math.degrees(math.acos(max(-1.0, min(1.0, downward))))
        note = (
            f"placement: stable pose {i + 1} of {len(poses)} (probability {poses[i].probability:.2f}), "
            f"turned {math.degrees(k * YAW_STEP):.0f} deg; the grasp approaches {tilt:.0f} deg from "
            "straight down"
        )
        if reach.reachable:
            note += f", the most from above of the reachable placements ({tries} tried)"
            return Plan(T_world_obj, T_world_tcp, width, open_width, reach, note)
        if first_failure is None:
            first_failure = (T_world_obj, T_world_tcp, reach, note)
    assert first_failure is not None
    T_world_obj, T_world_tcp, reach, note = first_failure
    reset_object_pose(cell.client, obj, T_world_obj)
    note += f"; no placement tried ({min(len(candidates), MAX_PLACEMENT_TRIES)}) is reachable"
    return Plan(T_world_obj, T_world_tcp, width, open_width, reach, note)


def default_camera(T_world_obj: Transform, size: tuple[int, int] = (320, 240)) -> Camera:
    """A camera 0.7 m from the object, 20 deg above it, looking along the seed camera's direction
    (the arm on the left, its reach to the right)."""
    target = T_world_obj.pos + np.array([0.0, 0.0, 0.08])
    return orbit_camera(tuple(target), 0.7, 0.0, -20.0, *size, fov=60.0)
