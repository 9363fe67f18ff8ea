"""The floating gripper (no arm), carried by a fixed constraint that is moved to approach, lift and shake."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pybullet as pb

from annotator.config import GripperConfig, ProtocolConfig
from annotator.geometry import Transform, axis_angle_to_matrix, matrix_to_quat
from annotator.grippers import GripperDescription, load_gripper
from annotator.sim.body import Body
from annotator.sim.gripper import GRIPPER_LOAD_FLAGS, ParallelGripper
from annotator.sim.world import World

log = logging.getLogger(__name__)


# A per-step callback of a motion: called with the 1-based step index, True stops the motion.
StepCallback = Callable[[int], bool]


@dataclass(frozen=True)
class ShakeMotion:
    """The shake's motions (docs/decisions/0004-short-paired-shake.md).

    ``amplitude`` (m) of the translations and ``angle`` (rad) of the rotations, about the gripper
    base's axes; ``duration`` (s) of all motions together; ``cycles`` sine periods per motion;
    ``paired``: three motions, each translating along and turning about one axis at once (else six,
    translations then rotations).
    """

    amplitude: float
    angle: float
    duration: float
    cycles: int = 1
    paired: bool = False

    @classmethod
    def of(cls, protocol: ProtocolConfig) -> ShakeMotion:
        """The protocol's shake (``shake_amplitude``, ``shake_angle``, ``shake_duration``, ...)."""
        return cls(
            protocol.shake_amplitude,
            protocol.shake_angle,
            protocol.shake_duration,
            protocol.shake_cycles,
            protocol.shake_paired,
        )


@dataclass(frozen=True)
class BenchmarkMotion:
    """A benchmark's slow motion after the lift (docs/protocol.md, "Stages"): turns about the
    closed TCP, to ``+approach_angle``, ``-approach_angle`` and back to 0 (rad) about the approach
    axis, then the same with ``closing_angle`` about the closing axis, in ``duration`` s; each move
    a smoothstep whose time grows with the square root of its angle, so that every move has the
    same peak angular acceleration, ``6 (sum of sqrt(angle))^2 / duration^2``.
    """

    approach_angle: float
    closing_angle: float
    duration: float

    @classmethod
    def of(cls, protocol: ProtocolConfig) -> BenchmarkMotion:
        """The protocol's (``motion_approach_angle``, ``motion_closing_angle``, ``motion_duration``)."""
        return cls(protocol.motion_approach_angle, protocol.motion_closing_angle, protocol.motion_duration)

    @property
    def active(self) -> bool:
        """Does it turn at all (a zero motion is no stage)?"""
        return self.approach_angle > 0 or self.closing_angle > 0

    def moves(self) -> list[tuple[int, float, float]]:
        """``(axis, from, to)`` of each move that turns: axis 2 (the approach, TCP z) or 0 (the
        closing axis, TCP x), angles in rad about it."""
        out = []
        for axis, angle in ((2, self.approach_angle), (0, self.closing_angle)):
            if angle > 0:
                out += [(axis, 0.0, angle), (axis, angle, -angle), (axis, -angle, 0.0)]
        return out

    @property
    def peak_angular_acceleration(self) -> float:
        """rad/s^2, the same in every move (0 without moves)."""
        roots = sum(abs(b - a) ** 0.5 for _, a, b in self.moves())
        return 6.0 * roots**2 / self.duration**2 if roots else 0.0


