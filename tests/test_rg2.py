"""The RG2 really grips: mimic coupling under squeeze, FK width mapping, hold / miss / impossible."""

from __future__ import annotations

import numpy as np
import pybullet as pb
import pytest
from conftest import make_box

from annotator import paths
from annotator.config import GripperConfig, PhysicsConfig
from annotator.geometry import Transform
from annotator.sim.body import Body
from annotator.sim.hand import FloatingRG2
from annotator.sim.rg2 import PAD_LINKS, RG2, read_mimic_table
from annotator.sim.world import World

DOWN = np.array([1.0, 0.0, 0.0, 0.0])  # TCP +z pointing down (-z world): a top grasp
SEED_MIMIC = {
    "gripper_finger2_joint": -1.0,
    "gripper_finger1_inner_knuckle_joint": 1.0,
    "gripper_finger2_inner_knuckle_joint": -1.0,
    "gripper_finger1_finger_tip_joint": -1.0,
    "gripper_finger2_finger_tip_joint": 1.0,
}


def grasp_box(hand: FloatingRG2, box: int, size: float, force: float = 40.0) -> None:
    """Place the open gripper around ``box`` from above and close it, gravity off."""
    T_world_tcp = Transform(
        np.asarray(pb.getBasePositionAndOrientation(box, physicsClientId=hand.client)[0]), DOWN
    )
    hand.teleport(hand.T_world_base_for_tcp(T_world_tcp, size), min(size + 0.02, hand.rg2.max_width))
    hand.world.set_gravity(False)
    hand.close(force, max_steps=480)


def box_pos(world: World, box: int) -> np.ndarray:
    return np.asarray(pb.getBasePositionAndOrientation(box, physicsClientId=world.client)[0])


@pytest.mark.parametrize("urdf", [paths.rg2_urdf(), paths.ur3_rg2_urdf()], ids=["floating", "on_ur3"])
def test_mimic_table_read_from_urdf_has_seed_multipliers(urdf):
    table = read_mimic_table(urdf)
    assert {k: m.multiplier for k, m in table.items()} == SEED_MIMIC
    assert {m.driven for m in table.values()} == {"gripper_finger1_joint"}


def test_width_mapping_matches_forward_kinematics(world):
    """Commanding a width 0..110 mm gives that pad separation within 1 mm (dynamic, free air)."""
    body = Body.load(world.client, paths.rg2_urdf(), fixed_base=True)
    rg2 = RG2(body, paths.rg2_urdf(), GripperConfig())
    world.set_gravity(False)
    errors = []
    for width in np.linspace(0.0, 0.110, 12):
        angle = rg2.table.angle_of(width)
        for _ in range(240):
            rg2.hold_position(angle, 40.0)
            world.step()
        errors.append(abs(rg2.measured_width() - width))
    assert max(errors) < 1e-3, np.round(np.array(errors) * 1000, 2)


def test_fully_open_reaches_the_110mm_stroke(world):
    body = Body.load(world.client, paths.rg2_urdf(), fixed_base=True)
    rg2 = RG2(body, paths.rg2_urdf(), GripperConfig())
    rg2.reset_angle(body.joints[rg2.driven].upper)
    assert rg2.measured_width() == pytest.approx(0.110, abs=0.002)
    rg2.reset_angle(body.joints[rg2.driven].lower)
    assert rg2.measured_width() == pytest.approx(0.0, abs=0.001)


def test_tcp_link_is_midway_between_closed_pads(world):
    body = Body.load(world.client, paths.rg2_urdf(), fixed_base=True)
    rg2 = RG2(body, paths.rg2_urdf(), GripperConfig())
    rg2.reset_width(0.0)
    p1, p2 = (body.link_pose(n).pos for n in ("gripper_finger1_pad_link", "gripper_finger2_pad_link"))
    assert np.allclose(body.link_pose("tcp").pos, (p1 + p2) / 2, atol=1e-4)
    # finger 1 sits at -x, finger 2 at +x of the TCP frame: +x is the closing direction 1 -> 2
    T_tcp_world = body.link_pose("tcp").inverse()
    assert T_tcp_world.apply(p1)[0] < 0 < T_tcp_world.apply(p2)[0]


