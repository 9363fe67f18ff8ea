"""The OnRobot RG2 in PyBullet: mimic coupling read from the URDF, width <-> angle from FK, closing.

PyBullet ignores URDF ``<mimic>`` tags (bullet3 #1140), so the followers are coupled here, from the
URDF's own mimic table, by one of two mechanisms chosen with ``coupling``:

* ``"gear"``: a ``JOINT_GEAR`` constraint per follower, with ``erp`` > 0 so it does not drift
  (bullet3 #2791). The driven joint's motor moves the whole linkage.
* ``"position"``: per-step position control of each follower towards multiplier x driven angle.

``tests/test_rg2.py`` and ``bench/rg2_coupling.py`` measure both under a 40 N squeeze; the default
is the one that holds (see GripperConfig.coupling).

The parallelogram's passive links (the inner knuckles) carry no pad: the pads hang off the driven
knuckle and the counter-rotating finger. With ``passive_links="kinematic"`` (the annotation
gripper, GripperConfig.passive_links) they are not coupled and never touch anything while the world
steps; they are still posed with the linkage by every kinematic reset and seen by
``getClosestPoints`` (which ignores collision filters), so the kinematic collision checks include
them. The linkage the solver sees is then 3 gear constraints instead of 5.
"""

from __future__ import annotations

import bisect
import functools
import logging
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pybullet as pb

from annotator.config import GripperConfig
from annotator.geometry import Transform
from annotator.sim.body import Body

log = logging.getLogger(__name__)

PAD_LINKS = ("gripper_finger1_pad_link", "gripper_finger2_pad_link")
FINGER_CHAINS = (
    (
        "gripper_finger1_knuckle_link",
        "gripper_finger1_inner_knuckle_link",
        "gripper_finger1_finger_tip_link",
        "gripper_finger1_pad_link",
    ),
    (
        "gripper_finger2_knuckle_link",
        "gripper_finger2_inner_knuckle_link",
        "gripper_finger2_finger_tip_link",
        "gripper_finger2_pad_link",
    ),
)
BASE_LINK = "rg2_base_link"
TCP_LINK = "tcp"


@dataclass(frozen=True)
class Mimic:
    """``follower = multiplier * driven + offset`` as written in the URDF."""

    follower: str
    driven: str
    multiplier: float
    offset: float


def read_mimic_table(urdf: Path | str) -> dict[str, Mimic]:
    """Parse the ``<mimic>`` tags of a URDF: follower joint name -> :class:`Mimic`."""
    table: dict[str, Mimic] = {}
    for joint in ET.parse(urdf).getroot().iter("joint"):
        mimic = joint.find("mimic")
        if mimic is None:
            continue
        name = joint.attrib["name"]
        table[name] = Mimic(
            follower=name,
            driven=mimic.attrib["joint"],
            multiplier=float(mimic.attrib.get("multiplier", 1.0)),
            offset=float(mimic.attrib.get("offset", 0.0)),
        )
    return table


@dataclass(frozen=True)
class WidthTable:
    """The gripper's forward kinematics sampled over the driven range.

    ``angle`` (k,) driven angle, rad, increasing; ``width`` (k,) pad-face separation, m;
    ``tcp`` (k, 3) pad-centre midpoint in the gripper base frame, m.
    """

    angle: np.ndarray
    width: np.ndarray
    tcp: np.ndarray
    slope: np.ndarray = None  # (k,) dw/dphi, m/rad, filled from the table's finite differences

    def __post_init__(self) -> None:
        if self.slope is None:
            object.__setattr__(self, "slope", np.gradient(self.width, self.angle))
        # plain lists for the per-step scalar lookup (np.interp costs ~5 us per scalar call)
        object.__setattr__(self, "_angles", self.angle.tolist())
        object.__setattr__(self, "_slopes", self.slope.tolist())

    def angle_of(self, width: float) -> float:
        return float(np.interp(width, self.width, self.angle))

    def width_of(self, angle: float) -> float:
        return float(np.interp(angle, self.angle, self.width))

    def dwidth_dangle(self, angle: float) -> float:
        """Transmission ratio dw/dphi (m/rad) at ``angle``, from the table's finite differences.

        Linear interpolation clamped at the ends, as ``np.interp``; called every simulated step.
        """
        a, k = self._angles, bisect.bisect_right(self._angles, angle)
        if k == 0:
            return self._slopes[0]
        if k == len(a):
            return self._slopes[-1]
        t = (angle - a[k - 1]) / (a[k] - a[k - 1])
        return self._slopes[k - 1] + t * (self._slopes[k] - self._slopes[k - 1])

    def T_base_tcp(self, width: float) -> Transform:
        """Pad-centre midpoint frame in the gripper base frame for opening ``width`` (m).

        The fingertips move along arcs, so the point between the pads moves along the tool axis
        as the gripper opens; its axes are those of the base (+z approach, +x closing).
        """
        pos = np.array([np.interp(width, self.width, self.tcp[:, i]) for i in range(3)])
        return Transform(pos, np.array([0.0, 0.0, 0.0, 1.0]))

    @property
    def max_width(self) -> float:
        return float(self.width[-1])

    @property
    def min_width(self) -> float:
        return float(self.width[0])


