"""A gripper's opening as a function of its drive, tabulated from the model's own forward kinematics.

The drive is the one joint a gripper's motor moves (revolute: rad; prismatic: m); every other
movable joint follows it through the URDF's ``<mimic>`` table. Sampling the pad links' poses over
the drive's range gives the pad-face separation (the width) and the pad-centre midpoint (the TCP)
at every opening, so nothing in the code assumes a formula for any gripper.
"""

from __future__ import annotations

import bisect
import functools
from dataclasses import dataclass, field

import numpy as np
import pybullet as pb

from annotator.geometry import Transform
from annotator.grippers.urdf import read_mimic_table
from annotator.sim.body import Body


@dataclass(frozen=True)
class WidthTable:
    """The gripper's forward kinematics sampled over the drive's range.

    ``angle`` (k,) drive position (rad or m), increasing; ``width`` (k,) pad-face separation, m,
    strictly monotonic in the drive (increasing when a larger drive opens the gripper, as the
    RG2's; decreasing when it closes it, as the Robotiq's ``finger_joint``); ``tcp`` (k, 3)
    pad-centre midpoint in the gripper base frame, m.
    """

    angle: np.ndarray
    width: np.ndarray
    tcp: np.ndarray
    # (k,) dw/d(drive), m/rad or m/m, from the table's finite differences (derived in __post_init__)
    slope: np.ndarray = field(init=False)
    # derived in __post_init__: plain lists for the scalar lookups, the table by increasing width
    _angles: list[float] = field(init=False, repr=False, compare=False)
    _slopes: list[float] = field(init=False, repr=False, compare=False)
    _w: np.ndarray = field(init=False, repr=False, compare=False)
    _w_angle: np.ndarray = field(init=False, repr=False, compare=False)
    _w_tcp: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "slope", np.gradient(self.width, self.angle))
        # plain lists for the per-step scalar lookup (np.interp costs ~5 us per scalar call)
        object.__setattr__(self, "_angles", self.angle.tolist())
        object.__setattr__(self, "_slopes", self.slope.tolist())
        # the table by increasing width, for the lookups by width (the same arrays when opening)
        order = slice(None) if self.opening > 0 else slice(None, None, -1)
        object.__setattr__(self, "_w", self.width[order])
        object.__setattr__(self, "_w_angle", self.angle[order])
        object.__setattr__(self, "_w_tcp", self.tcp[order])

    @property
    def opening(self) -> float:
        """+1.0 when a larger drive position opens the gripper, -1.0 when it closes it."""
        return 1.0 if self.width[-1] > self.width[0] else -1.0

    def angle_of(self, width: float) -> float:
        """The drive position (rad or m) at pad opening ``width`` (m), interpolated."""
        return float(np.interp(width, self._w, self._w_angle))

    def width_of(self, angle: float) -> float:
        """The pad opening (m) at drive position ``angle``, interpolated."""
        return float(np.interp(angle, self.angle, self.width))

    def dwidth_dangle(self, angle: float) -> float:
        """Transmission ratio dw/d(drive) (m/rad or m/m) at ``angle``, signed, from the table's
        finite differences. Linear interpolation clamped at the ends, as ``np.interp``; called
        every simulated step."""
        a, k = self._angles, bisect.bisect_right(self._angles, angle)
        if k == 0:
            return self._slopes[0]
        if k == len(a):
            return self._slopes[-1]
        t = (angle - a[k - 1]) / (a[k] - a[k - 1])
        return self._slopes[k - 1] + t * (self._slopes[k] - self._slopes[k - 1])

    def T_base_tcp(self, width: float) -> Transform:
        """Pad-centre midpoint frame in the gripper base frame for opening ``width`` (m).

        The fingertips of a linkage gripper move along arcs, so the point between the pads moves
        along the tool axis as the gripper opens; its axes are those of the base (+z approach,
        +x closing).
        """
        pos = np.array([np.interp(width, self._w, self._w_tcp[:, i]) for i in range(3)])
        return Transform(pos, np.array([0.0, 0.0, 0.0, 1.0]))

    @property
    def width_increasing(self) -> np.ndarray:
        """(k,) the widths in increasing order (``width`` itself when a larger drive opens)."""
        return self._w

    @property
    def tcp_by_width(self) -> np.ndarray:
        """(k, 3) the TCP rows in the order of :attr:`width_increasing`."""
        return self._w_tcp

    @property
    def max_width(self) -> float:
        """The widest opening in the table (m)."""
        return float(self._w[-1])

    @property
    def min_width(self) -> float:
        """The narrowest opening in the table (m)."""
        return float(self._w[0])


@functools.lru_cache(maxsize=8)
def fk_table(
    urdf: str,
    *,
    drive: str,
    pads: tuple[str, str],
    base_link: str,
    pad_thickness: float | None,
    lower: float,
    upper: float,
    samples: int,
) -> WidthTable:
    """Tabulate pad separation and pad-centre midpoint at ``samples`` drive positions.

    ``urdf`` holds the gripper (alone or on an arm), ``drive`` its driven joint, ``pads`` the pad
    links of finger 1 and finger 2, ``base_link`` the gripper's base, ``pad_thickness`` (m) the
    pads' extent along the closing axis (None: their collision boxes' x extent), ``lower`` ..
    ``upper`` the drive's range (rad or m); all but ``urdf`` by keyword. Runs the URDF's
    forward kinematics (kinematic joint resets, no stepping) in a private DIRECT client, so a GUI
    client is never slowed down and every body of the same model in this process shares one table.
    ValueError when the width is not strictly monotonic in the drive.
    """
    client = pb.connect(pb.DIRECT)
    try:
        body = Body.load(client, urdf, fixed_base=True)
        mimic = read_mimic_table(urdf)
        if pad_thickness is None:
            data = pb.getCollisionShapeData(body.uid, body.links[pads[0]], physicsClientId=client)
            pad_thickness = float(data[0][3][0])  # box extents (x, y, z); x is the closing axis
        T_base_world = body.link_pose(base_link).inverse()
        angles = np.linspace(lower, upper, samples)
        widths = np.empty_like(angles)
        tcps = np.empty((len(angles), 3))
        for k, q in enumerate(angles):
            body.reset_joints({drive: q, **{m.follower: m.multiplier * q + m.offset for m in mimic.values()}})
            p1, p2 = (T_base_world * body.link_pose(n) for n in pads)
            widths[k] = (p2.pos[0] - p1.pos[0]) - pad_thickness
            tcps[k] = (p1.pos + p2.pos) / 2
    finally:
        pb.disconnect(physicsClientId=client)
    steps = np.diff(widths)
    if not (np.all(steps > 0) or np.all(steps < 0)):
        raise ValueError(f"the width is not monotonic in the drive {drive!r} over its limits: check {urdf}")
    return WidthTable(angles, widths, tcps)