def test_squeeze_force_matches_command(world, hand):
    box = make_box(world, 0.04, 0.05)
    for commanded in (20.0, 40.0):
        grasp_box(hand, box, 0.04, force=commanded)
        for _ in range(60):
            hand.rg2.command(-hand.config.close_speed, commanded)
            world.step()
        measured = hand.rg2.pad_normal_forces(box)
        assert measured[0] == pytest.approx(commanded, rel=0.25)
        assert measured[1] == pytest.approx(commanded, rel=0.25)


def test_holds_a_40mm_box_through_lift_and_shake(world, hand):
    box = make_box(world, 0.04, 0.05)
    grasp_box(hand, box, 0.04)
    world.set_gravity(True)
    start = hand.target
    hand.move(Transform(start.pos + [0, 0, 0.10], start.quat), duration=0.5, force=40.0)
    lifted = box_pos(world, box)
    assert lifted[2] > 0.1 + 0.09, "box did not follow the 10 cm lift"
    hand.shake(amplitude=0.03, angle=np.radians(25), duration=1.5, force=40.0)
    T_tcp_world = (hand.base_pose() * hand.rg2.T_base_tcp(0.04)).inverse()
    slip = np.linalg.norm(T_tcp_world.apply(box_pos(world, box)))
    assert slip < 0.01, f"box slipped {slip * 1000:.1f} mm in the hand"
    assert np.all(hand.rg2.pad_normal_forces(box) > 10.0)


