"""Can the UR3 execute a grasp in the cell? Closed-form IK along the approach, then arm collisions.

For a TCP pose (at the label's width) the arm must reach every waypoint of the straight approach,
from ``approach_distance`` behind the grasp to the grasp, with one continuous IK branch, and at
each waypoint (gripper open) no link of the robot may touch the table, no arm link the object
(the gripper against the object is the grasp's own collision check), and the arm not itself.
The first IK solution (nearest to the seed configuration first) that passes is the answer;
otherwise the reason of the one that got furthest:

``no IK solution`` (at the grasp or along the approach), ``joint limits``, ``arm-table collision``,
``arm-object collision``, ``arm self-collision``.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from annotator.cell.world import Cell
from annotator.geometry import Transform
from annotator.sim import ur3
from annotator.sim.contacts import closest_points, contact_points
from annotator.sim.rigid import detect_collisions

log = logging.getLogger(__name__)

NO_IK = "no IK solution"
LIMITS = "joint limits"
ARM_TABLE = "arm-table collision"
ARM_OBJECT = "arm-object collision"
SELF = "arm self-collision"
REASONS = (NO_IK, LIMITS, ARM_TABLE, ARM_OBJECT, SELF)
# A joint that moves more than this between two approach waypoints 1 cm apart has jumped to
# another IK branch (a 1 cm Cartesian step moves a UR3 joint by a few hundredths of a radian away
# from singularities).
MAX_JOINT_STEP = 0.5  # rad
# The arm's home: upper arm up, forearm forward, the gripper pointing down over the table. IK
# solutions nearest to it are tried first (the batch job and replay), so the chosen branch is the
# one a UR3 reaches from its usual start (elbow up, wrist down), whatever the arm did before.
READY = np.array([0.0, -np.pi / 2, np.pi / 2, -np.pi / 2, -np.pi / 2, 0.0])


@dataclass(frozen=True)
class Reach:
    """The verdict for one TCP pose.

    ``path`` : (m, 6) rad, arm joints from the pregrasp (first row) to the grasp (last row),
    empty when unreachable; ``reason`` one of REASONS ('' when reachable), ``detail`` a short
    human-readable elaboration (which link touched what, where).
    """

    reachable: bool
    reason: str = ""
    detail: str = ""
    path: np.ndarray = field(default_factory=lambda: np.empty((0, 6)))

    @property
    def q_grasp(self) -> np.ndarray | None:
        return self.path[-1] if len(self.path) else None

    @property
    def q_pregrasp(self) -> np.ndarray | None:
        return self.path[0] if len(self.path) else None


def approach_waypoints(T_world_tcp: Transform, distance: float, step: float) -> list[Transform]:
    """TCP poses from ``distance`` behind ``T_world_tcp`` (along -z of the TCP) to it, ``step`` apart."""
    n = max(1, int(np.ceil(distance / step - 1e-9)))
    approach = T_world_tcp.rotation[:, 2]
    return [
        Transform(T_world_tcp.pos - approach * distance * (1 - k / n), T_world_tcp.quat) for k in range(n + 1)
    ]


def _link_names(cell: Cell) -> dict[int, str]:
    assert cell.robot is not None
    return {index: name for name, index in cell.robot.links.items()}


def _bodies(obj: int | Sequence[int] | None) -> tuple[int, ...]:
    if obj is None:
        return ()
    return (obj,) if isinstance(obj, int) else tuple(obj)


def arm_collision(cell: Cell, obj: int | Sequence[int] | None, margin: float) -> tuple[str, str]:
    """With the arm where it is: (reason, detail) of the first collision found, ('', '') if none.

    ``obj``: the object's body, or several (a scene: the target first, then its neighbours). The
    gripper's own links (every link of its description) against the objects are the grasp's
    collision check, not the arm's; against each other they are the gripper's business.
    """
    robot, gripper = cell.robot, cell.gripper
    assert robot is not None and gripper is not None
    client = cell.client
    names = _link_names(cell)
    gripper_links = frozenset(gripper.description.links)
    for link, distance in _closest(client, robot.uid, cell.table.uid, margin):
        return ARM_TABLE, f"{names[link]} touches the table ({distance * 1000:.1f} mm)"
    for k, body in enumerate(_bodies(obj)):
        what = "the object" if k == 0 else f"another object (body {body})"
        for link, distance in _closest(client, robot.uid, body, margin):
            if names[link] not in gripper_links:
                return ARM_OBJECT, f"{names[link]} touches {what} ({distance * 1000:.1f} mm)"
    detect_collisions(client)
    for c in contact_points(client, robot.uid, robot.uid):
        a, b = names[c.link_a], names[c.link_b]
        if c.distance < -1e-4 and not (a in gripper_links and b in gripper_links):
            return SELF, f"{a} touches {b}"
    return "", ""


def _closest(client: int, a: int, b: int, margin: float) -> list[tuple[int, float]]:
    """(link of ``a``, signed distance) of every pair closer than ``margin``, nearest first."""
    pts = closest_points(client, a, b, margin)
    return sorted(((p.link_a, p.distance) for p in pts if p.distance < margin), key=lambda x: x[1])


def check_reach(
    cell: Cell,
    T_world_tcp: Transform,
    width: float,
    *,
    open_width: float,
    approach_distance: float,
    approach_step: float,
    obj: int | Sequence[int] | None = None,
    q_seed: np.ndarray | None = None,
    margin: float | None = None,
) -> Reach:
    """Is the grasp at ``T_world_tcp`` (pads ``width`` apart) executable by the cell's arm?

    The arm and gripper are moved kinematically (reset) and put back where they were; no step is
    simulated. ``obj``: the object's body (or several), checked against the arm links. ``q_seed`` (6,):
    solutions nearest to it are tried first (default the arm's current joints).
    """
    robot, gripper = cell.robot, cell.gripper
    if robot is None or gripper is None:
        raise ValueError("reachability needs the cell's robot")
    margin = cell.config.arm_collision_margin if margin is None else margin
    saved_q = cell.arm_positions()
    saved_angle = gripper.driven_angle()
    q_seed = saved_q if q_seed is None else np.asarray(q_seed, dtype=float)
    limits = cell.arm_limits()
    waypoints = approach_waypoints(T_world_tcp, approach_distance, approach_step)[::-1]  # grasp first
    frames = cell.frames
    T_baselink_world = cell.T_world_baselink.inverse()
    flange = [frames.T_base_tool0(T_baselink_world * T, width) for T in waypoints]
    best = Reach(False, NO_IK, "no IK solution at the grasp pose")
    best_progress = -1
    try:
        result = ur3.solve_ik(flange[0], limits=limits, reference=q_seed)
        if not result:
            reason = LIMITS if result.reason == ur3.NO_LIMITS else NO_IK
            return Reach(False, reason, result.reason)
        order = np.argsort(np.linalg.norm(result.solutions - q_seed, axis=1), kind="stable")
        # the approach's other waypoints, all eight branches of each in one batch (solving them
        # one by one was a third of a cell worker's time); which branch continues the path is
        # chosen below, waypoint by waypoint, exactly as nearest_ik would
        along = ur3.ik_branches(np.stack(flange)) if len(flange) > 1 else None
        gripper.reset_width(open_width)
        for k in order:
            path = [result.solutions[k]]
            failure: tuple[str, str] | None = None
            for i, T_flange in enumerate(flange):
                if i > 0:
                    q = ur3.nearest_ik_along(along, i, T_flange, path[-1], limits)
                    if q is None or np.abs(q - path[-1]).max() > MAX_JOINT_STEP:
                        back = i * approach_step * 100
                        failure = (NO_IK, f"no continuous IK solution {back:.0f} cm back along the approach")
                        break
                    path.append(q)
                cell.reset_arm(path[-1])
                reason, detail = arm_collision(cell, obj, margin)
                if reason:
                    back = i * approach_step * 100
                    where = f"{back:.0f} cm back along the approach" if i else "at the grasp"
                    failure = (reason, f"{detail}, {where}")
                    break
            if failure is None:
                return Reach(True, path=np.array(path[::-1]))
            if len(path) > best_progress:
                best_progress = len(path)
                best = Reach(False, *failure)
        return best
    finally:
        cell.reset_arm(saved_q)
        gripper.reset_angle(saved_angle)
