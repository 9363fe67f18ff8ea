"""A parallel gripper in PyBullet, built from its description: coupling, width <-> drive, closing.

One class serves every gripper whose fingers one drive moves: revolute four-bar linkages (the
OnRobot RG2, the Robotiq 2F-85) and prismatic fingers (the Franka Hand). PyBullet ignores URDF
``<mimic>`` tags (bullet3 #1140), so the followers are coupled here, from the URDF's own mimic
table, by one of two mechanisms (the description's ``[drive] coupling``, or GripperConfig.coupling):

* ``"gear"``: a ``JOINT_GEAR`` constraint per follower, with ``erp`` > 0 so it does not drift
  (bullet3 #2791). The driven joint's motor moves the whole linkage.
* ``"position"``: per-step position control of each follower towards multiplier x drive.

Passive links (the description's ``[collision] kinematic_links``, e.g. the RG2's inner knuckles)
carry no pad. With ``passive_links="kinematic"`` (the annotation gripper, GripperConfig.passive_links)
they are not coupled and never touch anything while the world steps; they are still posed with the
linkage by every kinematic reset and seen by ``getClosestPoints`` (which ignores collision
filters), so the kinematic collision checks include them.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import numpy as np
import pybullet as pb

from annotator.config import ConfigError, GripperConfig
from annotator.geometry import Transform
from annotator.grippers import GripperDescription, default_gripper
from annotator.sim.body import Body
from annotator.sim.contacts import Contact, contact_points
from annotator.sim.width_table import WidthTable, fk_table

log = logging.getLogger(__name__)
T = TypeVar("T")

# Self-collision on, minus parent/child pairs; ParallelGripper filters the remaining in-finger pairs.
GRIPPER_LOAD_FLAGS = pb.URDF_USE_SELF_COLLISION | pb.URDF_USE_SELF_COLLISION_EXCLUDE_PARENT


@dataclass(frozen=True)
class GripperSettings:
    """The numbers a run simulates the gripper with: the description's, unless the configuration
    sets them. Forces N, speed rad/s or m/s of the drive, friction coefficients (rolling: m)."""

    grip_force: float
    close_speed: float
    pad_lateral_friction: float
    pad_spinning_friction: float
    pad_rolling_friction: float
    coupling: str

    @classmethod
    def resolve(cls, description: GripperDescription, config: GripperConfig) -> GripperSettings:
        """``config``'s overrides on ``description``'s values; ConfigError (one line) for a grip force
        outside the gripper's range."""

        def pick(override: T | None, default: T) -> T:
            return default if override is None else override

        settings = cls(
            grip_force=pick(config.grip_force, description.grip_force),
            close_speed=pick(config.close_speed, description.close_speed),
            pad_lateral_friction=pick(config.pad_lateral_friction, description.pad_lateral_friction),
            pad_spinning_friction=pick(config.pad_spinning_friction, description.pad_spinning_friction),
            pad_rolling_friction=pick(config.pad_rolling_friction, description.pad_rolling_friction),
            coupling=pick(config.coupling, description.coupling),
        )
        lo, hi = description.grip_force_min, description.grip_force_max
        if not lo <= settings.grip_force <= hi:
            raise ConfigError(
                f"[gripper] grip_force: {settings.grip_force:g} N is outside the {description.name}'s "
                f"{lo:g}..{hi:g} N"
            )
        if settings.grip_force > description.grip_force_simulated_max:
            log.warning(
                "%s: a %g N squeeze is above the %g N its model was measured to hold with the default "
                "solver settings (docs/grippers.md)",
                description.name,
                settings.grip_force,
                description.grip_force_simulated_max,
            )
        return settings


