"""The physics checks a gripper model must pass before it labels (``annotator gripper check``).

The shipped grippers pass them (tests/test_grippers.py runs the same measurements); a gripper
written from a datasheet may not: a housing too light for the coupling to hold the followers under
the squeeze, a grip force that cannot hold a box through the shake, pads the FK table does not
describe. Each check is one :class:`Verdict`: the figure measured, its limit and, when it fails,
what to change. All run in private DIRECT PyBullet worlds with the annotation worlds' settings
(``[physics]``, ``[gripper]`` of ``config``):

* ``pads follow the FK``: the drive held at 17 widths over the stroke in free air: the measured
  pad separation and the pads' midpoint against the FK table (:data:`FK_LIMIT`), the pads'
  tilt from the base's closing axis (:data:`TILT_LIMIT_DEG`).
* ``followers' drift``: a 40 mm, 200 g box (:data:`BOX_SIZE`, :data:`BOX_MASS`) closed on from
  above with the grip force, squeezed 120 steps, lifted and shaken as the protocol does: the
  largest error of any coupled follower against its ``<mimic>`` target
  (:data:`FOLLOWER_LIMIT`, rad for a linkage, m for sliding fingers).
* ``squeeze``: the pads' normal forces on the box after the squeeze, against the grip force (within
  :data:`FORCE_TOLERANCE`).
* ``box held``: after the lift and the shake the box moved less than :data:`HELD_SLIP` in the hand
  and both pads still press with at least half the grip force.
* ``no success wider than the stroke``: :data:`WIDE_CANDIDATES` candidates sampled on a cube
  30 mm wider than the stroke, labelled by the worker: none may succeed.
"""

from __future__ import annotations

import logging
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from annotator.config import AnnotatorConfig
from annotator.grippers.description import GripperDescription

log = logging.getLogger(__name__)

# The limits are those the shipped grippers are tested against (tests/test_grippers.py).
FK_LIMIT = 5e-4  # m: measured pad separation and pad midpoint against the FK table
TILT_LIMIT_DEG = 1.0  # deg: a pad's closing axis against the base's
# Followers against their mimic targets under the squeeze, lift and shake: 1 deg on a ~55 mm link
# moves a pad ~1 mm; the Panda's sliding fingers stray 0.65 mm under 70 N and 1.1 mm in the shake.
FOLLOWER_LIMIT = {"revolute": float(np.radians(1.0)), "prismatic": 0.0015}
FORCE_TOLERANCE = 0.1  # the pads' normal forces within 10 % of the grip force
BOX_SIZE = 0.04  # m, edge of the box squeezed, lifted and shaken
BOX_MASS = 0.2  # kg
BOX_FRICTION = 1.0  # the box's lateral friction (the pads' shipped default)
HELD_SLIP = 0.01  # m the box may move in the hand through lift and shake
SQUEEZE_STEPS = 120  # steps of squeeze before the forces are read
CLOSE_STEPS = 480  # steps the close may take
FK_WIDTHS = 17  # openings over the stroke where the pads are compared with the FK table
FK_HOLD_STEPS = 120  # steps the drive is held at each
WIDE_CANDIDATES = 30  # candidates labelled on the cube wider than the stroke
WIDE_MARGIN = 0.03  # m the cube is wider than the stroke
DOWN = np.array([1.0, 0.0, 0.0, 0.0])  # xyzw: TCP +z pointing down (a top grasp)


@dataclass(frozen=True)
class Verdict:
    """One check: its ``name``, whether it ``passed``, the ``figure`` measured (a phrase with its
    unit and limit) and ``advice``: what to change when it failed ("" when it passed)."""

    name: str
    passed: bool
    figure: str
    advice: str = ""

    def line(self) -> str:
        """``PASS name: figure`` or ``FAIL name: figure: advice``."""
        head = f"{'PASS' if self.passed else 'FAIL'} {self.name}: {self.figure}"
        return head if self.passed or not self.advice else f"{head}: {self.advice}"


@dataclass(frozen=True)
class Squeeze:
    """What the box test measured: follower error (rad or m), the pads' forces (2,) N after the
    squeeze, the box's movement in the hand (m) and the pads' forces at the end (2,) N."""

    follower_error: float
    forces: np.ndarray
    slip: float
    forces_after: np.ndarray
    grip_force: float
    steps: int
    housing_mass: float  # kg, the base link's