@dataclass(frozen=True)
class FingerEnvelope:
    """The RG2's two fingers (the collision boxes of finger plate and pad) in the TCP frame.

    The parallelogram linkage keeps each finger parallel to the gripper base, so at any opening the
    fingers are the same two rigid shapes: seen from the TCP at that opening (the pad-centre
    midpoint), finger ``k`` is ``corners[k]`` shifted by ``side[k] * (w - width) / 2`` along x.
    Placed for opening ``b`` (the base fixed) and opened to ``w``, the TCP itself moves by
    ``tcp(w) - tcp(b)`` (the fingertips travel on arcs). Every collision shape of a finger is a
    box, so the lowest of these corners is the lowest point of the fingers, exactly; the knuckle
    links and the housing behind them are not included (they turn with the opening).

    corners : (2, c, 3) float, box corners of finger 1 and finger 2 at opening ``width``, m;
    side : (2,) float, -1 for finger 1 (at -x), +1 for finger 2; table_width (k,), table_tcp
    (k, 3): the width table (the TCP in the base frame per opening, m).
    """

    corners: np.ndarray
    side: np.ndarray
    width: float
    table_width: np.ndarray
    table_tcp: np.ndarray

    def corners_at(self, width: np.ndarray, base_width: np.ndarray) -> np.ndarray:
        """Finger corners (n, 2c, 3) in the frame of the TCP placed for opening ``base_width`` (n,)
        with the fingers opened to ``width`` (n,), m."""
        width = np.asarray(width, dtype=float)
        base_width = np.asarray(base_width, dtype=float)
        shift = np.stack(
            [
                np.interp(width, self.table_width, self.table_tcp[:, i])
                - np.interp(base_width, self.table_width, self.table_tcp[:, i])
                for i in range(3)
            ],
            axis=-1,
        )  # (n, 3)
        spread = (width - self.width)[:, None, None] / 2.0 * self.side[None, :, None]  # (n, 2, 1)
        out = self.corners[None] + shift[:, None, None, :]  # (n, 2, c, 3)
        out[..., 0] += spread
        return out.reshape(width.shape[0], 2 * self.corners.shape[1], 3)


@functools.lru_cache(maxsize=8)
def fk_table(urdf: str, lower: float, upper: float, samples: int) -> WidthTable:
    """Tabulate pad separation and pad-centre midpoint at ``samples`` angles over ``lower..upper``.

    Runs the URDF's forward kinematics (kinematic joint resets, no stepping) in a private
    DIRECT client, so a GUI client is never slowed down and every body of the same model in this
    process shares one table.
    """
    client = pb.connect(pb.DIRECT)
    try:
        body = Body.load(client, urdf, fixed_base=True)
        mimic = read_mimic_table(urdf)
        driven = {m.driven for m in mimic.values()}.pop()
        data = pb.getCollisionShapeData(body.uid, body.links[PAD_LINKS[0]], physicsClientId=client)
        pad_thickness = float(data[0][3][0])  # box extents (x, y, z); x is the closing axis
        T_base_world = body.link_pose(BASE_LINK).inverse()
        angles = np.linspace(lower, upper, samples)
        widths = np.empty_like(angles)
        tcps = np.empty((len(angles), 3))
        for k, q in enumerate(angles):
            body.reset_joints(
                {driven: q, **{m.follower: m.multiplier * q + m.offset for m in mimic.values()}}
            )
            p1, p2 = (T_base_world * body.link_pose(n) for n in PAD_LINKS)
            widths[k] = (p2.pos[0] - p1.pos[0]) - pad_thickness
            tcps[k] = (p1.pos + p2.pos) / 2
    finally:
        pb.disconnect(physicsClientId=client)
    if np.any(np.diff(widths) <= 0):
        raise ValueError(f"RG2 width is not monotonic in the driven angle: check {urdf}")
    return WidthTable(angles, widths, tcps)


