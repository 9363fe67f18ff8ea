"""One grasp trial -> outcome: collision check, close, contacts, lift, shake, still held?

The protocol (docs/protocol.md), with an early exit at each stage:

1. ``collision``: the open gripper intersects the object at the grasp pose or anywhere along the
   approach, or, closed on the expected chord, touches it with anything but the pads, or touches
   an obstacle (the cell's table) anywhere (kinematic checks, no simulation).
2. close with the gripper's force, gravity off (GraspDataGen) for a floating object, on for one
   resting on a support (``annotate --cell``), until the fingers stall.
3. ``no_contact``: not both pads touch the object.
4. ``slipped_lift``: gravity on, lift; the object lost a pad or moved in the hand.
5. ``slipped_motion``: the benchmark's slow motion (when the protocol has one); the object lost a
   pad or moved in the hand.
6. ``slipped_shake``: translations and rotations; the object lost a pad or moved in the hand.
7. ``success``.

Every trial records how far it held (:class:`annotator.outcome.Stage`); the row's ``success`` is
trial 0 held through ``[protocol] gate``. The perturbed trials of ``--trials K`` stop after stage 4
(or 5 with ``RobustConfig.motion``) and are judged there as after a shake, unless their ranges say
``shake`` (``RobustConfig.shake``; docs/decisions/0021).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from annotator.config import AnnotatorConfig, PhysicsConfig, RobustConfig
from annotator.geometry import Transform, axis_angle_to_matrix
from annotator.outcome import Outcome, Stage
from annotator.rng import trial_rng  # noqa: F401  (re-exported)
from annotator.sim import pb
from annotator.sim.contacts import closest_points, touching
from annotator.sim.hand import BenchmarkMotion, FloatingGripper, ShakeMotion
from annotator.sim.world import World

log = logging.getLogger(__name__)


# s the carrier keeps pulling at the end of a simulated approach, so that an unhindered gripper
# reaches the grasp pose (its lag behind the moving target closes) before it is held there.
APPROACH_HOLD = 0.1
# m of a lift-only perturbed trial's simulated approach kept before the first place the open
# gripper would touch anything (RobustConfig.approach_from_contact): the travel through free space
# before it changes nothing but time; the carrier reaches its speed within 1 mm (0.1 m/s, 300 N),
# and the lead is at least one sweep increment, so a contact between increments is never skipped.
# docs/decisions/0022-perturbed-approach-from-contact.md measures it.
APPROACH_LEAD = 0.01
# m/s and rad/s under which the object counts as at rest after a perturbed trial's approach from
# the contact: an object at rest stays so while the fingers travel through free space, so they may
# start near it (GraspTrial._preclose); one the approach set moving is closed on from where it is.
# docs/decisions/0024-perturbed-fingers-start-near-a-resting-object.md measures it.
REST_SPEED = 1e-3
REST_SPIN = 1e-2


@dataclass(frozen=True, eq=False)
class Perturbation:
    """Changes of one robust trial (RobustConfig; docs/decisions/0018-execution-uncertainty.md).

    ``T_tcp_tcp``: the robot's TCP error, in the TCP frame. ``object_shift`` (3,) m and
    ``object_rotvec`` (3,) rad: where the object really is against where the grasp was planned,
    in the world frame, the rotation about the object's centre of mass (yaw about the vertical,
    tilt about horizontal axes). ``friction_delta``: added to the object's friction coefficient;
    ``mass_scale``: its mass and inertia; ``force_scale``: the grip force; ``com_offset`` (3,) m:
    where the centre of mass really sits against the model's, in the object's inertial frame.
    """

    T_tcp_tcp: Transform
    friction_delta: float
    mass_scale: float
    object_shift: np.ndarray = field(default_factory=lambda: np.zeros(3))
    object_rotvec: np.ndarray = field(default_factory=lambda: np.zeros(3))
    force_scale: float = 1.0
    com_offset: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @classmethod
    def none(cls) -> Perturbation:
        return cls(Transform.identity(), 0.0, 1.0)

    @classmethod
    def sample(cls, rng: np.random.Generator, robust: RobustConfig) -> Perturbation:
        """One draw: Gaussian TCP and object pose errors, uniform friction, mass and force changes."""
        rotvec = rng.normal(0.0, robust.rotation_sigma, 3)
        pos = rng.normal(0.0, 1.0, 3) * np.array(
            [robust.position_sigma, robust.position_sigma, robust.approach_sigma]
        )
        friction = rng.uniform(-robust.friction_delta, robust.friction_delta)
        mass = rng.uniform(1.0 - robust.mass_delta, 1.0 + robust.mass_delta)
        shift = np.append(rng.normal(0.0, robust.object_position_sigma, 2), 0.0)
        tilt = rng.normal(0.0, robust.object_tilt_sigma, 2)
        yaw = rng.normal(0.0, robust.object_yaw_sigma)
        force = rng.uniform(1.0 - robust.grip_force_delta, 1.0 + robust.grip_force_delta)
        # drawn last and only when set: the other draws, and so the scores of runs made without
        # it, stay what they were
        com = rng.normal(0.0, robust.com_offset_sigma, 3) if robust.com_offset_sigma > 0 else np.zeros(3)
        if robust.scale_levels:  # exploring the ranges: a level for the pose, one for friction, drawn last
            pose, rub = (
                float(v)
                for v in np.asarray(robust.scale_levels)[rng.integers(0, len(robust.scale_levels), 2)]
            )
            shift, yaw, pos, friction = shift * pose, yaw * pose, pos * pose, friction * rub
        return cls(
            Transform.from_rotation(_rotation(rotvec), pos),
            float(friction),
            float(mass),
            shift,
            np.array([tilt[0], tilt[1], yaw]),
            float(force),
            com,
        )

    def T_obj_tcp(self, T_obj_tcp: Transform, T_world_obj: Transform, com_world: np.ndarray) -> Transform:
        """The grasp as executed, in the frame of the object as it really is: the robot goes to
        ``T_world_obj_planned · T_obj_tcp · T_tcp_tcp`` while the object sits at ``E ·
        T_world_obj_planned`` (``E``: the object's error, rotating about ``com_world`` (3,))."""
        R = _rotation(self.object_rotvec)
        c = np.asarray(com_world, dtype=np.float64)
        if not np.any(self.object_rotvec) and not np.any(self.object_shift):
            return T_obj_tcp * self.T_tcp_tcp
        E = Transform.from_rotation(R, c - R @ c + self.object_shift)
        return T_world_obj.inverse() * E.inverse() * T_world_obj * T_obj_tcp * self.T_tcp_tcp


def _rotation(rotvec: np.ndarray) -> np.ndarray:
    """(3, 3) rotation of a rotation vector (rad)."""
    angle = float(np.linalg.norm(rotvec))
    return axis_angle_to_matrix(rotvec / angle, angle) if angle > 0 else np.eye(3)


@dataclass(frozen=True)
class CollisionCheck:
    """The kinematic collision check of one grasp.

    ``collided``: the open gripper along the approach, or the gripper closed on the expected
    chord with a link other than its pads, touches the object or an obstacle; ``open_width``: the
    opening the approach was checked at (m; the row's ``width`` for a collision); ``stage``:
    ``"approach"`` or ``"closed"`` where it collided (``"pregrasp"``: a simulated approach's start);
    ``hit``: the body touched (PyBullet id).
    """

    collided: bool
    open_width: float
    stage: str | None = None
    hit: int | None = None


@dataclass(frozen=True)
class TrialResult:
    """What one trial measured. ``T_obj_tcp`` is the pad-centre midpoint at the end of closing."""

    outcome: Outcome
    T_obj_tcp: Transform
    width: float  # m, pad separation at the end of closing (open width for collisions)
    steps: int  # simulated steps used
    slip: float  # m, object displacement in the hand from grasp to end (nan if not held)
    check: CollisionCheck | None = None  # the kinematic check the trial began with
    stage: Stage = Stage.NONE  # how far it held (every stage of its plan: Stage.SHAKEN or its last)


@dataclass(frozen=True)
class TrialPlan:
    """Which stages one trial runs and how: trial 0's protocol, or a perturbed trial's
    (:meth:`perturbed`, from ``RobustConfig``; docs/protocol.md, "Robust labels")."""

    shake: bool  # shaken after the lift (False: judged after the lift, or after the motion)
    motion: bool = True  # the benchmark motion after the lift, when the protocol has one
    approach_from_contact: bool = False  # a simulated approach starts near the first contact
    stall_by_travel: bool = False  # the close also ends by the drive's travel (FloatingGripper.close)
    fingers_from_contact: bool = False  # then the fingers start near an object at rest (_preclose)

    @classmethod
    def perturbed(cls, robust: RobustConfig, shake: bool) -> TrialPlan:
        """A perturbed trial's plan in a trial whose own ``shake`` is ``shake``: lift-only unless
        ``robust.shake``, with the shortcuts ``robust`` allows a lift-only trial."""
        lift_only = not robust.shake
        from_contact = lift_only and robust.approach_from_contact
        return cls(
            shake=shake and robust.shake,
            motion=shake and (robust.shake or robust.motion),
            approach_from_contact=from_contact,
            stall_by_travel=lift_only and robust.stall_by_travel,
            fingers_from_contact=from_contact and robust.fingers_from_contact,
        )


class GraspTrial:
    """Runs trials for one object in a world that holds the floating gripper and that object.

    The initial state (gripper parked, object at rest wherever it is: at the world origin for a
    floating object, on the table for the cell) is saved once and restored before every trial.
    ``obstacles``: bodies the gripper must not touch at all in the kinematic checks (the table);
    ``resting``: the object rests on one of them, so gravity stays on while the gripper closes;
    ``shake``: False ends the trial after the lift (judged as after a shake: both pads on the
    object, moved less than ``max_slip`` in the hand), as VGN's trials end; ``obstacle_margin``
    (m): how close the gripper may come to an obstacle in the kinematic checks (default the
    protocol's ``collision_margin``).
    """

    def __init__(
        self,
        world: World,
        hand: FloatingGripper,
        object_uid: int,
        config: AnnotatorConfig,
        *,
        obstacles: Sequence[int] = (),
        resting: bool = False,
        shake: bool = True,
        obstacle_margin: float | None = None,
    ) -> None:
        self.world = world
        self.hand = hand
        self.obj = object_uid
        self.config = config
        self.obstacles = tuple(obstacles)
        self.resting = resting
        self.shake = shake
        self.obstacle_margin = obstacle_margin
        self.client = world.client
        info = pb.getDynamicsInfo(object_uid, -1, physicsClientId=self.client)
        self._mass, self._inertia, self._friction = info[0], np.asarray(info[2]), info[1]
        self._T_com_obj = Transform(info[3], info[4]).inverse()  # mesh frame in the COM frame
        # the perturbed trials' ranges: the run's [robust] over the gripper's own (RobustConfig.over)
        self.robust = config.robust.over(dict(hand.gripper.description.robust))
        # the stage trial 0 must hold through for the row's success ([protocol] gate)
        self.gate = Stage.from_label(config.protocol.gate)
        self.state = world.save_state()

    def close(self) -> None:
        self.world.remove_state(self.state)

    # --- helpers ----------------------------------------------------------------------------

    def _T_world_obj(self) -> Transform:
        pos, orn = pb.getBasePositionAndOrientation(self.obj, physicsClientId=self.client)
        return Transform(pos, orn) * self._T_com_obj

    def _intersects(self, skip_pads: bool = False) -> bool:
        """Does the gripper (without its pads, if ``skip_pads``) intersect the object?"""
        margin = self.config.protocol.collision_margin
        pts = closest_points(self.client, self.hand.uid, self.obj, margin)
        return touching(pts, margin, except_links_a=self.hand.gripper.pads if skip_pads else ())

    def _obstacle_touched(self) -> int | None:
        """The first obstacle any link of the gripper (pads included) touches, or None."""
        margin = (
            self.config.protocol.collision_margin if self.obstacle_margin is None else self.obstacle_margin
        )
        for body in self.obstacles:
            if touching(closest_points(self.client, self.hand.uid, body, margin), margin):
                return body
        return None

    def _both_pads_touch(self) -> bool:
        a, b = self.hand.gripper.pad_contacts(self.obj)
        return bool(a) and bool(b)

    # --- the protocol --------------------------------------------------------------------------

    def collides(self, T_obj_tcp: Transform, width: float) -> CollisionCheck:
        """Kinematic checks: the open gripper at the grasp pose and back along the approach; the
        gripper closed on the expected chord touching the object with its pads only; no obstacle
        touched anywhere."""
        p = self.config.protocol
        open_width = min(self.hand.gripper.max_width, width + 2 * p.pregrasp_clearance)
        T_world_tcp = self._T_world_obj() * T_obj_tcp
        T_world_base = self.hand.T_world_base_for_tcp(T_world_tcp, width)
        approach = T_world_tcp.rotation[:, 2]
        self.hand.gripper.reset_width(open_width)
        n_checks = max(1, int(np.ceil(p.approach_distance / p.approach_step)))
        backwards = (  # from the grasp pose
            Transform(T_world_base.pos - approach * k * p.approach_step, T_world_base.quat)
            for k in range(n_checks + 1)
        )
        touch = self._first_touch(backwards)
        if touch is not None:
            return CollisionCheck(True, open_width, "approach", touch[1])
        # closed on the expected chord, only the pads may touch: a finger link that reaches the
        # object first (e.g. a can's rim under a tilted grasp) would stop the close on it
        self.hand.body.reset_base_pose(T_world_base)
        self.hand.gripper.reset_width(width)
        hit = self._what_is_hit(skip_pads=True)
        if hit is not None:
            return CollisionCheck(True, open_width, "closed", hit)
        return CollisionCheck(False, open_width)

    def _free_travel(self, start: Transform, direction: np.ndarray) -> float:
        """How far (m) the open gripper posed at ``start`` (world) moves along ``direction`` (unit,
        world) in ``approach_step`` increments before it touches anything: the last increment
        that touches nothing; the whole ``approach_distance`` if none touches. Leaves the gripper
        posed wherever the sweep stopped."""
        p = self.config.protocol
        n = max(1, int(np.ceil(p.approach_distance / p.approach_step)))
        forwards = (
            Transform(start.pos + direction * min(k * p.approach_step, p.approach_distance), start.quat)
            for k in range(1, n + 1)
        )
        touch = self._first_touch(forwards)
        return p.approach_distance if touch is None else touch[0] * p.approach_step

    def _first_touch(self, poses: Iterable[Transform]) -> tuple[int, int] | None:
        """``(index, body)`` of the first of ``poses`` (the gripper base in the world, the linkage
        as posed) at which the gripper, pads included, touches anything; None when none does.
        Leaves the gripper at the last pose tried."""
        for i, pose in enumerate(poses):
            self.hand.body.reset_base_pose(pose)
            hit = self._what_is_hit(skip_pads=False)
            if hit is not None:
                return i, hit
        return None

    def _approach(self, T_obj_tcp: Transform, width: float, from_contact: bool = False) -> CollisionCheck:
        """The approach as a robot executes it (``ProtocolConfig.approach = "simulated"``): the
        gripper, open to ``width + 2 x pregrasp_clearance``, starts ``approach_distance`` back along
        the approach (a collision if it touches anything there) and its carrier moves it to the
        grasp pose at ``approach_speed``, pushing with at most ``approach_force``, gravity on as
        the object rests (off for a floating one): what it meets is pushed or stops it, as a real
        arm stops against a board or nudges a misplaced object. The close then starts where the
        gripper came to rest; the carrier holds it there. ``from_contact``: the approach starts
        ``APPROACH_LEAD`` before the first increment of the kinematic sweep that touches anything
        (:meth:`_free_travel`), not ``approach_distance`` back."""
        p = self.config.protocol
        hand = self.hand
        open_width = min(hand.gripper.max_width, width + 2 * p.pregrasp_clearance)
        T_world_tcp = self._T_world_obj() * T_obj_tcp
        T_world_base = hand.T_world_base_for_tcp(T_world_tcp, width)
        start = Transform(
            T_world_base.pos - T_world_tcp.rotation[:, 2] * p.approach_distance, T_world_base.quat
        )
        hand.teleport(start, open_width)
        hit = self._what_is_hit(skip_pads=False)
        if hit is not None:
            return CollisionCheck(True, open_width, "pregrasp", hit)
        travel = p.approach_distance
        if from_contact:
            skip = max(0.0, self._free_travel(start, T_world_tcp.rotation[:, 2]) - APPROACH_LEAD)
            start = Transform(start.pos + T_world_tcp.rotation[:, 2] * skip, start.quat)
            hand.teleport(start, open_width)
            travel -= skip
        self.world.set_gravity(self.resting)
        steps = max(1, round(travel / p.approach_speed / self.world.dt))
        hold = round(APPROACH_HOLD / self.world.dt)
        hand.approach(T_world_base, steps, p.approach_force, hand.gripper.table.angle_of(open_width), hold)
        return CollisionCheck(False, open_width)

    def _at_rest(self) -> bool:
        """Is the object still (below ``REST_SPEED`` and ``REST_SPIN``)?"""
        v, w = pb.getBaseVelocity(self.obj, physicsClientId=self.client)
        return bool(np.linalg.norm(v) < REST_SPEED and np.linalg.norm(w) < REST_SPIN)

    def _preclose(self) -> None:
        """After a perturbed trial's simulated approach from the contact, the object at rest: the
        fingers, where the approach left them, are moved in (at rest) by ``2 x preclose_gap`` of
        width at a time while they touch nothing, and kept at the last width that touches nothing,
        as the teleported approach starts them ``preclose_gap`` outside the chord. Fingers that
        already touch something at the first such width are left exactly as they were."""
        g, uid, client = self.hand.gripper, self.hand.uid, self.client
        step = 2 * self.config.protocol.preclose_gap
        joints = range(pb.getNumJoints(uid, physicsClientId=client))
        before = [s[:2] for s in pb.getJointStates(uid, joints, physicsClientId=client)]
        width = g.measured_width()
        free = None
        while step > 0 and width - step > 0:
            g.reset_width(width - step)
            if self._what_is_hit(skip_pads=False) is not None:
                break
            width -= step
            free = width
        if free is None:
            for j, (position, velocity) in zip(joints, before, strict=True):
                pb.resetJointState(uid, j, position, velocity, physicsClientId=client)
        else:
            g.reset_width(free)

    def _what_is_hit(self, skip_pads: bool) -> int | None:
        """The body the gripper as posed touches: the object first, then any obstacle; None."""
        if self._intersects(skip_pads=skip_pads):
            return self.obj
        return self._obstacle_touched()

    def _apply(self, perturbation: Perturbation) -> None:
        """Object friction and mass for this trial (restoreState does not reset dynamics)."""
        s = perturbation.mass_scale
        pb.changeDynamics(
            self.obj,
            -1,
            mass=self._mass * s,
            localInertiaDiagonal=(self._inertia * s).tolist(),
            lateralFriction=max(0.0, self._friction + perturbation.friction_delta),
            physicsClientId=self.client,
        )

    def run(
        self, T_obj_tcp: Transform, width_expected: float, perturbation: Perturbation | None = None
    ) -> TrialResult:
        """Simulate one candidate grasp from the saved initial state.

        With a ``perturbation`` the grasp is executed with its TCP and object pose errors
        (:meth:`Perturbation.T_obj_tcp`) and grip force, and the object's friction and mass
        change for this trial only: they are set back to the nominal
        ones when it ends, however it ends. Whatever runs next in this world (the next
        candidate's unperturbed trial 0, an object settling on the table in a new orientation,
        another :class:`GraspTrial` of the same body reading its nominal dynamics) then finds the
        object as ``--trials 1`` leaves it, so trial 0 is the same whatever K. A perturbed trial
        shakes only when its ranges say so (``RobustConfig.shake``); otherwise it ends after the
        lift, judged there as after a shake, its simulated approach (if any) starts near the
        first contact (``RobustConfig.approach_from_contact``), its fingers then start near an
        object at rest (``RobustConfig.fingers_from_contact``), and its close ends when the drive
        stalls by travel as well as by speed (``RobustConfig.stall_by_travel``).
        """
        physics = self.world.physics  # a light object's lift and shake may change it (_held_physics)
        if perturbation is not None and np.any(perturbation.com_offset):
            self.world.before_step = _OffsetMass(self, perturbation)
        try:
            if perturbation is None:
                return self._run(T_obj_tcp, width_expected, Perturbation.none())  # trial 0's plan
            plan = TrialPlan.perturbed(self.robust, self.shake)
            return self._run(T_obj_tcp, width_expected, perturbation, plan)
        finally:
            self.world.use(physics)
            if perturbation is not None:
                self.world.before_step = None
                self._apply(Perturbation.none())

    def _run(
        self,
        T_obj_tcp: Transform,
        width_expected: float,
        perturbation: Perturbation,
        plan: TrialPlan | None = None,
    ) -> TrialResult:
        """:meth:`run` with the perturbation applied (its dynamics left as they were set), the
        stages ``plan`` says (None: trial 0's)."""
        plan = TrialPlan(self.shake, motion=self.shake) if plan is None else plan
        self.world.restore_state(self.state)
        self._apply(perturbation)
        com_world = pb.getBasePositionAndOrientation(self.obj, physicsClientId=self.client)[0]
        T_obj_tcp = perturbation.T_obj_tcp(T_obj_tcp, self._T_world_obj(), np.asarray(com_world))
        steps0 = self.world.steps
        cfg, force = self.config.protocol, self.hand.grip_force * perturbation.force_scale
        if cfg.approach == "simulated":
            check = self._approach(T_obj_tcp, width_expected, plan.approach_from_contact)
        else:
            check = self.collides(T_obj_tcp, width_expected)
        open_width = check.open_width
        if check.collided:
            return TrialResult(Outcome.COLLISION, T_obj_tcp, open_width, 0, float("nan"), check)

        # 2. close (gravity off on a free object, on for a resting one). The fingers' travel
        # through free space has no effect but time, so they start preclose_gap outside the
        # expected chord, unless the gripper intersects the object there (a feature inside the
        # chord): then fully open. After a simulated approach they close from where they are,
        # unless the plan moves them in first over an object at rest (_preclose).
        if cfg.approach == "simulated" and plan.fingers_from_contact and self._at_rest():
            self._preclose()
        elif cfg.approach != "simulated":
            T_world_tcp = self._T_world_obj() * T_obj_tcp
            T_world_base = self.hand.T_world_base_for_tcp(T_world_tcp, width_expected)
            start_width = min(open_width, width_expected + 2 * cfg.preclose_gap)
            self.hand.teleport(T_world_base, start_width)
            if start_width < open_width and self._intersects():
                self.hand.teleport(T_world_base, open_width)
        self.world.set_gravity(self.resting)
        max_steps = round(cfg.close_timeout / self.world.dt)
        self.hand.close(force=force, max_steps=max_steps, stall_by_travel=plan.stall_by_travel)
        width = self.hand.gripper.measured_width()
        T_obj_tcp_closed = (
            self._T_world_obj().inverse() * self.hand.base_pose() * self.hand.gripper.T_base_tcp(width)
        )

        def result(outcome: Outcome, stage: Stage, slip: float = float("nan")) -> TrialResult:
            steps = self.world.steps - steps0
            return TrialResult(outcome, T_obj_tcp_closed, width, steps, slip, check, stage)

        # 3. both pads on the object?
        if not self._both_pads_touch():
            return result(Outcome.NO_CONTACT, Stage.NONE)

        # 4. lift with gravity on; a light floating object, closed on at its finer step, is held at
        # the run's time step from here (docs/decisions/0025-light-objects-held-at-the-time-step.md)
        held = self._held_physics()
        if held is not None:
            self.world.use(held)
        grasped_at = self._hand_obj_position()
        self.world.set_gravity(True)
        start = self.hand.target
        lifted = Transform(start.pos + np.array([0.0, 0.0, cfg.lift_height]), start.quat)
        lost = self._loss_monitor(grasped_at)
        self.hand.move(lifted, duration=cfg.lift_duration, force=force, on_step=lost)
        if lost.lost:
            return result(Outcome.SLIPPED_LIFT, Stage.CLOSED)
        # the stages after the lift, each judged as it ends (the last one after the settle)
        motion = BenchmarkMotion.of(cfg)
        # without a motion stage in the protocol, holding through the lift passes it (Stage)
        stages: list[tuple[Outcome, Stage, str | None]] = [
            (Outcome.SLIPPED_LIFT, Stage.LIFTED if motion.active else Stage.MOVED, None)
        ]
        if plan.motion and motion.active:
            stages.append((Outcome.SLIPPED_MOTION, Stage.MOVED, "motion"))
        if plan.shake:
            stages.append((Outcome.SLIPPED_SHAKE, Stage.SHAKEN, "shake"))
        reached = Stage.CLOSED
        for k, (failed, stage, what) in enumerate(stages):
            if what is not None:
                lost = self._loss_monitor(grasped_at)
                if what == "motion":
                    self.hand.benchmark_motion(motion, force=force, on_step=lost)
                else:
                    self.hand.shake(ShakeMotion.of(cfg), force=force, on_step=lost)
                if lost.lost:  # the object left the pads: no settling can bring it back
                    return result(failed, reached, self._slip(grasped_at))
            if k + 1 < len(stages):
                # a stage followed by another: judged as it ends (pads on, slipped less than max_slip)
                if self._both_pads_touch() and self._slip(grasped_at) <= cfg.max_slip:
                    reached = stage
                    continue
                return result(failed, reached, self._slip(grasped_at))
            # the last stage: let it settle, then judge
            for _ in range(round(cfg.settle_time / self.world.dt)):
                self.hand.gripper.squeeze(force)
                self.world.step()
            slip = self._slip(grasped_at)
            if lost.lost or not self._both_pads_touch() or slip > cfg.max_slip:
                return result(failed, reached, slip)
            return result(Outcome.SUCCESS, stage, slip)
        raise AssertionError("unreachable: the stages always end in a verdict")

    def _held_physics(self) -> PhysicsConfig | None:
        """The settings this trial lifts and shakes with once closed (``PhysicsConfig.held``): a
        floating object's only; one resting on a table (the cell, scenes) keeps the world's."""
        if self.resting:
            return None
        return self.world.physics.held(self.config.physics, self._mass)

    def _hand_obj_position(self) -> np.ndarray:
        """The object's centre of mass in the gripper's COM frame, (3,) m (cheap, C-level math)."""
        return np.asarray(self._hand_obj_xyz())

    def _hand_obj_xyz(self) -> tuple[float, float, float]:
        """:meth:`_hand_obj_position` as PyBullet gives it (a tuple: no array per call)."""
        hand = pb.getBasePositionAndOrientation(self.hand.uid, physicsClientId=self.client)
        obj = pb.getBasePositionAndOrientation(self.obj, physicsClientId=self.client)
        inv = pb.invertTransform(hand[0], hand[1])
        x, y, z = pb.multiplyTransforms(inv[0], inv[1], obj[0], obj[1])[0]
        return x, y, z

    def _slip(self, reference: np.ndarray) -> float:
        """How far the object moved in the hand since ``reference`` (from _hand_obj_position), m."""
        return float(np.linalg.norm(self._hand_obj_position() - reference))

    def _loss_monitor(self, reference: np.ndarray) -> _LossMonitor:
        return _LossMonitor(self, reference)


class _LossMonitor:
    """Per-step callback: flags the grasp as lost (early exit) once the object is clearly gone."""

    def __init__(self, trial: GraspTrial, reference: np.ndarray) -> None:
        self.trial = trial
        self.ref = tuple(float(v) for v in reference)
        self.lost = False
        self.every = trial.config.protocol.check_every
        self.lost_distance2 = trial.config.protocol.lost_distance**2

    def __call__(self, i: int) -> bool:
        """Every ``check_every`` steps: lost once no pad touches or the object is ``lost_distance``
        from where it was grasped (plain floats and one contact query per pad at most: this runs
        during every lift and shake)."""
        if i % self.every:
            return False
        t = self.trial
        x, y, z = t._hand_obj_xyz()
        rx, ry, rz = self.ref
        moved2 = (x - rx) ** 2 + (y - ry) ** 2 + (z - rz) ** 2
        if moved2 > self.lost_distance2 or not t.hand.gripper.touches(t.obj):
            self.lost = True
        return self.lost


class _OffsetMass:
    """Before every step of a trial whose object's centre of mass sits ``r`` off the model's: the
    torque that mass puts about the model's centre of mass, ``r_world x m (g - a)``.

    PyBullet cannot move a body's inertial frame once the body is made, so the offset mass is its
    load instead: gravity ``g`` and the inertial force of the body's acceleration ``a`` (from the
    last step's change of velocity) act at the true centre, ``r`` from the simulated one; exact
    for a held or translating object, first order in ``r`` (the terms of angular acceleration
    and rate, and the parallel-axis change of inertia, are left out).
    """

    def __init__(self, trial: GraspTrial, perturbation: Perturbation) -> None:
        self.trial = trial
        self.r_com = tuple(float(v) for v in perturbation.com_offset)
        self.mass = trial._mass * perturbation.mass_scale
        self.velocity: tuple[float, float, float] | None = None

    def __call__(self) -> None:
        t = self.trial
        client, world = t.client, t.world
        v = pb.getBaseVelocity(t.obj, physicsClientId=client)[0]
        if self.velocity is None:
            a = (0.0, 0.0, 0.0)
        else:
            a = tuple((v[i] - self.velocity[i]) / world.dt for i in range(3))
        self.velocity = v
        g = world.physics.gravity if world.gravity_on else 0.0
        orn = pb.getBasePositionAndOrientation(t.obj, physicsClientId=client)[1]
        r = np.asarray(pb.multiplyTransforms((0, 0, 0), orn, self.r_com, (0, 0, 0, 1))[0])
        f = self.mass * np.array([-a[0], -a[1], g - a[2]])
        pb.applyExternalTorque(t.obj, -1, np.cross(r, f).tolist(), pb.WORLD_FRAME, physicsClientId=client)
