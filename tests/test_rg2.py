"""The RG2's own facts (the seed's mimic table, its 110 mm stroke, gear coupling) and the floating
hand's shake. Every shipped gripper's physics (the RG2's included) is tested in test_grippers.py."""

from __future__ import annotations

import numpy as np
import pytest

from annotator import paths
from annotator.config import GripperConfig, PhysicsConfig
from annotator.geometry import Transform
from annotator.grippers import default_gripper, read_mimic_table
from annotator.sim.body import Body
from annotator.sim.gripper import ParallelGripper
from annotator.sim.hand import ShakeMotion
from annotator.sim.world import World

DOWN = np.array([1.0, 0.0, 0.0, 0.0])  # TCP +z pointing down (-z world): a top grasp
SEED_MIMIC = {
    "gripper_finger2_joint": -1.0,
    "gripper_finger1_inner_knuckle_joint": 1.0,
    "gripper_finger2_inner_knuckle_joint": -1.0,
    "gripper_finger1_finger_tip_joint": -1.0,
    "gripper_finger2_finger_tip_joint": 1.0,
}


@pytest.mark.parametrize("urdf", [default_gripper().urdf, paths.ur3_rg2_urdf()], ids=["floating", "on_ur3"])
def test_mimic_table_read_from_urdf_has_seed_multipliers(urdf):
    table = read_mimic_table(urdf)
    assert {k: m.multiplier for k, m in table.items()} == SEED_MIMIC
    assert {m.driven for m in table.values()} == {"gripper_finger1_joint"}


def test_fully_open_reaches_the_110mm_stroke(world):
    body = Body.load(world.client, default_gripper().urdf, fixed_base=True)
    rg2 = ParallelGripper(body, default_gripper(), GripperConfig())
    rg2.reset_angle(body.joints[rg2.driven].upper)
    assert rg2.measured_width() == pytest.approx(0.110, abs=0.002)
    rg2.reset_angle(body.joints[rg2.driven].lower)
    assert rg2.measured_width() == pytest.approx(0.0, abs=0.001)


@pytest.mark.parametrize("paired", [False, True], ids=["sequential", "paired"])
def test_shake_moves_the_gripper_by_its_amplitude_and_angle(world, hand, paired):
    """The carried gripper really follows the shake: reaches the amplitude and angle, comes back.

    Sequential: translations first (no rotation), then rotations about the TCP. Paired: each axis
    translates and rotates at once, in half the motions.
    """
    world.set_gravity(False)
    centre = Transform([0.0, 0.0, 0.5], DOWN)
    hand.teleport(centre, 0.04)
    tcp0 = centre.apply(hand.gripper.T_base_tcp(0.0).pos)
    shifts, angles = [], []

    def record(i: int) -> bool:
        pose = hand.base_pose()
        shifts.append(np.linalg.norm(pose.apply(hand.gripper.T_base_tcp(0.0).pos) - tcp0))
        dq = abs(float(np.dot(pose.quat, centre.quat)))
        angles.append(2 * np.arccos(min(1.0, dq)))
        return False

    amplitude, angle = 0.03, np.radians(20)
    steps = hand.shake(ShakeMotion(amplitude, angle, 1.2, paired=paired), force=40.0, on_step=record)
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


def test_gear_coupling_is_the_default_and_position_coupling_also_runs():
    assert default_gripper().coupling == "gear" and GripperConfig().coupling is None
    with World(PhysicsConfig()) as w:
        body = Body.load(w.client, default_gripper().urdf, fixed_base=True)
        rg2 = ParallelGripper(body, default_gripper(), GripperConfig(coupling="position"))
        assert rg2.coupling == "position" and not rg2._constraints
        for _ in range(120):
            rg2.hold_position(0.5, 40.0)
            w.step()
        assert np.degrees(rg2.follower_errors().max()) < 1.0