class FloatingGripper:
    """A gripper body in ``world`` whose base link follows a movable fixed constraint.

    ``gripper``: its description (a name or folder is loaded; default the RG2).
    """

    def __init__(
        self,
        world: World,
        config: GripperConfig | None = None,
        gripper: GripperDescription | str | None = None,
    ) -> None:
        self.world = world
        self.client = world.client
        self.config = config or GripperConfig()
        self.description = load_gripper(gripper)
        sat = pb.URDF_INITIALIZE_SAT_FEATURES if self.config.sat_features else 0
        self.body = Body.load(self.client, self.description.urdf, flags=GRIPPER_LOAD_FLAGS | sat)
        self.gripper = ParallelGripper(
            self.body, self.description, self.config, passive_links=self.config.passive_links
        )
        self._constraint = pb.createConstraint(
            self.body.uid,
            -1,
            -1,
            -1,
            pb.JOINT_FIXED,
            [0, 0, 0],
            self.body.T_com_base.pos.tolist(),  # parent frame: the base link in its COM frame
            [0, 0, 0],
            self.body.T_com_base.quat.tolist(),
            physicsClientId=self.client,
        )
        self.target = Transform.identity()
        self.set_target(self.target)

    # --- placement ---------------------------------------------------------------------------

    @property
    def uid(self) -> int:
        """The gripper body's PyBullet id."""
        return self.body.uid

    @property
    def grip_force(self) -> float:
        """The run's squeeze, N per pad (the description's default unless configured)."""
        return self.gripper.grip_force

    def set_target(self, T_world_base: Transform) -> None:
        """Where the constraint pulls the gripper base link to (the motion is simulated)."""
        self.target = T_world_base
        pb.changeConstraint(
            self._constraint,
            jointChildPivot=T_world_base.pos.tolist(),
            jointChildFrameOrientation=T_world_base.quat.tolist(),
            maxForce=self.config.carrier_max_force,
            physicsClientId=self.client,
        )

    def teleport(self, T_world_base: Transform, width: float) -> None:
        """Put the base link at ``T_world_base`` with the fingers at ``width`` (no simulation)."""
        self.body.reset_base_pose(T_world_base)
        self.set_target(T_world_base)
        self.gripper.reset_width(width)
        for j in self.body.movable_joints:
            pb.resetJointState(
                self.uid, j.index, self.body.joint_position(j.name), 0.0, physicsClientId=self.client
            )

    def base_pose(self) -> Transform:
        """``T_world_base``: the gripper base link's pose in the world."""
        return self.body.link_pose(self.description.base_link)

    def T_world_base_for_tcp(self, T_world_tcp: Transform, width: float) -> Transform:
        """Base pose that puts the pad-centre midpoint at ``T_world_tcp`` at opening ``width``."""
        return T_world_tcp * self.gripper.T_base_tcp(width).inverse()

    # --- motion --------------------------------------------------------------------------------

    def close(
        self,
        *,
        force: float | None = None,
        max_steps: int,
        on_step: Callable[[], None] | None = None,
        stall_by_travel: bool = False,
    ) -> int:
        """Close with squeeze ``force`` (N per pad; None: the run's grip force) until the fingers
        stall or ``max_steps``; ``on_step()`` runs after every step. Returns steps used.

        Stalled: the drive slower than ``stall_fraction x close_speed`` for ``stall_steps`` steps
        in a row, or with ``stall_by_travel`` also (whichever comes first) its travel over the last
        ``stall_steps`` steps no more than that speed covers in that time: fingers that chatter
        about where they squeeze stall too (docs/decisions/0023)."""
        force = self.grip_force if force is None else force
        stalled = 0
        gripper = self.gripper
        velocity = gripper.close_velocity
        stall_speed = self.config.stall_fraction * gripper.settings.close_speed
        stall_steps = self.config.stall_steps
        stall_travel = stall_speed * stall_steps * self.world.dt
        uid, index, client = self.uid, self.body.joints[gripper.driven].index, self.client
        angle = pb.getJointState(uid, index, physicsClientId=client)[0]
        angles = [angle] * stall_steps  # ring: the drive's angle stall_steps steps ago at step % n
        for step in range(1, max_steps + 1):
            gripper.command(velocity, force, angle)
            self.world.step()
            if on_step is not None:
                on_step()
            angle, speed = pb.getJointState(uid, index, physicsClientId=client)[:2]
            stalled = stalled + 1 if abs(speed) < stall_speed else 0
            if stalled >= stall_steps:
                return step
            if stall_by_travel:
                slot = step % stall_steps
                if step >= stall_steps and abs(angle - angles[slot]) <= stall_travel:
                    return step
                angles[slot] = angle
        return max_steps

    def _follow(
        self,
        pos: np.ndarray,
        quat: np.ndarray,
        force: float,
        on_step: StepCallback | None,
    ) -> int:
        """Step once per row of ``pos`` (n, 3) / ``quat`` (n, 4), moving the constraint target.

        Keeps squeezing with ``force``; ``on_step(i)`` returning True stops early. Returns steps.
        """
        cid, client, max_force = self._constraint, self.client, self.config.carrier_max_force
        update_every = self.config.motor_update_every
        pivots, orientations = pos.tolist(), quat.tolist()
        for i in range(len(pos)):
            pb.changeConstraint(
                cid,
                jointChildPivot=pivots[i],
                jointChildFrameOrientation=orientations[i],
                maxForce=max_force,
                physicsClientId=client,
            )
            if i % update_every == 0:
                self.gripper.command(self.gripper.close_velocity, force)
            self.world.step()
            if on_step is not None and on_step(i + 1):
                self.target = Transform(pos[i], quat[i])
                return i + 1
        self.target = Transform(pos[-1], quat[-1])
        return len(pos)

    def move(
        self,
        T_world_base_goal: Transform,
        *,
        duration: float,
        force: float,
        on_step: StepCallback | None = None,
    ) -> int:
        """Move the constraint target to the goal in ``duration`` s: smoothstep in position, slerp
        in rotation.

        ``force`` (N per pad) keeps the fingers squeezing. ``on_step(i)`` may return True to stop early.
        Returns the number of steps simulated.
        """
        start = self.target
        n = max(1, round(duration / self.world.dt))
        s = _smoothstep(np.arange(1, n + 1) / n)
        pos = start.pos + s[:, None] * (T_world_base_goal.pos - start.pos)
        quat = _slerp(start.quat, T_world_base_goal.quat, s)
        return self._follow(pos, quat, force, on_step)

    def approach(
        self, T_world_base_goal: Transform, steps: int, max_force: float, open_angle: float, hold: int = 0
    ) -> int:
        """Move the carrier straight to the goal in ``steps`` steps at constant speed, pulling with
        at most ``max_force`` N (what resists more stops the gripper), the fingers held open at
        ``open_angle``; keep pulling towards the goal for ``hold`` more steps (the carrier's lag
        closes when nothing is in the way); then hold the gripper where it came to rest. Returns
        the steps simulated."""
        start = self.target
        grip = self.gripper.grip_force
        cid, client = self._constraint, self.client
        quat = T_world_base_goal.quat.tolist()
        for i in range(1, steps + hold + 1):
            pos = start.pos + (T_world_base_goal.pos - start.pos) * (min(i, steps) / steps)
            pb.changeConstraint(
                cid,
                jointChildPivot=pos.tolist(),
                jointChildFrameOrientation=quat,
                maxForce=max_force,
                physicsClientId=client,
            )
            self.gripper.hold_position(open_angle, grip)
            self.world.step()
        self.set_target(self.base_pose())
        return steps + hold

    def shake(self, motion: ShakeMotion, *, force: float, on_step: StepCallback | None = None) -> int:
        """Shake about the current target along and about the gripper base axes x, y, z, squeezing
        with ``force`` (N per pad).

        Sequential: six motions, a translation along x, y, z then a rotation about x, y, z.
        ``motion.paired``: three motions, each translating along and rotating about the same axis
        at once. Each motion is ``motion.cycles`` sine periods over ``motion.duration / motions``
        seconds, amplitude ``motion.amplitude`` metres and ``motion.angle`` radians; rotations turn
        about the closed TCP (the grasp, not the flange). Returns steps simulated; ``on_step(i)``
        returning True stops early.
        """
        amplitude, angle, duration = motion.amplitude, motion.angle, motion.duration
        cycles, paired = motion.cycles, motion.paired
        centre = self.target
        motions = 3 if paired else 6
        per = max(1, round(duration / motions / self.world.dt))
        phase = np.sin(2 * np.pi * cycles * np.arange(1, per + 1) / per)  # (per,)
        R = centre.rotation
        pivot = centre.apply(self.gripper.T_base_tcp(0.0).pos)
        zero = np.zeros_like(phase)
        if paired:
            plan = [(axis, phase, phase) for axis in range(3)]  # (axis, translation, rotation)
        else:
            plan = [(axis, phase, zero) for axis in range(3)] + [(axis, zero, phase) for axis in range(3)]
        # the motions' rotations (M, 3, 3) and translated positions (M, 3), M = motions * per,
        # turned into poses in one batch (row for row the same floats as motion by motion)
        R_deltas = np.concatenate([axis_angle_to_matrix(R[:, axis], angle * turn) for axis, _, turn in plan])
        p = np.concatenate(
            [centre.pos + shift[:, None] * (amplitude * R[:, axis]) for axis, shift, _ in plan]
        )
        positions = pivot + np.einsum("nij,nj->ni", R_deltas, p - pivot)
        steps = self._follow(positions, matrix_to_quat(R_deltas @ R), force, on_step)
        self.set_target(centre)
        return steps

    def benchmark_motion(
        self, motion: BenchmarkMotion, *, force: float, on_step: StepCallback | None = None
    ) -> int:
        """Turn about the closed TCP as ``motion`` says (:class:`BenchmarkMotion`), squeezing with
        ``force`` (N per pad), and come back to the current target. Returns the steps simulated;
        ``on_step(i)`` returning True stops early."""
        moves = motion.moves()
        if not moves:
            return 0
        centre = self.target
        T_world_tcp = centre * self.gripper.T_base_tcp(self.gripper.measured_width())
        pivot, R_tcp = T_world_tcp.pos, T_world_tcp.rotation
        roots = np.array([abs(b - a) ** 0.5 for _, a, b in moves])
        rotations, offsets = [], []
        for (axis, a, b), root in zip(moves, roots, strict=True):
            n = max(1, round(motion.duration * root / roots.sum() / self.world.dt))
            angles = a + (b - a) * _smoothstep(np.arange(1, n + 1) / n)
            R = axis_angle_to_matrix(R_tcp[:, axis], angles)  # (n, 3, 3)
            rotations.append(R)
            offsets.append(np.einsum("nij,j->ni", R, centre.pos - pivot))
        R_all = np.concatenate(rotations)
        positions = pivot + np.concatenate(offsets)
        steps = self._follow(positions, matrix_to_quat(R_all @ centre.rotation), force, on_step)
        self.set_target(centre)
        return steps


def _smoothstep(s: np.ndarray) -> np.ndarray:
    """Zero-velocity start and end for constraint motions (less jerk than a linear ramp)."""
    out: np.ndarray = s * s * (3 - 2 * s)
    return out


def _slerp(qa: np.ndarray, qb: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Spherical-linear interpolation of xyzw quaternions: (4,), (4,), s (n,) -> (n, 4)."""
    dot = float(np.dot(qa, qb))
    if dot < 0:
        qb, dot = -qb, -dot
    if dot > 0.9995:
        q = qa[None] + s[:, None] * (qb - qa)[None]
    else:
        theta = np.arccos(dot)
        q = (np.sin((1 - s) * theta)[:, None] * qa + np.sin(s * theta)[:, None] * qb) / np.sin(theta)
    out: np.ndarray = q / np.linalg.norm(q, axis=1, keepdims=True)
    return out