def check_gripper(
    spec: str | Path | GripperDescription, config: AnnotatorConfig | None = None, wide: bool = True
) -> list[Verdict]:
    """Every check of the module docstring on gripper ``spec`` (a name, folder or description),
    with ``config`` (default :class:`AnnotatorConfig`); ``wide``: also label the cube wider than
    the stroke (the slowest check). Raises :class:`DescriptionError` when it cannot be loaded."""
    from annotator.grippers import load_gripper

    description = load_gripper(spec)
    config = config or AnnotatorConfig()
    verdicts = [pads_follow_fk(description, config)]
    squeeze = squeeze_box(description, config)
    verdicts += [
        followers_verdict(description, squeeze),
        force_verdict(description, squeeze),
        held_verdict(description, squeeze),
    ]
    if wide:
        verdicts.append(wider_than_stroke(description, config))
    return verdicts


# (gripper digest, the configuration's sections the checks read) that passed in this process
_PASSED: set[tuple[str, str]] = set()


def check_before_work(spec: str | Path | GripperDescription, config: AnnotatorConfig) -> None:
    """Before a command simulates a gripper of the user's own: the checks of ``annotator gripper
    check --fast`` (:func:`check_gripper` without the cube wider than the stroke, a second or two)
    with the run's ``config``; the first failing verdict is one line,
    :class:`annotator.tools.common.ToolError` (exit 2). Its masses, inertias and inertial origins
    were checked when it was loaded (:mod:`annotator.grippers.inertials`). A shipped gripper is
    not checked again: tests/test_grippers.py runs the same measurements on each. A description that
    cannot be loaded is left to the command, which says why."""
    from annotator.grippers import DescriptionError, load_gripper
    from annotator.grippers.loading import is_shipped
    from annotator.tools.common import ToolError

    try:
        description = load_gripper(spec)
    except DescriptionError:
        return
    key = (description.digest, repr((config.physics, config.gripper, config.protocol)))
    if is_shipped(description) or key in _PASSED:
        return
    try:
        verdicts = check_gripper(description, config, wide=False)
    except Exception as exc:  # a model the checks cannot even simulate
        raise ToolError(
            f"gripper {description.name} ({description.folder}): its physics checks could not run "
            f"({type(exc).__name__}: {exc}); see annotator gripper check"
        ) from None
    failed = [v for v in verdicts if not v.passed]
    if failed:
        where = f"{description.name} ({description.folder})"
        raise ToolError(f"gripper {where} fails annotator gripper check: {failed[0].line()}")
    _PASSED.add(key)


def _base_mass(hand) -> float:
    from annotator.sim import rigid

    return float(rigid.dynamics(hand.client, hand.body.uid).mass)


def pads_follow_fk(description: GripperDescription, config: AnnotatorConfig) -> Verdict:
    """The drive held at :data:`FK_WIDTHS` openings in free air: pads against the FK table."""
    from annotator.geometry import Transform
    from annotator.sim.hand import FloatingGripper
    from annotator.sim.world import World

    with World(config.physics) as world:
        hand = FloatingGripper(world, config.gripper, description)
        hand.teleport(Transform([0.0, 0.0, 0.5], DOWN), 0.5 * hand.gripper.max_width)
        world.set_gravity(False)
        g = hand.gripper
        width_err, tcp_err, tilt = 0.0, 0.0, 0.0
        for width in np.linspace(0.0, g.max_width, FK_WIDTHS):
            for _ in range(FK_HOLD_STEPS):
                g.hold_position(g.table.angle_of(width), g.grip_force)
                world.step()
            T_base_world = hand.base_pose().inverse()
            pads = [T_base_world * hand.body.link_pose(n) for n in description.pad_links]
            width_err = max(width_err, abs(g.measured_width() - width))
            midpoint = (pads[0].pos + pads[1].pos) / 2
            tcp_err = max(tcp_err, float(np.linalg.norm(midpoint - g.T_base_tcp(width).pos)))
            for p in pads:
                tilt = max(tilt, float(np.degrees(np.arccos(np.clip(p.rotation[0, 0], -1.0, 1.0)))))
        mass = _base_mass(hand)
    passed = width_err < FK_LIMIT and tcp_err < FK_LIMIT and tilt < TILT_LIMIT_DEG
    figure = (
        f"over the stroke the pads are {width_err * 1000:.2f} mm from the FK table's width and their "
        f"midpoint {tcp_err * 1000:.2f} mm from its TCP (limit {FK_LIMIT * 1000:.1f} mm), "
        f"tilted {tilt:.2f} deg (limit {TILT_LIMIT_DEG:g} deg)"
    )
    advice = (
        "check the pads' joints (a pad must sit on the chain the drive moves, its face normal along "
        "the base's x), the followers' <mimic> multipliers and offsets, and the finger links' masses "
        f"against the housing's ({mass:.3g} kg): the drive holds them with the [force] default "
        f"({description.grip_force:g} N)"
    )
    return Verdict("pads follow the FK", passed, figure, "" if passed else advice)


