"""The UR3's closed-form inverse kinematics against its DH forward kinematics and the URDF model."""

from __future__ import annotations

import math

import numpy as np
import pybullet as pb
import pytest

from annotator import paths
from annotator.geometry import Transform
from annotator.grippers import default_gripper, read_mimic_table
from annotator.sim import ur3
from annotator.sim.body import Body

PAD_LINKS = default_gripper().pad_links

N_RANDOM = 4000


def random_configurations(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 6) configurations spread over the whole joint ranges (+-2 pi, elbow +-pi)."""
    return rng.uniform(ur3.JOINT_LIMITS[:, 0], ur3.JOINT_LIMITS[:, 1], size=(n, 6))


def angle_gap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Largest joint difference up to multiples of 2 pi, broadcasting over leading axes."""
    d = np.mod(np.asarray(a) - np.asarray(b) + np.pi, 2 * np.pi) - np.pi
    return np.abs(d).max(axis=-1)


def test_fk_round_trip_on_thousands_of_configurations():
    """Every branch found reproduces the pose to 1e-9; the generating configuration is one of them."""
    q = random_configurations(np.random.default_rng(0), N_RANDOM)
    T = ur3.dh_forward_kinematics_batch(q)
    branches = ur3.ik_branches(T)
    found = branches.stage == 0
    assert found.any(axis=1).all()
    T_found = ur3.dh_forward_kinematics_batch(branches.q[found])
    assert ur3.pose_error(T_found, np.repeat(T[:, None], 8, axis=1)[found]).max() < 1e-9
    gaps = np.where(found, angle_gap(branches.q, q[:, None, :]), np.inf)
    assert gaps.min(axis=1).max() < 1e-8
    # the batch and the scalar forward kinematics agree
    np.testing.assert_allclose(T[:50], [ur3.dh_forward_kinematics(x) for x in q[:50]], atol=1e-15)


def test_solve_ik_returns_distinct_solutions_within_limits():
    rng = np.random.default_rng(1)
    counts = []
    for q in random_configurations(rng, 300):
        T = ur3.dh_forward_kinematics(q)
        result = ur3.solve_ik(T)
        sols = result.solutions
        assert result.reason == "" and 1 <= len(sols) <= 8
        assert np.all(sols >= ur3.JOINT_LIMITS[:, 0]) and np.all(sols <= ur3.JOINT_LIMITS[:, 1])
        # default representation: each joint in (-pi, pi] (elbow in [-pi, pi])
        assert np.all(np.abs(sols) <= np.pi + 1e-12)
        assert ur3.pose_error(ur3.dh_forward_kinematics_batch(sols), T).max() < 1e-9
        assert angle_gap(sols, q).min() < 1e-8
        pairwise = angle_gap(sols[:, None, :], sols[None, :, :]) + np.eye(len(sols)) * 10
        assert pairwise.min() > ur3.SAME_SOLUTION
        counts.append(len(sols))
    assert max(counts) == 8  # a generic pose inside the workspace has all eight


def test_all_eight_branches_of_a_generic_pose():
    q = np.array([0.3, -1.2, 1.4, -0.9, 1.1, 0.5])
    sols = ur3.ik_solutions(ur3.dh_forward_kinematics(q))
    assert len(sols) == 8
    # two shoulder, two wrist, two elbow values: q1 takes 2 values, q5 2 per q1, q3 a +- pair each
    assert len(np.unique(np.round(sols[:, 0], 9))) == 2
    assert len(np.unique(np.round(sols[:, 4], 9))) == 4
    np.testing.assert_allclose(sols[0::2, 2], -sols[1::2, 2], atol=1e-12)