@pytest.mark.parametrize("paired", [False, True], ids=["sequential", "paired"])
def test_shake_moves_the_gripper_by_its_amplitude_and_angle(world, hand, paired):
    """The carried gripper really follows the shake: reaches the amplitude and angle, comes back.

    Sequential: translations first (no rotation), then rotations about the TCP. Paired: each axis
    translates and rotates at once, in half the motions.
    """
    world.set_gravity(False)
    centre = Transform([0.0, 0.0, 0.5], DOWN)
    hand.teleport(centre, 0.04)
    tcp0 = centre.apply(hand.rg2.T_base_tcp(0.0).pos)
    shifts, angles = [], []

    def record(i: int) -> bool:
        pose = hand.base_pose()
        shifts.append(np.linalg.norm(pose.apply(hand.rg2.T_base_tcp(0.0).pos) - tcp0))
        dq = abs(float(np.dot(pose.quat, centre.quat)))
        angles.append(2 * np.arccos(min(1.0, dq)))
        return False

    amplitude, angle = 0.03, np.radians(20)
    steps = hand.shake(amplitude, angle, duration=1.2, force=40.0, on_step=record, paired=paired)
    motions = 3 if paired else 6
    assert steps == motions * round(1.2 / motions / world.dt) == len(shifts)
    for _ in range(48):  # the carrier lags the target a little: 0.2 s to settle
        world.step()
        record(0)
    shift, turn = np.array(shifts), np.array(angles)
    assert shift[:steps].max() == pytest.approx(amplitude, rel=0.2)
    assert turn[:steps].max() == pytest.approx(angle, rel=0.2)
    assert shift[-1] < 0.002 and turn[-1] < np.radians(1)  # back at the centre
    if not paired:
        assert turn[: steps // 2].max() < np.radians(2)  # the translations do not rotate
        assert shift[steps // 2 + 24 : steps].max() < 0.1 * amplitude  # rotations turn about the TCP
    else:
        first = slice(0, steps // 3)  # x: translates and turns at the same time
        assert shift[first].max() > 0.8 * amplitude and turn[first].max() > 0.8 * angle


def test_closing_on_nothing_ends_closed_without_contact(world, hand):
    box = make_box(world, 0.04, 0.05, pos=(0.5, 0.0, 0.1))  # far away
    hand.teleport(Transform([0, 0, 0.5], DOWN), 0.08)
    world.set_gravity(False)
    steps = hand.close(40.0, max_steps=480)
    assert steps < 480, "closing never finished"
    assert hand.rg2.measured_width() < 0.002
    assert not any(hand.rg2.pad_contacts(box))


def test_150mm_box_does_not_fit_in_the_open_gripper(world, hand):
    """The open gripper (110 mm) around a 150 mm box's centre intersects it: impossible grasp."""
    box = make_box(world, 0.15, 0.5)
    T_world_tcp = Transform([0, 0, 0.1], DOWN)
    hand.teleport(hand.T_world_base_for_tcp(T_world_tcp, hand.rg2.max_width), hand.rg2.max_width)
    pb.performCollisionDetection(physicsClientId=world.client)
    penetrations = [c[8] for c in pb.getClosestPoints(hand.uid, box, 0.0, physicsClientId=world.client)]
    assert penetrations and min(penetrations) < -0.01
    # and from above, closing can only squeeze air above the box: it ends closed, with no hold
    T_above = Transform([0, 0, 0.1 + 0.075 + 0.02], DOWN)
    hand.teleport(hand.T_world_base_for_tcp(T_above, hand.rg2.max_width), hand.rg2.max_width)
    world.set_gravity(False)
    hand.close(40.0, max_steps=480)
    assert not any(hand.rg2.pad_contacts(box))


def test_gear_coupling_is_the_default_and_position_coupling_also_runs():
    assert GripperConfig().coupling == "gear"
    with World(PhysicsConfig()) as w:
        body = Body.load(w.client, paths.rg2_urdf(), fixed_base=True)
        rg2 = RG2(body, paths.rg2_urdf(), GripperConfig(coupling="position"))
        for _ in range(120):
            rg2.hold_position(0.5, 40.0)
            w.step()
        assert np.degrees(rg2.follower_errors().max()) < 1.0


@pytest.mark.parametrize("urdf", [paths.rg2_urdf(), paths.ur3_rg2_urdf()], ids=["floating", "on_ur3"])
def test_model_loads_cleanly_and_survives_random_targets(urdf, capfd):
    """Every referenced file exists, PyBullet prints no warning, 1 s of random targets is stable."""
    import xml.etree.ElementTree as ET

    for mesh in ET.parse(urdf).getroot().iter("mesh"):
        assert (urdf.parent / mesh.attrib["filename"]).exists(), mesh.attrib["filename"]
    with World(PhysicsConfig()) as w:
        capfd.readouterr()
        body = Body.load(w.client, urdf, fixed_base=True, flags=pb.URDF_USE_SELF_COLLISION)
        printed = capfd.readouterr()
        assert "warning" not in (printed.out + printed.err).lower(), printed.out + printed.err
        rg2 = RG2(body, urdf, GripperConfig())
        arm = [j for j in body.movable_joints if not j.name.startswith("gripper_")]
        rng = np.random.default_rng(0)
        for step in range(240):
            if step % 40 == 0:
                angle = rng.uniform(body.joints[rg2.driven].lower, body.joints[rg2.driven].upper)
                targets = [rng.uniform(max(j.lower, -np.pi), min(j.upper, np.pi)) for j in arm]
            rg2.hold_position(angle, 40.0)
            if arm:
                body.position_control({j.name: q for j, q in zip(arm, targets, strict=True)})
            w.step()
        base = body.base_pose().pos
        for name in body.links:
            p = body.link_pose(name).pos
            assert np.all(np.isfinite(p)) and np.linalg.norm(p - base) < 2.0, name
        assert np.degrees(rg2.follower_errors().max()) < 1.0


# --- the annotation gripper: passive links kinematic -----------------------------------------------

INNER_KNUCKLES = ("gripper_finger1_inner_knuckle_joint", "gripper_finger2_inner_knuckle_joint")


def world_for(passive: str) -> World:
    """The world each model is simulated in: the annotation worlds' iterations for the kinematic
    passive links, the whole-linkage iterations otherwise (the arm, the GUI)."""
    physics = PhysicsConfig()
    return World(physics if passive == "kinematic" else physics.whole_linkage())


def test_annotation_gripper_couples_only_the_pad_chains():
    with world_for("kinematic") as world:
        rg2 = FloatingRG2(world, GripperConfig(passive_links="kinematic")).rg2
        assert set(rg2.passive) == set(INNER_KNUCKLES)
        assert len(rg2.coupled) == 3 and len(rg2._constraints) == 3
    with world_for("simulated") as world:
        rg2 = FloatingRG2(world, GripperConfig(passive_links="simulated")).rg2
        assert rg2.passive == () and len(rg2._constraints) == 5


@pytest.mark.parametrize("passive", ["kinematic", "simulated"])
def test_pad_kinematics_follow_the_fk_table_at_every_width(passive):
    """Driven through the stroke in free air (dynamic), each model's pads are where the model's FK
    table puts them: separation, pad-centre midpoint in the base frame, pads parallel to the base."""
    with world_for(passive) as world:
        hand = FloatingRG2(world, GripperConfig(passive_links=passive))
        hand.teleport(Transform([0.0, 0.0, 0.5], DOWN), 0.05)
        world.set_gravity(False)
        rg2 = hand.rg2
        width_err, tcp_err, tilt = [], [], []
        for width in np.linspace(0.0, rg2.max_width, 23):
            for _ in range(120):
                rg2.hold_position(rg2.table.angle_of(width), 40.0)
                world.step()
            T_base_world = hand.base_pose().inverse()
            pads = [T_base_world * hand.body.link_pose(n) for n in PAD_LINKS]
            width_err.append(abs(rg2.measured_width() - width))
            midpoint = (pads[0].pos + pads[1].pos) / 2
            tcp_err.append(np.linalg.norm(midpoint - rg2.T_base_tcp(width).pos))
            tilt.extend(np.degrees(np.arccos(np.clip(p.rotation[0, 0], -1, 1))) for p in pads)
        assert max(width_err) < 5e-4, np.round(np.array(width_err) * 1000, 2)
        assert max(tcp_err) < 5e-4, np.round(np.array(tcp_err) * 1000, 2)
        assert max(tilt) < 1.0, np.round(tilt, 2)


@pytest.mark.parametrize("passive", ["kinematic", "simulated"])
def test_followers_of_each_model_stay_coupled_under_40N_squeeze_and_shake(passive):
    """A 40 N squeeze, then a lift and a shake: every coupled follower within 1 deg of its mimic
    target throughout, the pads squeezing 40 N, the box held (moved in the hand less than the
    protocol's 20 mm max_slip)."""
    with world_for(passive) as world:
        hand = FloatingRG2(world, GripperConfig(passive_links=passive))
        box = make_box(world, 0.04, 0.2)
        grasp_box(hand, box, 0.04)
        errors = []
        for _ in range(120):
            hand.rg2.command(-hand.config.close_speed, 40.0)
            world.step()
            errors.append(hand.rg2.follower_errors().max())
        forces = hand.rg2.pad_normal_forces(box)
        world.set_gravity(True)
        lifted = Transform(hand.target.pos + [0.0, 0.0, 0.1], hand.target.quat)

        def watch(_: int) -> bool:
            errors.append(hand.rg2.follower_errors().max())
            return False

        hand.move(lifted, 0.5, 40.0, on_step=watch)
        hand.shake(0.03, 0.35, 0.6, 40.0, on_step=watch, paired=True)
        assert np.all(np.abs(forces - 40.0) < 4.0), forces
        assert np.degrees(max(errors)) < 1.0, np.degrees(max(errors))
        in_hand = (hand.base_pose().inverse() * Transform(box_pos(world, box), [0, 0, 0, 1])).pos
        assert np.linalg.norm(in_hand - hand.rg2.T_base_tcp(0.04).pos) < 0.02


def test_kinematic_passive_links_are_checked_but_never_touch_while_stepping():
    """A probe inside an inner knuckle's collision box: getClosestPoints (the kinematic checks)
    reports the knuckle in both models; while the world steps it touches the probe only when the
    passive links are simulated."""
    touched = {}
    for passive in ("kinematic", "simulated"):
        with world_for(passive) as world:
            hand = FloatingRG2(world, GripperConfig(passive_links=passive))
            hand.teleport(Transform([0.0, 0.0, 0.5], DOWN), 0.08)
            knuckle = hand.body.links["gripper_finger1_inner_knuckle_link"]
            probe_pos = hand.body.link_pose("gripper_finger1_inner_knuckle_link").apply([0.0, 0.0, 0.015])
            probe = make_box(world, 0.003, 0.001, pos=probe_pos)
            closest = pb.getClosestPoints(hand.uid, probe, 0.0, physicsClientId=world.client)
            assert knuckle in {p[3] for p in closest}, passive
            world.set_gravity(False)
            world.step(3)
            touched[passive] = any(
                p[3] == knuckle for p in pb.getContactPoints(hand.uid, probe, physicsClientId=world.client)
            )
    assert touched == {"kinematic": False, "simulated": True}