def squeeze_box(description: GripperDescription, config: AnnotatorConfig) -> Squeeze:
    """The box test: a :data:`BOX_SIZE` box of :data:`BOX_MASS` closed on from above with the grip
    force (gravity off), squeezed, then lifted and shaken as the protocol does (gravity on)."""
    from annotator.geometry import Transform
    from annotator.sim import rigid
    from annotator.sim.hand import FloatingGripper, ShakeMotion
    from annotator.sim.world import World

    p = config.protocol
    with World(config.physics) as world:
        hand = FloatingGripper(world, config.gripper, description)
        g, force = hand.gripper, hand.grip_force
        half = [BOX_SIZE / 2] * 3
        shape = rigid.collision_shape(world.client, "box", halfExtents=half)
        box = rigid.multibody(
            world.client,
            baseMass=BOX_MASS,
            baseCollisionShapeIndex=shape,
            baseVisualShapeIndex=-1,
            basePosition=[0.0, 0.0, 0.1],
        )
        rigid.change_dynamics(world.client, box, lateralFriction=BOX_FRICTION, spinningFriction=0.002)
        T_world_tcp = Transform([0.0, 0.0, 0.1], DOWN)
        hand.teleport(hand.T_world_base_for_tcp(T_world_tcp, BOX_SIZE), min(BOX_SIZE + 0.02, g.max_width))
        world.set_gravity(False)
        steps = hand.close(force=force, max_steps=CLOSE_STEPS)
        errors: list[float] = []
        for _ in range(SQUEEZE_STEPS):
            g.squeeze(force)
            world.step()
            errors.append(float(g.follower_errors().max(initial=0.0)))
        forces = g.pad_normal_forces(box)
        world.set_gravity(True)
        lifted = Transform(hand.target.pos + [0.0, 0.0, p.lift_height], hand.target.quat)

        def watch(_: int) -> bool:
            errors.append(float(g.follower_errors().max(initial=0.0)))
            return False

        hand.move(lifted, duration=p.lift_duration, force=force, on_step=watch)
        hand.shake(ShakeMotion.of(p), force=force, on_step=watch)
        box_pos = np.asarray(rigid.pose(world.client, box)[0])
        in_hand = (hand.base_pose().inverse() * Transform(box_pos, [0.0, 0.0, 0.0, 1.0])).pos
        slip = float(np.linalg.norm(in_hand - g.T_base_tcp(BOX_SIZE).pos))
        forces_after = g.pad_normal_forces(box)
        mass = _base_mass(hand)
    return Squeeze(max(errors), np.asarray(forces), slip, np.asarray(forces_after), float(force), steps, mass)


def followers_limit(description: GripperDescription) -> float:
    """:data:`FOLLOWER_LIMIT` of the gripper's drive (rad or m)."""
    return FOLLOWER_LIMIT[description.drive_kind]


def followers_verdict(description: GripperDescription, s: Squeeze) -> Verdict:
    """The coupled followers against their mimic targets through squeeze, lift and shake."""
    limit = followers_limit(description)
    passed = s.follower_error < limit
    if description.drive_kind == "revolute":
        shown, unit, bound = np.degrees(s.follower_error), "deg", np.degrees(limit)
    else:
        shown, unit, bound = s.follower_error * 1000, "mm", limit * 1000
    figure = (
        f"followers drift {shown:.2f} {unit} from their <mimic> targets under the {s.grip_force:g} N "
        f"squeeze, lift and shake (limit {bound:.3g} {unit})"
    )
    advice = (
        f"the coupling cannot hold the fingers against the squeeze: raise the housing's mass "
        f"({s.housing_mass:.3g} kg, the base link {description.base_link!r} in the URDF) to the real "
        "gripper's weight less its fingers', or [gripper] coupling_max_force"
        + ('; try [drive] coupling = "gear"' if description.coupling == "position" else "")
    )
    return Verdict("followers' drift", passed, figure, "" if passed else advice)