class RG2:
    """An RG2 body (floating or on the arm) with its followers coupled and its FK tabulated."""

    def __init__(
        self,
        body: Body,
        urdf: Path | str,
        config: GripperConfig | None = None,
        *,
        passive_links: str = "simulated",
    ) -> None:
        """``passive_links``: ``"simulated"`` (the whole linkage coupled and colliding: the arm, the
        GUI) or ``"kinematic"`` (the passive links only posed for kinematic checks; see above)."""
        self.body = body
        self.client = body.client
        self.config = config or GripperConfig()
        self.coupling = self.config.coupling
        self.urdf = Path(urdf)
        self.mimic = read_mimic_table(urdf)
        drivers = {m.driven for m in self.mimic.values()}
        if len(drivers) != 1:
            raise ValueError(f"expected one driven joint in the mimic table, found {sorted(drivers)}")
        self.driven = drivers.pop()
        self.pads = tuple(body.links[name] for name in PAD_LINKS)
        extents = self._pad_extents()
        self.pad_thickness = float(extents[0])  # along the closing axis
        self.pad_face = (float(extents[1]), float(extents[2]))  # across (TCP y) and along the approach (z)
        if passive_links not in ("simulated", "kinematic"):
            raise ValueError(f"unknown passive_links {passive_links!r}; use 'simulated' or 'kinematic'")
        self.passive = self._passive_followers() if passive_links == "kinematic" else ()
        # the followers the coupling moves (every follower unless the passive ones are kinematic)
        self.coupled = tuple(name for name in self.mimic if name not in self.passive)
        for name in self.mimic:
            body.disable_motor(name)  # followers are moved by the coupling only (pitfall 3)
        for name in self.passive:
            link = self.body.joints[name].index
            pb.setCollisionFilterGroupMask(body.uid, link, 0, 0, physicsClientId=self.client)
        self._constraints: list[int] = []
        if self.coupling == "gear":
            self._add_gear_constraints()
        elif self.coupling != "position":
            raise ValueError(f"unknown coupling {self.coupling!r}; use 'gear' or 'position'")
        self._filter_self_collisions()
        self._set_pad_friction()
        self.table = self._tabulate()
        self._last_motor: tuple | None = None  # the driven motor's last command, to skip repeats

    # --- set-up -----------------------------------------------------------------------------

    def _passive_followers(self) -> tuple[str, ...]:
        """Followers whose link is not on a pad's chain to the base: the passive links."""
        on_pad_chain: set[int] = set()
        for link in self.pads:
            while link >= 0:
                on_pad_chain.add(link)
                link = pb.getJointInfo(self.body.uid, link, physicsClientId=self.client)[16]
        return tuple(name for name in self.mimic if self.body.joints[name].index not in on_pad_chain)

    def _pad_extents(self) -> np.ndarray:
        """The pad box's extents (3,), m, in the TCP's axes: x closing, y across, z approach."""
        data = pb.getCollisionShapeData(self.body.uid, self.pads[0], physicsClientId=self.client)
        return np.asarray(data[0][3], dtype=np.float64)

    def _add_gear_constraints(self) -> None:
        driven = self.body.joints[self.driven].index
        for name in self.coupled:
            m = self.mimic[name]
            follower = self.body.joints[m.follower].index
            c = pb.createConstraint(
                self.body.uid,
                driven,
                self.body.uid,
                follower,
                jointType=pb.JOINT_GEAR,
                jointAxis=[0, 1, 0],
                parentFramePosition=[0, 0, 0],
                childFramePosition=[0, 0, 0],
                physicsClientId=self.client,
            )
            # Bullet's gear row enforces q_driven * ratio + q_follower = offset-free, so the
            # ratio is the negated multiplier (checked by tests/test_rg2.py's follower errors).
            pb.changeConstraint(
                c,
                gearRatio=-m.multiplier,
                maxForce=self.config.coupling_max_force,
                erp=self.config.coupling_erp,
                physicsClientId=self.client,
            )
            self._constraints.append(c)

    def _filter_self_collisions(self) -> None:
        """Keep only finger-1 vs finger-2 self-contacts (the pads meet when closed).

        Links of one finger overlap at their shared pivots and the outer links start inside the
        housing, so those pairs are excluded one by one (ROBOT_FACTS pitfall 6) instead of
        switching self-collision off.
        """
        uid, names = self.body.uid, [BASE_LINK, *FINGER_CHAINS[0], *FINGER_CHAINS[1]]
        idx = {n: self.body.links[n] for n in names}
        for a in range(len(names)):
            for b in range(a + 1, len(names)):
                na, nb = names[a], names[b]
                across = (na in FINGER_CHAINS[0] and nb in FINGER_CHAINS[1]) or (
                    na in FINGER_CHAINS[1] and nb in FINGER_CHAINS[0]
                )
                if not across:
                    pb.setCollisionFilterPair(uid, uid, idx[na], idx[nb], 0, physicsClientId=self.client)

    def _set_pad_friction(self) -> None:
        for link in self.pads:
            pb.changeDynamics(
                self.body.uid,
                link,
                lateralFriction=self.config.pad_lateral_friction,
                spinningFriction=self.config.pad_spinning_friction,
                rollingFriction=self.config.pad_rolling_friction,
                physicsClientId=self.client,
            )

    def _tabulate(self) -> WidthTable:
        """The model's FK over the driven range, from a private DIRECT copy (cached per URDF)."""
        driven = self.body.joints[self.driven]
        return fk_table(str(self.urdf), driven.lower, driven.upper, self.config.width_table_samples)

    # --- kinematics ----------------------------------------------------------------------------

    @property
    def max_width(self) -> float:
        return self.table.max_width

    def follower_targets(self, angle: float) -> dict[str, float]:
        """Every coupled joint's position for driven angle ``angle`` (driven joint included)."""
        targets = {self.driven: angle}
        for m in self.mimic.values():
            targets[m.follower] = m.multiplier * angle + m.offset
        return targets

    def reset_angle(self, angle: float) -> None:
        """Teleport the linkage to driven angle ``angle`` (set-up only)."""
        self.body.reset_joints(self.follower_targets(angle))
        self._last_motor = None  # a new trial (or restored state): send the next command in full

    def reset_width(self, width: float) -> None:
        """Teleport the linkage to pad separation ``width`` (m), clipped to the stroke."""
        self.reset_angle(self.table.angle_of(width))

    def T_base_tcp(self, width: float) -> Transform:
        """Pad-centre midpoint frame in the gripper base frame for opening ``width`` (m)."""
        return self.table.T_base_tcp(width)

    def finger_envelope(self) -> FingerEnvelope:
        """The fingers' collision boxes in the TCP frame (:class:`FingerEnvelope`), read from the
        model at half the stroke; the linkage is put back where it was."""
        angle = self.driven_angle()
        width = 0.5 * self.max_width
        self.reset_width(width)
        try:
            T_tcp_world = (self.body.base_pose() * self.T_base_tcp(width)).inverse()
            corners, sides = [], []
            for chain in FINGER_CHAINS:
                points = [T_tcp_world.apply(p) for name in chain[2:] for p in self._box_corners(name)]
                finger = np.concatenate(points)
                corners.append(finger)
                sides.append(float(np.sign(finger[:, 0].mean())))
        finally:
            self.reset_angle(angle)
        return FingerEnvelope(
            np.stack(corners), np.array(sides), width, self.table.width.copy(), self.table.tcp.copy()
        )

    def _box_corners(self, link: str) -> list[np.ndarray]:
        """World corners (8, 3) of each collision box of ``link`` (its shapes' frames are given in
        the link's inertial frame, the pose getLinkState reports first)."""
        index = self.body.links[link]
        state = pb.getLinkState(self.body.uid, index, computeForwardKinematics=1, physicsClientId=self.client)
        T_world_com = Transform(state[0], state[1])
        out = []
        for shape in pb.getCollisionShapeData(self.body.uid, index, physicsClientId=self.client):
            if shape[2] != pb.GEOM_BOX:
                raise ValueError(f"{link}: the finger envelope expects box collision shapes")
            half = 0.5 * np.asarray(shape[3])
            signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1], indexing="ij")).reshape(3, -1).T
            T_world_box = T_world_com * Transform(shape[5], shape[6])
            out.append(T_world_box.apply(signs * half))
        return out

    def driven_angle(self) -> float:
        return self.body.joint_position(self.driven)

    def measured_width(self) -> float:
        """Pad-face separation from the simulated pad poses (m)."""
        p1, p2 = (self.body.link_pose(n) for n in PAD_LINKS)
        x_axis = self.body.link_pose(BASE_LINK).rotation[:, 0]
        return float(np.dot(p2.pos - p1.pos, x_axis)) - self.pad_thickness

    def follower_errors(self) -> np.ndarray:
        """|follower - multiplier x driven| for every coupled follower, (n_coupled,) rad."""
        q = self.driven_angle()
        names = list(self.coupled)
        actual = self.body.joint_positions(names)
        expected = np.array([self.mimic[n].multiplier * q + self.mimic[n].offset for n in names])
        return np.abs(actual - expected)

    # --- actuation -------------------------------------------------------------------------------

    def command(self, target_velocity: float, force: float, angle: float | None = None) -> None:
        """Drive the linkage at ``target_velocity`` (rad/s, < 0 closes) with squeeze ``force`` (N).

        The joint torque limit is ``force x dw/dphi`` from the FK table (virtual work: the two pads
        each move dw/2 against ``force``), so a stalled gripper squeezes with ``force``. Call it
        every step while the fingers move: the transmission ratio changes with the angle.
        ``angle``: the driven angle if the caller has just read it (saves a joint-state query).
        """
        if angle is None:
            angle = self.driven_angle()
        self._actuate(pb.VELOCITY_CONTROL, {"targetVelocity": target_velocity}, force, angle)

    def hold_position(self, angle: float, force: float) -> None:
        """Hold driven angle ``angle`` with at most the torque for ``force`` N (GUI slider use)."""
        self._actuate(pb.POSITION_CONTROL, {"targetPosition": angle}, force, angle)

    def _actuate(self, mode: int, target: dict[str, float], force: float, angle: float) -> None:
        """The driven joint's motor in ``mode`` with the torque for ``force`` at ``angle``.

        With ``coupling="position"`` the followers are also position-controlled to their mimic
        targets for the current driven angle.
        """
        torque = force * self.table.dwidth_dangle(angle)
        last = self._last_motor
        if (
            self.coupling == "gear"
            and last is not None
            and last[0] == mode
            and last[1] == target
            and abs(last[2] - torque) <= self.config.motor_torque_rtol * torque
        ):
            return  # the motor still holds this command (stalled fingers: the ratio barely moves)
        self._last_motor = (mode, target, torque)
        joint = self.body.joints[self.driven]
        pb.setJointMotorControl2(
            self.body.uid, joint.index, mode, force=torque, physicsClientId=self.client, **target
        )
        if self.coupling == "position":
            targets = self.follower_targets(self.driven_angle())
            targets = {name: targets[name] for name in self.coupled}
            self.body.position_control(targets, {n: self.config.coupling_max_force for n in targets})

    # --- contacts --------------------------------------------------------------------------------

    def pad_contacts(self, other: int) -> tuple[list, list]:
        """Contact points of pad 1 and pad 2 with body ``other``."""
        return tuple(
            pb.getContactPoints(self.body.uid, other, linkIndexA=link, physicsClientId=self.client)
            for link in self.pads
        )

    def touches(self, other: int) -> bool:
        """Does either pad touch body ``other``? (one contact query per pad at most)"""
        uid, client = self.body.uid, self.client
        return any(
            pb.getContactPoints(uid, other, linkIndexA=link, physicsClientId=client) for link in self.pads
        )

    def pad_normal_forces(self, other: int) -> np.ndarray:
        """Sum of normal forces (N) on each pad from body ``other``, (2,)."""
        return np.array([sum(c[9] for c in pts) for pts in self.pad_contacts(other)])