def test_unreachable_poses_return_no_solution_with_a_reason():
    far = np.eye(4)
    far[:3, 3] = (0.9, 0.0, 0.2)  # beyond d1 + |a2| + |a3| + d5 + d6 reach
    result = ur3.solve_ik(far)
    assert not result and result.solutions.shape == (0, 6) and result.reason == ur3.NO_ELBOW
    # flange straight down with the wrist centre on the base axis: r = 0 < d4
    axis = np.diag([1.0, -1.0, -1.0, 1.0])
    axis[:3, 3] = (0.0, 0.0, 0.3 - ur3.DH_D6)
    result = ur3.solve_ik(axis)
    assert not result and result.reason == ur3.NO_SHOULDER
    # just inside / outside the d4 cylinder
    for r, reachable in ((ur3.DH_D4 + 1e-4, True), (ur3.DH_D4 - 1e-4, False)):
        T = axis.copy()
        T[0, 3] = r
        assert bool(ur3.solve_ik(T)) is reachable, r


def test_custom_limits_are_respected_and_reported():
    q = np.array([0.3, -1.2, 1.4, -0.9, 1.1, 0.5])
    T = ur3.dh_forward_kinematics(q)
    limits = ur3.JOINT_LIMITS.copy()
    limits[2] = (0.0, math.pi)  # elbow up only
    sols = ur3.ik_solutions(T, limits)
    assert len(sols) == 4 and np.all(sols[:, 2] >= 0.0)
    limits[0] = (2.0, 2.5)  # no shoulder-pan solution lies here, nor 2 pi away
    result = ur3.solve_ik(T, limits=limits)
    assert not result and result.reason == ur3.NO_LIMITS


def test_two_pi_representatives_follow_the_seed():
    q = np.array([-3.0, -1.2, 1.4, 2.9, 1.1, -3.0])
    T = ur3.dh_forward_kinematics(q)
    np.testing.assert_allclose(ur3.nearest_ik(T, q), q, atol=1e-8)
    shifted = q + np.array([2 * math.pi, 0, 0, -2 * math.pi, 0, 2 * math.pi])  # all within +-2 pi
    np.testing.assert_allclose(ur3.nearest_ik(T, shifted + 0.05), shifted, atol=1e-8)
    # a joint limit forbids the representation nearest the reference: the other one is used
    limits = ur3.JOINT_LIMITS.copy()
    limits[0] = (-2 * math.pi, 3.0)
    sols = ur3.solve_ik(T, limits=limits, reference=shifted + 0.05).solutions
    assert np.all(sols[:, 0] <= 3.0)
    same_branch = sols[np.argmin(angle_gap(sols, q))]
    np.testing.assert_allclose(same_branch, shifted - [2 * math.pi, 0, 0, 0, 0, 0], atol=1e-8)
    # the seed picks the branch too
    for sol in ur3.ik_solutions(T):
        np.testing.assert_allclose(ur3.nearest_ik(T, sol + 1e-3), sol, atol=1e-8)


def test_wrist_singularity_keeps_the_reference_q6():
    q = np.array([0.2, -1.0, 1.2, -0.5, 0.0, 0.7])  # q5 = 0: joints 4 and 6 coaxial
    T = ur3.dh_forward_kinematics(q)
    result = ur3.solve_ik(T, reference=np.array([0, 0, 0, 0, 0, 0.7]))
    assert result and result.wrist_singular.any()
    assert ur3.pose_error(ur3.dh_forward_kinematics_batch(result.solutions), T).max() < 1e-9
    singular = result.solutions[result.wrist_singular]
    np.testing.assert_allclose(singular[:, 5], 0.7, atol=1e-9)
    assert angle_gap(result.solutions, q).min() < 1e-8


def test_nearest_ik_along_a_batched_path_equals_solving_each_waypoint_alone():
    """check_reach solves an approach's waypoints in one batch: the branch it then picks at each
    waypoint, from the previous one, must be nearest_ik's own answer, bit for bit, on random
    approaches and on one through the wrist singularity (where q6 comes from the seed)."""
    rng = np.random.default_rng(7)
    paths_checked = 0
    singular_q = np.array([0.2, -1.0, 1.2, -0.5, 0.0, 0.7])
    configurations = [*random_configurations(rng, 60), singular_q]
    for q in configurations:
        T_grasp = ur3.dh_forward_kinematics(q)
        back = T_grasp[:3, 2]  # approach along the flange's z
        flange = np.stack([T_grasp.copy() for _ in range(11)])
        flange[:, :3, 3] -= np.outer(np.linspace(0.0, 0.1, 11), back)
        along = ur3.ik_branches(flange)
        if q is singular_q:
            assert along.wrist_singular[0].any()
        seed = q
        for i in range(1, 11):
            want = ur3.nearest_ik(flange[i], seed)
            got = ur3.nearest_ik_along(along, i, flange[i], seed)
            if want is None:
                assert got is None
                break
            assert got is not None and np.array_equal(got, want)
            seed = want
        paths_checked += 1
    assert paths_checked == len(configurations)


