"""The arm's plan-and-execute in the cell: from the pregrasp along the approach, close, lift, judge.

What :mod:`annotator.tools.replay` (``annotator replay``) and clutter removal
(:mod:`annotator.policies.clutter`) both run once they have chosen where the object rests and which
grasp to try (a :class:`Plan`, built on :func:`annotator.cell.reach.check_reach`):

1. **Motion.** The arm starts at the pregrasp (``approach_distance`` behind the grasp, gripper
   open to ``Plan.open_width``) and follows the joint-space trajectory through the IK solutions of
   the straight approach (``Plan.reach.path``, 1 cm apart) to the grasp.
2. **Close** with the gripper's grip force until the fingers stall, the arm holding still.
3. **Lift** ``lift_height`` straight up (IK waypoints), keep squeezing, hold, and judge: the
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

from annotator.cell.reach import Reach
from annotator.cell.world import Cell
from annotator.config import AnnotatorConfig
from annotator.geometry import Transform
from annotator.objects import get_object_pose
from annotator.render import Camera, render_rgb
from annotator.sim.contacts import contact_points

log = logging.getLogger(__name__)

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
class Execution:
    """What executing a :class:`Plan` measured (see the module docstring)."""

    plan: Plan
    approach_contacts: list[str] = field(default_factory=list)
    table_touched: bool = False  # a link touched the table on the way in
    links_on_object: set[str] = field(default_factory=set)  # links that touched the object on the way in
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


def frames_every(dt: float) -> int:
    """Simulation steps of ``dt`` s per GIF frame (one frame per FRAME_SECONDS simulated)."""
    return max(1, round(FRAME_SECONDS / dt))


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


def execute_plan(
    cell: Cell,
    obj: int,
    plan: Plan,
    config: AnnotatorConfig,
    *,
    camera: Camera | None = None,
    frame_every: int | None = None,
    realtime: bool = False,
) -> Execution:
    """Execute ``plan`` on the cell's arm (gravity on throughout) and measure; see the module docstring.

    ``frame_every``: steps per GIF frame (default: one frame per FRAME_SECONDS simulated)."""
    robot, gripper = cell.robot, cell.gripper
    assert robot is not None and gripper is not None
    if not plan.reach.reachable:
        raise ValueError(f"the grasp is not reachable: {plan.reach.reason} ({plan.reach.detail})")
    g, p = config.gripper, config.protocol
    force = gripper.grip_force
    every = frame_every if frame_every is not None else frames_every(cell.world.dt)
    rec = _Recorder(cell, camera, every, realtime)
    result = Execution(plan)
    names = {index: name for name, index in robot.links.items()}
    open_angle = gripper.table.angle_of(plan.open_width)

    def hold_open() -> None:
        gripper.hold_position(open_angle, force)

    def watch_contacts() -> None:
        for body, what in ((obj, "the object"), (cell.table.uid, "the table")):
            for c in contact_points(cell.client, robot.uid, body):
                if body == obj:
                    result.links_on_object.add(names[c.link_a])
                else:
                    result.table_touched = True
                text = f"{names[c.link_a]} touched {what}"
                if text not in result.approach_contacts:
                    result.approach_contacts.append(text)

    path = plan.reach.path
    cell.reset_arm(path[0])
    gripper.reset_width(plan.open_width)
    _follow(cell, path[:1], SETTLE_TIME, hold_open, rec)

    def hold_open_and_watch() -> None:
        hold_open()
        watch_contacts()

    approach_seconds = p.approach_distance / APPROACH_SPEED
    _follow(cell, path, approach_seconds, hold_open_and_watch, rec)
    _follow(cell, path[-1:], SETTLE_TIME, hold_open_and_watch, rec)

    # close: the arm holds the grasp, the gripper squeezes until the fingers stall
    stall_speed = g.stall_fraction * gripper.settings.close_speed
    stalled = 0
    for _ in range(round(p.close_timeout / cell.world.dt)):
        cell.command_arm(path[-1])
        gripper.squeeze(force)
        rec.step()
        speed = robot.joint_velocity(gripper.driven)
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