@dataclass(frozen=True)
class FingerEnvelope:
    """The two fingers (the collision boxes of the links that keep the base's orientation: finger
    plate and pad) in the TCP frame.

    A parallel gripper's fingers stay parallel to its base, so at any opening they are the same two
    rigid shapes: seen from the TCP at that opening (the pad-centre midpoint), finger ``k`` is
    ``corners[k]`` shifted by ``side[k] * (w - width) / 2`` along x. Placed for opening ``b`` (the
    base fixed) and opened to ``w``, the TCP itself moves by ``tcp(w) - tcp(b)`` (a linkage's
    fingertips travel on arcs). Every such collision shape is a box, so the lowest of these corners
    is the lowest point of the fingers, exactly; links that turn with the opening (knuckles) and
    the housing are not included.

    corners : (2, c, 3) float, box corners of finger 1 and finger 2 at opening ``width``, m;
    side : (2,) float, -1 for finger 1 (at -x), +1 for finger 2; table_width (k,), table_tcp
    (k, 3): the width table by increasing width (the TCP in the base frame per opening, m).
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


class ParallelGripper:
    """A gripper body (floating or on the arm) with its followers coupled and its FK tabulated.

    ``body`` was loaded from ``urdf`` (default: the description's own URDF; the arm's model when
    the gripper is mounted on it), whose gripper links and joints keep the description's names.
    """

    def __init__(
        self,
        body: Body,
        description: GripperDescription | None = None,
        config: GripperConfig | None = None,
        *,
        urdf: Path | str | None = None,
        passive_links: str = "simulated",
    ) -> None:
        """``passive_links``: ``"simulated"`` (the whole linkage coupled and colliding: the arm, the
        GUI) or ``"kinematic"`` (the passive links only posed for kinematic checks; see above)."""
        self.body = body
        self.client = body.client
        self.description = description or default_gripper()
        self.config = config or GripperConfig()
        self.settings = GripperSettings.resolve(self.description, self.config)
        self.coupling = self.settings.coupling
        self.urdf = Path(urdf) if urdf is not None else self.description.urdf
        self.mimic = self.description.mimic_table
        self.driven = self.description.drive_joint
        self.pads = tuple(body.links[name] for name in self.description.pad_links)
        extents = self._pad_extents()
        self.pad_thickness = float(extents[0])  # along the closing axis
        self.pad_face = (float(extents[1]), float(extents[2]))  # across (TCP y) and along the approach (z)
        if passive_links not in ("simulated", "kinematic"):
            raise ValueError(f"unknown passive_links {passive_links!r}; use 'simulated' or 'kinematic'")
        self.passive = self._passive_followers() if passive_links == "kinematic" else ()
        # the followers the coupling moves (every follower unless the passive ones are kinematic)
        self.coupled = tuple(name for name in self.mimic if name not in self.passive)
        for name in self.mimic:
            body.disable_motor(name)  # followers are moved by the coupling only (bullet3 #1140)
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
        # the drive's velocity that closes the gripper at the closing speed (< 0 when a larger
        # drive position opens it, as the RG2's)
        self.close_velocity = -self.table.opening * self.settings.close_speed
        self._last_motor: tuple | None = None  # the driven motor's last command, to skip repeats

    # --- set-up -----------------------------------------------------------------------------

    @property
    def grip_force(self) -> float:
        """The squeeze (N per pad) this run simulates: the description's default unless configured."""
        return self.settings.grip_force

    def _passive_followers(self) -> tuple[str, ...]:
        """Followers whose child link is one of the description's kinematic links (mimic order)."""
        kinematic = set(self.description.kinematic_links)
        return tuple(name for name in self.mimic if self.body.joints[name].child_link in kinematic)

    def _pad_extents(self) -> np.ndarray:
        """The pad's extents (3,), m, in the TCP's axes: x closing, y across, z approach (the
        description's [pads] size, else the pad link's collision box)."""
        if self.description.pad_size is not None:
            return np.asarray(self.description.pad_size, dtype=np.float64)
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
            # ratio is the negated multiplier (checked by tests/test_grippers.py's follower errors).
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
        housing, so those pairs are excluded one by one instead of switching self-collision off
        (a port that switched it off dropped objects, one that left it on jammed).
        """
        fingers = self.description.fingers
        names = [self.description.base_link, *fingers[0], *fingers[1]]
        names = [n for n in names if n in self.description.colliding_links]
        uid, idx = self.body.uid, {n: self.body.links[n] for n in names}
        for a in range(len(names)):
            for b in range(a + 1, len(names)):
                na, nb = names[a], names[b]
                across = (na in fingers[0] and nb in fingers[1]) or (na in fingers[1] and nb in fingers[0])
                if not across:
                    pb.setCollisionFilterPair(uid, uid, idx[na], idx[nb], 0, physicsClientId=self.client)

    def _set_pad_friction(self) -> None:
        s = self.settings
        for link in self.pads:
            pb.changeDynamics(
                self.body.uid,
                link,
                lateralFriction=s.pad_lateral_friction,
                spinningFriction=s.pad_spinning_friction,
                rollingFriction=s.pad_rolling_friction,
                physicsClientId=self.client,
            )

    def _tabulate(self) -> WidthTable:
        """The model's FK over the drive's range, from a private DIRECT copy (cached per URDF)."""
        d, driven = self.description, self.body.joints[self.driven]
        return fk_table(
            str(self.urdf),
            drive=d.drive_joint,
            pads=d.pad_links,
            base_link=d.base_link,
            pad_thickness=None if d.pad_size is None else d.pad_size[0],
            lower=driven.lower,
            upper=driven.upper,
            samples=self.config.width_table_samples,
        )

    # --- kinematics ----------------------------------------------------------------------------

    @property
    def max_width(self) -> float:
        """The widest pad opening the model reaches (m)."""
        return self.table.max_width

    def follower_targets(self, angle: float) -> dict[str, float]:
        """Every coupled joint's position for drive position ``angle`` (driven joint included)."""
        targets = {self.driven: angle}
        for m in self.mimic.values():
            targets[m.follower] = m.multiplier * angle + m.offset
        return targets

    def reset_angle(self, angle: float) -> None:
        """Teleport the linkage to drive position ``angle`` (set-up only)."""
        self.body.reset_joints(self.follower_targets(angle))
        self._last_motor = None  # a new trial (or restored state): send the next command in full

    def reset_width(self, width: float) -> None:
        """Teleport the linkage to pad separation ``width`` (m), clipped to the stroke."""
        self.reset_angle(self.table.angle_of(width))

    def T_base_tcp(self, width: float) -> Transform:
        """Pad-centre midpoint frame in the gripper base frame for opening ``width`` (m)."""
        return self.table.T_base_tcp(width)

    def base_pose(self) -> Transform:
        """World pose of the gripper's base link."""
        return self.body.link_pose(self.description.base_link)

    def finger_envelope(self) -> FingerEnvelope:
        """The fingers' collision boxes in the TCP frame (:class:`FingerEnvelope`), read from the
        model at half the stroke; the linkage is put back where it was."""
        angle = self.driven_angle()
        width = 0.5 * self.max_width
        rigid = self.rigid_finger_links()
        self.reset_width(width)
        try:
            T_tcp_world = (self.base_pose() * self.T_base_tcp(width)).inverse()
            corners, sides = [], []
            for links in rigid:
                points = [T_tcp_world.apply(p) for name in links for p in self._box_corners(name)]
                finger = np.concatenate(points)
                corners.append(finger)
                sides.append(float(np.sign(finger[:, 0].mean())))
        finally:
            self.reset_angle(angle)
        return FingerEnvelope(
            np.stack(corners),
            np.array(sides),
            width,
            self.table.width_increasing.copy(),
            self.table.tcp_by_width.copy(),
        )

    def rigid_finger_links(self) -> list[list[str]]:
        """Each finger's links that keep the base's orientation at every opening (and collide)."""
        lo, hi = self.table.angle[0], self.table.angle[-1]
        angle = self.driven_angle()
        rotations = []
        try:
            for q in (lo, hi):
                self.reset_angle(q)
                T_base_world = self.base_pose().inverse()
                rotations.append(
                    {n: (T_base_world * self.body.link_pose(n)).rotation for n in self._finger_links()}
                )
        finally:
            self.reset_angle(angle)
        out = []
        for finger in self.description.fingers:
            keep = [
                n
                for n in finger
                if n in self.description.colliding_links
                and np.allclose(rotations[0][n], rotations[1][n], atol=1e-6)
                and np.allclose(rotations[0][n], np.eye(3), atol=1e-6)
            ]
            out.append(keep)
        return out

    def _finger_links(self) -> list[str]:
        return [n for finger in self.description.fingers for n in finger]

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
        """The drive joint's position (rad, or m for a prismatic drive)."""
        return self.body.joint_position(self.driven)

    def measured_width(self) -> float:
        """Pad-face separation from the simulated pad poses (m)."""
        p1, p2 = (self.body.link_pose(n) for n in self.description.pad_links)
        x_axis = self.base_pose().rotation[:, 0]
        return float(np.dot(p2.pos - p1.pos, x_axis)) - self.pad_thickness

    def follower_errors(self) -> np.ndarray:
        """|follower - multiplier x drive| for every coupled follower, (n_coupled,) rad or m."""
        q = self.driven_angle()
        names = list(self.coupled)
        actual = self.body.joint_positions(names)
        expected = np.array([self.mimic[n].multiplier * q + self.mimic[n].offset for n in names])
        return np.abs(actual - expected)

    # --- actuation -------------------------------------------------------------------------------

    def command(self, target_velocity: float, force: float, angle: float | None = None) -> None:
        """Drive the linkage at ``target_velocity`` (rad/s or m/s of the drive; :attr:`close_velocity`
        closes) with squeeze ``force`` (N).

        The joint torque (or force) limit is ``force x |dw/d(drive)|`` from the FK table (virtual
        work: the two pads each move dw/2 against ``force``), so a stalled gripper squeezes with
        ``force``. Call it every step while the fingers move: a linkage's transmission ratio changes
        with the angle. ``angle``: the drive position if the caller has just read it (saves a
        joint-state query).
        """
        if angle is None:
            angle = self.driven_angle()
        self._actuate(pb.VELOCITY_CONTROL, {"targetVelocity": target_velocity}, force, angle)

    def squeeze(self, force: float | None = None, angle: float | None = None) -> None:
        """Keep closing at the closing speed with ``force`` (N; default: the run's grip force)."""
        self.command(self.close_velocity, self.grip_force if force is None else force, angle)

    def hold_position(self, angle: float, force: float) -> None:
        """Hold drive position ``angle`` with at most the torque for ``force`` N (GUI slider use)."""
        self._actuate(pb.POSITION_CONTROL, {"targetPosition": angle}, force, angle)

    def _actuate(self, mode: int, target: dict[str, float], force: float, angle: float) -> None:
        """The driven joint's motor in ``mode`` with the torque for ``force`` at ``angle``.

        With ``coupling="position"`` the followers are also position-controlled to their mimic
        targets for the current drive position.
        """
        torque = force * abs(self.table.dwidth_dangle(angle))
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

    def pad_contacts(self, other: int) -> tuple[list[Contact], list[Contact]]:
        """Contact points (:class:`annotator.sim.contacts.Contact`) of pad 1 and pad 2 with body
        ``other`` after the last step."""
        first, second = (contact_points(self.client, self.body.uid, other, link_a=link) for link in self.pads)
        return first, second

    def touches(self, other: int) -> bool:
        """Does either pad touch body ``other``? (one contact query per pad at most)"""
        uid, client = self.body.uid, self.client
        return any(
            pb.getContactPoints(uid, other, linkIndexA=link, physicsClientId=client) for link in self.pads
        )

    def pad_normal_forces(self, other: int) -> np.ndarray:
        """Sum of normal forces (N) on each pad from body ``other``, (2,)."""
        return np.array([sum(c.normal_force for c in pts) for pts in self.pad_contacts(other)])