def force_verdict(description: GripperDescription, s: Squeeze) -> Verdict:
    """The pads' normal forces after the squeeze against the grip force."""
    low, high = float(s.forces.min()), float(s.forces.max())
    passed = bool(np.all(np.abs(s.forces - s.grip_force) < FORCE_TOLERANCE * s.grip_force))
    figure = (
        f"the pads squeeze {low:.1f} and {high:.1f} N for a grip force of {s.grip_force:g} N "
        f"(within {FORCE_TOLERANCE:.0%})"
    )
    if s.follower_error >= followers_limit(description):
        advice = "the followers' drift (above) takes the squeeze: fix it first"
    elif s.steps >= CLOSE_STEPS:
        advice = (
            f"the close never stalled on the {BOX_SIZE * 1000:g} mm box in {CLOSE_STEPS} steps: check "
            "[drive] joint (the joint that closes) and close_speed, and that the pads are the links "
            "that touch the box"
        )
    elif high < 0.5 * s.grip_force:
        advice = (
            "the pads barely touch the box: check [pads] links and size (the pad faces must be the "
            "links that meet the object) and the FK table (the check above)"
        )
    else:
        advice = (
            "the drive's torque is not turned into the squeeze the FK predicts: check the followers' "
            "<mimic> multipliers (the pads must move as the FK table says) and the drive joint's "
            "effort limit"
        )
    return Verdict("squeeze equals the grip force", passed, figure, "" if passed else advice)


def held_verdict(description: GripperDescription, s: Squeeze) -> Verdict:
    """The box through lift and shake: moved less than :data:`HELD_SLIP`, still squeezed."""
    held = s.slip < HELD_SLIP and bool(np.all(s.forces_after > 0.5 * s.grip_force))
    figure = (
        f"a {BOX_MASS * 1000:g} g, {BOX_SIZE * 1000:g} mm box moved {s.slip * 1000:.1f} mm in the hand "
        f"through lift and shake (limit {HELD_SLIP * 1000:g} mm), the pads ending at "
        f"{float(s.forces_after.min()):.1f} N (at least half of {s.grip_force:g} N)"
    )
    advice = (
        f"raise [force] default ({description.grip_force:g} N) to the datasheet's gripping force and "
        f"check [pads] lateral_friction ({description.pad_lateral_friction:g})"
    )
    if s.follower_error >= followers_limit(description):
        advice = "the followers' drift (above) lets the box go: fix it first"
    return Verdict("box held through lift and shake", held, figure, "" if held else advice)


def wider_than_stroke(description: GripperDescription, config: AnnotatorConfig) -> Verdict:
    """:data:`WIDE_CANDIDATES` candidates on a cube :data:`WIDE_MARGIN` wider than the stroke,
    labelled by a worker of the runner's execution (as ``annotate`` labels): none may succeed."""
    import trimesh

    from annotator.objects import ObjectSource
    from annotator.pipeline.in_memory import run_in_memory
    from annotator.pipeline.tasks import GivenGrasps, Span, SpanTask
    from annotator.sampler import object_rng, sample_candidates
    from annotator.sim.hand import max_width

    side = description.stroke_max + WIDE_MARGIN
    mesh = trimesh.creation.box(np.full(3, side))
    stroke = max_width(config, description)
    with tempfile.TemporaryDirectory(prefix="gripper-check-") as folder:
        path = Path(folder) / "wide.obj"
        mesh.export(path)
        source = ObjectSource("wide", path)
        c = sample_candidates(mesh, WIDE_CANDIDATES, object_rng(0, "wide"), config.sampler, stroke)
        given = GivenGrasps(c.T_obj_tcp, c.width_expected)
        task = SpanTask(
            span=Span("wide", source, None, 0, len(c.width_expected), given),
            config=config,
            seed=0,
            n=len(c.width_expected),
            gripper=description,
        )
        (result,) = run_in_memory([task])
    name = "no success wider than the stroke"
    if result.error is not None:
        return Verdict(name, False, f"the cube could not be labelled: {result.error}", "see the error")
    rows = result.rows
    assert rows is not None  # a span without an error has its rows
    outcomes = rows["outcome"].value_counts().to_dict()
    wins = int(outcomes.get("success", 0))
    shown = ", ".join(f"{k} {v}" for k, v in sorted(outcomes.items()))
    figure = (
        f"{wins} of {len(rows)} grasps on a {side * 1000:.0f} mm cube (the stroke "
        f"{description.stroke_max * 1000:.0f} mm + {WIDE_MARGIN * 1000:g}) succeeded ({shown})"
    )
    advice = (
        "the model closes on more than its stroke: check [stroke] max against the datasheet and the "
        "drive joint's limits in the URDF (the FK must not open wider than the real gripper)"
    )
    return Verdict(name, wins == 0, figure, "" if wins == 0 else advice)