def test_stretched_elbow_branches_coincide_once():
    q = np.array([0.4, -0.8, 0.0, -0.6, 1.0, 0.2])  # q3 = 0: the two elbow branches meet
    sols = ur3.ik_solutions(ur3.dh_forward_kinematics(q))
    assert angle_gap(sols, q).min() < 1e-5  # acos at 1: the elbow is known to ~sqrt(eps)
    pairwise = angle_gap(sols[:, None, :], sols[None, :, :]) + np.eye(len(sols)) * 10
    assert pairwise.min() > ur3.SAME_SOLUTION and len(sols) < 8


@pytest.fixture(scope="module")
def model():
    client = pb.connect(pb.DIRECT)
    body = Body.load(client, paths.ur3_rg2_urdf())
    yield body
    pb.disconnect(client)


def _set(body: Body, q: np.ndarray, width: float, frames: ur3.ArmFrames) -> None:
    body.reset_joints(dict(zip(ur3.JOINT_NAMES, map(float, q), strict=True)))
    angle = frames.gripper.angle_of(width)
    mimic = read_mimic_table(paths.ur3_rg2_urdf())
    driven = next(iter(mimic.values())).driven
    body.reset_joints({driven: angle, **{m.follower: m.multiplier * angle for m in mimic.values()}})


def _model_tcp(body: Body) -> Transform:
    """The pad-centre midpoint with the ``tcp`` link's axes, from PyBullet's FK of the URDF."""
    mid = (body.link_pose(PAD_LINKS[0]).pos + body.link_pose(PAD_LINKS[1]).pos) / 2
    T_base_world = body.link_pose(ur3.BASE_LINK).inverse()
    return T_base_world * Transform(mid, body.link_pose("tcp").quat)


def test_arm_frames_come_from_the_model(model):
    frames = ur3.arm_frames()
    np.testing.assert_allclose(frames.T_baselink_base.as_matrix(), ur3.T_BASELINK_BASE, atol=1e-9)
    np.testing.assert_allclose(frames.T_tool0_gripper.as_matrix(), np.eye(4), atol=1e-9)
    assert frames.gripper.max_width == pytest.approx(0.110, abs=1e-3)
    rng = np.random.default_rng(4)
    for q, width in zip(random_configurations(rng, 20), rng.uniform(0, 0.11, 20), strict=True):
        _set(model, q, width, frames)
        T_model = _model_tcp(model)
        T_dh = frames.tcp_pose(q, width)
        np.testing.assert_allclose(T_dh.pos, T_model.pos, atol=2e-6)  # PyBullet FK is float32-ish
        np.testing.assert_allclose(T_dh.rotation, T_model.rotation, atol=2e-6)


def test_ik_for_a_tcp_pose_places_the_models_tcp_there(model):
    """IK of a TCP pose (at an opening) puts the URDF's pad midpoint on it, for every solution."""
    frames = ur3.arm_frames()
    rng = np.random.default_rng(5)
    for q, width in zip(random_configurations(rng, 10), rng.uniform(0, 0.11, 10), strict=True):
        T_baselink_tcp = frames.tcp_pose(q, width)
        result = frames.ik_tcp(T_baselink_tcp, width)
        assert result and angle_gap(result.solutions, q).min() < 1e-8
        for sol in result.solutions:
            _set(model, sol, width, frames)
            T_model = _model_tcp(model)
            np.testing.assert_allclose(T_model.pos, T_baselink_tcp.pos, atol=2e-6)
            np.testing.assert_allclose(T_model.rotation, T_baselink_tcp.rotation, atol=2e-6)
