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
2. **Motion.** The arm starts at the pregrasp (``approach_distance`` behind the grasp, gripper
   open to the label's width + 2 x the protocol's clearance) and follows the joint-space
   trajectory through the IK solutions of the straight approach (1 cm apart) to the grasp.
3. **Close** with the gripper's grip force until the fingers stall, the arm holding still.
4. **Lift** ``lift_height`` straight up (IK waypoints), keep squeezing, hold, and judge: the
   object *came up* when it rose at least ``LIFTED_SHARE`` of the lift; *moved in the hand* is its
   displacement in the gripper frame from the end of the close to the end.

Contacts of the robot with the object or the table during the approach are recorded (a
``collision`` label's gripper meets the object there).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from annotator.cell.placement import place, stable_poses
from annotator.cell.reach import READY, Reach, check_reach
from annotator.cell.world import Cell
from annotator.config import AnnotatorConfig
from annotator.dataset import poses_as_matrices
from annotator.geometry import Transform
from annotator.objects import ObjectModel, get_object_pose, physics_for, reset_object_pose
from annotator.outcome import Outcome
from annotator.render import Camera, orbit_camera, render_rgb
from annotator.sim import pb
from annotator.sim.world import World
from annotator.tools.given import CMD_COLUMNS

log = logging.getLogger(__name__)

PLACEMENT_COLUMNS = ("obj_x", "obj_y", "obj_z", "obj_qx", "obj_qy", "obj_qz", "obj_qw")
YAW_STEP = math.radians(15.0)  # turns tried about the vertical for a floating label's placement
MAX_PLACEMENT_TRIES = 60  # reachability checks at most (~0.1 s each) before giving up
# A ready configuration (elbow up, flange pointing down) whose IK branch is preferred: the
# posture a UR is usually taught to grasp from above in.
APPROACH_SPEED = 0.05  # m/s along the approach: a cautious taught-grasp speed for a UR3
LIFT_DURATION = 1.0  # s for the lift (0.1 m/s), well inside the UR3's joint speed limits
SETTLE_TIME = 0.25  # s: the arm settles at the pregrasp and at the grasp before the next phase
HOLD_TIME = 0.5  # s held in the air before the verdict
LIFTED_SHARE = 0.8  # the object came up if it rose at least this share of the lift
FRAME_SECONDS = 0.05  # GIF: one frame per 0.05 s simulated (20 frames per simulated second)


@dataclass(frozen=True)
class Plan:
    """Where the object rests and how the arm gets to the grasp."""

    T_world_obj: Transform
    T_world_tcp: Transform
    width: float  # m, the TCP frame's opening (the label's width; the expected chord for collisions)
    open_width: float  # m, the opening during the approach
    reach: Reach
    note: str  # how the placement was chosen


@dataclass
class ReplayResult:
    """What the replay measured (see the module docstring)."""

    plan: Plan
    approach_contacts: list[str] = field(default_factory=list)
    closed_width: float = float("nan")  # m
    pads_touching: int = 0  # pads touching the object after the close
    pads_at_end: int = 0  # pads touching the object after the lift and hold
    rise: float = float("nan")  # m the object rose during lift and hold
    slip: float = float("nan")  # m the object moved in the gripper frame after the close
    frames: list[np.ndarray] = field(default_factory=list)

    def lifted(self, lift_height: float) -> bool:
        """The object came up with the hand (rose at least LIFTED_SHARE of the lift)."""
        return bool(self.rise >= LIFTED_SHARE * lift_height)

    def held(self, lift_height: float, max_slip: float) -> bool:
        """Came up, both pads still on it, moved less than ``max_slip`` in the hand (as a trial judges)."""
        return self.lifted(lift_height) and self.pads_at_end == 2 and self.slip < max_slip


def replay_world(model: ObjectModel, config: AnnotatorConfig, *, gui: bool = False) -> World:
    """The world a label of ``model`` is replayed in, with the physics the batch job gave it: an
    object under ``[physics] light_object_mass`` at its finer time step
    (:func:`annotator.objects.physics_for`); at 1/240 s a light object's contacts can disagree with
    its label. The arm's gripper simulates its whole linkage, with the iterations that needs
    (``PhysicsConfig.whole_linkage``)."""
    return World(physics_for(model, config.physics.whole_linkage()), gui=gui)


def frames_every(dt: float) -> int:
    """Simulation steps of ``dt`` s per GIF frame (one frame per FRAME_SECONDS simulated)."""
    return max(1, round(FRAME_SECONDS / dt))


def label_row(labels: pd.DataFrame, object_id: str, grasp_id: int) -> pd.Series:
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


class _Recorder:
    """Renders every ``every``-th step; in GUI mode paces the loop at real time instead."""

    def __init__(self, cell: Cell, camera: Camera | None, every: int, realtime: bool) -> None:
        self.cell, self.camera, self.every, self.realtime = cell, camera, max(1, every), realtime
        self.frames: list[np.ndarray] = []
        self.steps = 0
        self.start = time.monotonic()

    def step(self) -> None:
        self.cell.world.step()
        self.steps += 1
        if self.camera is not None and self.steps % self.every == 0:
            self.frames.append(render_rgb(self.cell.client, self.camera))
        if self.realtime:
            lag = self.start + self.steps * self.cell.world.dt - time.monotonic()
            if lag > 0:
                time.sleep(lag)  # the GUI replay runs at real time


def _follow(
    cell: Cell, path: np.ndarray, seconds: float, each_step: Callable[[], None], rec: _Recorder
) -> None:
    """Position-control the arm through joint waypoints ``path`` (m, 6) over ``seconds``."""
    n = max(1, round(seconds / cell.world.dt))
    s = np.linspace(0.0, len(path) - 1, n + 1)[1:]
    for x in s:
        k = min(int(x), len(path) - 2) if len(path) > 1 else 0
        u = x - k
        q = path[k] if len(path) == 1 else (1 - u) * path[k] + u * path[k + 1]
        cell.command_arm(q)
        each_step()
        rec.step()


def replay(
    cell: Cell,
    obj: int,
    plan: Plan,
    config: AnnotatorConfig,
    *,
    camera: Camera | None = None,
    frame_every: int | None = None,
    realtime: bool = False,
) -> ReplayResult:
    """Execute ``plan`` in simulation (gravity on throughout) and measure; see the module docstring.

    ``frame_every``: steps per GIF frame (default: one frame per FRAME_SECONDS simulated)."""
    robot, gripper = cell.robot, cell.gripper
    assert robot is not None and gripper is not None
    if not plan.reach.reachable:
        raise ValueError(f"the grasp is not reachable: {plan.reach.reason} ({plan.reach.detail})")
    g, p = config.gripper, config.protocol
    force = gripper.grip_force
    every = frame_every if frame_every is not None else frames_every(cell.world.dt)
    rec = _Recorder(cell, camera, every, realtime)
    result = ReplayResult(plan)
    names = {index: name for name, index in robot.links.items()}
    open_angle = gripper.table.angle_of(plan.open_width)

    def hold_open() -> None:
        gripper.hold_position(open_angle, force)

    def watch_contacts() -> None:
        for body, what in ((obj, "the object"), (cell.table.uid, "the table")):
            for c in pb.getContactPoints(robot.uid, body, physicsClientId=cell.client):
                text = f"{names[c[3]]} touched {what}"
                if text not in result.approach_contacts:
                    result.approach_contacts.append(text)

    path = plan.reach.path
    cell.reset_arm(path[0])
    gripper.reset_width(plan.open_width)
    _follow(cell, path[:1], SETTLE_TIME, hold_open, rec)
    approach_seconds = p.approach_distance / APPROACH_SPEED
    _follow(cell, path, approach_seconds, lambda: (hold_open(), watch_contacts()), rec)
    _follow(cell, path[-1:], SETTLE_TIME, lambda: (hold_open(), watch_contacts()), rec)

    # close: the arm holds the grasp, the gripper squeezes until the fingers stall
    driven = robot.joints[gripper.driven].index
    stall_speed = g.stall_fraction * gripper.settings.close_speed
    stalled = 0
    for _ in range(round(p.close_timeout / cell.world.dt)):
        cell.command_arm(path[-1])
        gripper.squeeze(force)
        rec.step()
        speed = pb.getJointState(robot.uid, driven, physicsClientId=cell.client)[1]
        stalled = stalled + 1 if abs(speed) < stall_speed else 0
        if stalled >= g.stall_steps:
            break
    result.closed_width = gripper.measured_width()
    result.pads_touching = sum(bool(c) for c in gripper.pad_contacts(obj))
    z0 = get_object_pose(cell.client, obj).pos[2]
    in_hand_0 = (gripper.base_pose().inverse() * get_object_pose(cell.client, obj)).pos

    # lift straight up through IK waypoints, squeezing
    lift = [path[-1]]
    steps = max(1, int(math.ceil(p.lift_height / p.approach_step)))
    for k in range(1, steps + 1):
        T = Transform(plan.T_world_tcp.pos + [0.0, 0.0, p.lift_height * k / steps], plan.T_world_tcp.quat)
        q = cell.nearest_ik(T, plan.width, lift[-1])
        if q is None:
            log.warning(
                "the lift leaves the arm's reach %.0f mm up: stops there", 1000 * p.lift_height * k / steps
            )
            break
        lift.append(q)
    squeeze = lambda: gripper.squeeze(force)  # noqa: E731
    _follow(cell, np.array(lift), LIFT_DURATION, squeeze, rec)
    _follow(cell, np.array(lift[-1:]), HOLD_TIME, squeeze, rec)
    T_world_obj = get_object_pose(cell.client, obj)
    result.rise = float(T_world_obj.pos[2] - z0)
    in_hand = (gripper.base_pose().inverse() * T_world_obj).pos
    result.slip = float(np.linalg.norm(in_hand - in_hand_0))
    result.pads_at_end = sum(bool(c) for c in gripper.pad_contacts(obj))
    result.frames = rec.frames
    return result


def default_camera(T_world_obj: Transform, size: tuple[int, int] = (320, 240)) -> Camera:
    """A camera 0.7 m from the object, 20 deg above it, looking along the seed camera's direction
    (the arm on the left, its reach to the right)."""
    target = T_world_obj.pos + np.array([0.0, 0.0, 0.08])
    return orbit_camera(tuple(target), 0.7, 0.0, -20.0, *size, fov=60.0)
