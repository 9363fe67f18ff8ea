"""The gripper's collision boxes in its TCP frame at an opening: what a vision policy checks
against the observed cloud.

Read from the gripper's own model (the collision shapes of its URDF posed by its kinematics, in a
private PyBullet client opened once per process): only the poses come from PyBullet. Boxes only:
the RG2's collision model is boxes (a gripper with mesh shapes contributes its boxes alone).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from annotator.geometry import Transform


@dataclass(frozen=True)
class Box:
    """A box of full ``extents`` (3,) m posed at ``T_tcp_box`` (4, 4) in the TCP frame."""

    extents: np.ndarray
    T_tcp_box: np.ndarray


class GripperBoxes:
    """The collision boxes of a gripper (default the RG2) at any opening (:meth:`at`)."""

    def __init__(self, gripper: str | None = None) -> None:
        from annotator.config import GripperConfig
        from annotator.grippers import load_gripper
        from annotator.sim.body import Body
        from annotator.sim.gripper import ParallelGripper
        from annotator.sim.world import World

        self.world = World()
        description = load_gripper(gripper)
        self.body = Body.load(self.world.client, description.urdf, fixed_base=True)
        self.gripper = ParallelGripper(self.body, description, GripperConfig())

    @property
    def max_width(self) -> float:
        return self.gripper.max_width

    def at(self, width: float, placed_for: float) -> tuple[Box, ...]:
        """The boxes with the gripper placed so that its TCP at opening ``placed_for`` (m) is the
        frame's origin and its fingers at opening ``width`` (m): as the arm places it for a grasp of
        chord ``placed_for`` and opens it for the approach (a linkage's pads then sit higher)."""
        return _boxes_at(self, round(float(width), 4), round(float(placed_for), 4))


@lru_cache(maxsize=512)
def _boxes_at(boxes: GripperBoxes, width: float, placed_for: float) -> tuple[Box, ...]:
    from annotator.sim import rigid

    g = boxes.gripper
    boxes.body.reset_base_pose(g.T_base_tcp(placed_for).inverse())
    g.reset_width(width)
    out = []
    client, uid = boxes.world.client, boxes.body.uid
    for index in [-1, *boxes.body.links.values()]:
        pos, orn = rigid.link_pose(client, uid, index)
        T_com = Transform(pos, orn)
        for shape in rigid.collision_shapes(client, uid, index):
            if shape.kind == "box":
                T_tcp_box = (T_com * Transform(shape.local_position, shape.local_orientation)).as_matrix()
                out.append(Box(np.asarray(shape.dimensions, float), T_tcp_box))
    return tuple(out)


@lru_cache(maxsize=4)
def gripper_boxes(gripper: str | None = None) -> GripperBoxes:
    """This process's :class:`GripperBoxes` of ``gripper`` (loaded once)."""
    return GripperBoxes(gripper)


def points_in_boxes(points_tcp: np.ndarray, boxes: tuple[Box, ...], margin: float = 0.0) -> np.ndarray:
    """Which points (n, 3) (TCP frame) lie inside any box grown by ``margin`` m: (n,) bool."""
    inside = np.zeros(len(points_tcp), dtype=bool)
    for box in boxes:
        R, t = box.T_tcp_box[:3, :3], box.T_tcp_box[:3, 3]
        local = (points_tcp - t) @ R
        inside |= np.all(np.abs(local) <= box.extents / 2 + margin, axis=1)
    return inside


def points_in_swept_boxes(points_tcp: np.ndarray, boxes: tuple[Box, ...], sweep: float) -> np.ndarray:
    """Which points (n, 3) (TCP frame) any box meets while the gripper backs off from its pose by
    0..``sweep`` m along the approach (the TCP frame's -z; the points move +z relative to it):
    (n,) bool, exact for boxes (per axis, the interval of back-offs that holds the point; hit where
    the three intervals and [0, sweep] overlap)."""
    hit = np.zeros(len(points_tcp), dtype=bool)
    for box in boxes:
        R, t = box.T_tcp_box[:3, :3], box.T_tcp_box[:3, 3]
        a = (points_tcp - t) @ R  # (n, 3) the points in the box's frame
        b = R[2, :]  # how a back-off of 1 m moves them, box frame
        h = box.extents / 2
        lo = np.zeros(len(a))
        hi = np.full(len(a), float(sweep))
        for i in range(3):
            if abs(b[i]) < 1e-12:
                inside = np.abs(a[:, i]) <= h[i]
                hi = np.where(inside, hi, -1.0)
                continue
            s1, s2 = (-h[i] - a[:, i]) / b[i], (h[i] - a[:, i]) / b[i]
            lo = np.maximum(lo, np.minimum(s1, s2))
            hi = np.minimum(hi, np.maximum(s1, s2))
        hit |= lo <= hi
    return hit


def box_corners(boxes: tuple[Box, ...]) -> np.ndarray:
    """The corners (8 m, 3) of every box, TCP frame."""
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
    out = [(signs * box.extents / 2) @ box.T_tcp_box[:3, :3].T + box.T_tcp_box[:3, 3] for box in boxes]
    return np.concatenate(out) if out else np.zeros((0, 3))
