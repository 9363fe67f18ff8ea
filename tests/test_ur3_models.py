"""The UR3, Kinect v2 and UR3 + RG2 models load in real PyBullet and match the published numbers."""

from __future__ import annotations

import importlib.util
import math
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pybullet as p
import pytest

from annotator import paths
from annotator.sim import ur3
from annotator.sim.body import Body

FLAGS = p.URDF_USE_INERTIA_FROM_FILE
# docs/robots.md: masses (kg) of the UR3 links
UR3_MASSES = {
    "base_link": 2.0,
    "shoulder_link": 2.0,
    "upper_arm_link": 3.42,
    "forearm_link": 1.26,
    "wrist_1_link": 0.8,
    "wrist_2_link": 0.8,
    "wrist_3_link": 0.35,
}
FRAME_LINKS = ("base", "tool0")  # massless frames (explicit tiny inertial)
EFFORTS = [56.0, 56.0, 28.0, 12.0, 12.0, 12.0]  # N m, docs/robots.md joint limits
MOUNT_ROOT = "world"  # PyBullet makes an inertial-less root static only under this name
HOME = np.array([0.0, -math.pi / 2, 0.0, 0.0, math.pi / 2, 0.0])  # the seed scene's start


@pytest.fixture
def client() -> Iterator[int]:
    cid = p.connect(p.DIRECT)
    p.setGravity(0, 0, -9.8, physicsClientId=cid)
    yield cid
    p.disconnect(cid)


def _combined_urdf() -> Path:
    path = paths.ur3_rg2_urdf()
    if not path.exists():
        pytest.skip(
            f"{path} not generated yet (needs assets/grippers/rg2/make_rg2.py; run assets/ur3/make_ur3.py)"
        )
    return path


def _arm_models() -> list[Path]:
    models = [paths.ur3_urdf()]
    if paths.ur3_rg2_urdf().exists():
        models.append(paths.ur3_rg2_urdf())
    return models


def _load(client: int, path: Path, fixed: bool = True, flags: int = FLAGS) -> Body:
    return Body(client, p.loadURDF(str(path), useFixedBase=fixed, flags=flags, physicsClientId=client))


def _set_arm(body: Body, q: np.ndarray) -> None:
    body.reset_joints(dict(zip(ur3.JOINT_NAMES, map(float, q), strict=True)))


def _tool0_position(body: Body, q: np.ndarray) -> np.ndarray:
    _set_arm(body, q)
    return body.link_pose(ur3.TOOL0_LINK).pos


def _mass(body: Body, link: str) -> float:
    return p.getDynamicsInfo(body.uid, body.links[link], physicsClientId=body.client)[0]


@pytest.mark.parametrize("name", ["ur3.urdf", "kinect_v2.urdf", "ur3_visual_grabbing_with_rg2.urdf"])
def test_every_referenced_file_exists_and_every_link_has_inertial(name: str) -> None:
    path = paths.assets_dir() / "ur3" / name
    if name.startswith("ur3_visual"):
        path = _combined_urdf()
    root = ET.parse(path).getroot()
    for mesh in root.iter("mesh"):
        assert (path.parent / mesh.attrib["filename"]).is_file(), mesh.attrib["filename"]
    children = {j.find("child").attrib["link"] for j in root.iter("joint")}
    roots = [link.attrib["name"] for link in root.iter("link") if link.attrib["name"] not in children]
    assert len(roots) == 1, roots
    for link in root.iter("link"):
        if link.attrib["name"] == MOUNT_ROOT and roots == [MOUNT_ROOT]:
            # the mount: massless on purpose, so PyBullet treats the arm's base as static
            assert link.find("inertial") is None
            continue
        assert link.find("inertial") is not None, f"{name}: link {link.attrib['name']} has no <inertial>"
    if name != "kinect_v2.urdf":
        assert roots == [MOUNT_ROOT], f"{name}: the arm must be mounted on a massless '{MOUNT_ROOT}' root"


@pytest.mark.parametrize("model", _arm_models(), ids=lambda m: m.name)
def test_arm_mounts_itself_without_use_fixed_base(client: int, model: Path) -> None:
    """Loaded as the seed loads it (no useFixedBase), under gravity and a shove, the base stays put."""
    body = Body(client, p.loadURDF(str(model), [0.2, -0.1, 0.3], [0, 0, 0.6, 0.8], physicsClientId=client))
    assert _mass(body, ur3.MOUNT_LINK) == 0.0  # static root
    before = body.link_pose(ur3.BASE_LINK).as_matrix()
    base = body.links[ur3.BASE_LINK]
    p.applyExternalForce(body.uid, base, [200, 0, 0], [0, 0, 0], p.WORLD_FRAME, physicsClientId=client)
    for _ in range(240):
        p.stepSimulation(physicsClientId=client)
    np.testing.assert_allclose(body.link_pose(ur3.BASE_LINK).as_matrix(), before, atol=1e-9)


def test_dh_forward_kinematics_matches_published_figures() -> None:
    t0 = ur3.dh_forward_kinematics(np.zeros(6))
    np.testing.assert_allclose(t0[:3, 3], [-0.4569, -0.19425, 0.06655], atol=1e-9)
    t1 = ur3.dh_forward_kinematics(np.array([0, -math.pi / 2, 0, -math.pi / 2, 0, 0]))
    assert t1[2, 3] == pytest.approx(0.69415, abs=1e-9)


@pytest.mark.parametrize("model", _arm_models(), ids=lambda m: m.name)
def test_urdf_tool0_matches_dh_figures(client: int, model: Path) -> None:
    body = _load(client, model)
    # base_link is the world frame; the DH base frame `base` is Rz(pi) from it (ROS-Industrial).
    t_world_base = body.link_pose(ur3.DH_BASE_LINK).as_matrix()
    np.testing.assert_allclose(t_world_base, ur3.T_BASELINK_BASE, atol=1e-6)
    # q = 0: DH (-0.4569, -0.19425, 0.06655) becomes (+0.4569, +0.19425, 0.06655) in base_link.
    pos = _tool0_position(body, np.zeros(6))
    np.testing.assert_allclose(pos, [0.4569, 0.19425, 0.06655], atol=1e-3)
    p_dh = (np.linalg.inv(t_world_base) @ np.append(pos, 1.0))[:3]
    np.testing.assert_allclose(p_dh, [-0.4569, -0.19425, 0.06655], atol=1e-3)
    pos = _tool0_position(body, np.array([0, -math.pi / 2, 0, -math.pi / 2, 0, 0]))
    assert pos[2] == pytest.approx(0.69415, abs=1e-3)


@pytest.mark.parametrize("model", _arm_models(), ids=lambda m: m.name)
def test_urdf_fk_equals_dh_fk_for_random_configurations(client: int, model: Path) -> None:
    body = _load(client, model)
    rng = np.random.default_rng(1234)
    worst_pos, worst_rot = 0.0, 0.0
    for q in rng.uniform(-math.pi, math.pi, size=(20, 6)):
        _set_arm(body, q)
        t_urdf = body.link_pose(ur3.TOOL0_LINK).as_matrix()
        t_dh = ur3.T_BASELINK_BASE @ ur3.dh_forward_kinematics(q)
        worst_pos = max(worst_pos, float(np.linalg.norm(t_urdf[:3, 3] - t_dh[:3, 3])))
        worst_rot = max(worst_rot, float(np.abs(t_urdf[:3, :3] - t_dh[:3, :3]).max()))
    assert worst_pos < 1e-3, f"max tool0 position error {worst_pos * 1e3:.4f} mm"
    assert worst_rot < 1e-5, f"max tool0 rotation-matrix error {worst_rot:.2e}"


@pytest.mark.parametrize("model", _arm_models(), ids=lambda m: m.name)
def test_arm_masses_match_the_facts(client: int, model: Path) -> None:
    body = _load(client, model, fixed=False)  # a fixed base reports mass 0
    for name, mass in UR3_MASSES.items():
        assert _mass(body, name) == pytest.approx(mass)
    for name in FRAME_LINKS:
        assert _mass(body, name) < 1e-3


def test_bare_arm_total_mass_and_limits(client: int) -> None:
    body = _load(client, paths.ur3_urdf(), fixed=False)
    total = sum(_mass(body, name) for name in body.links)
    assert total == pytest.approx(sum(UR3_MASSES.values()), abs=1e-3)  # 10.63 kg
    expected = {  # (upper limit, velocity, effort), docs/robots.md
        "shoulder_pan_joint": (2 * math.pi, math.pi, 56),
        "shoulder_lift_joint": (2 * math.pi, math.pi, 56),
        "elbow_joint": (math.pi, math.pi, 28),
        "wrist_1_joint": (2 * math.pi, 2 * math.pi, 12),
        "wrist_2_joint": (2 * math.pi, 2 * math.pi, 12),
        "wrist_3_joint": (2 * math.pi, 2 * math.pi, 12),
    }
    for name, (upper, velocity, effort) in expected.items():
        joint = body.joints[name]
        assert joint.kind == "revolute"
        assert (joint.lower, joint.upper) == pytest.approx((-upper, upper), abs=1e-6)
        assert joint.max_force == pytest.approx(effort)
        assert joint.max_velocity == pytest.approx(velocity, abs=1e-6)
    np.testing.assert_allclose(ur3.arm_limits(body), ur3.JOINT_LIMITS, atol=1e-6)


def test_kinect_mass_and_camera_frames(client: int) -> None:
    body = _load(client, paths.kinect_urdf(), fixed=False)
    assert _mass(body, "kinect_link") == pytest.approx(0.9)
    assert {"kinect_link", "camera_link", "camera_optical_frame"} <= set(body.links)
    aabb_min, aabb_max = p.getAABB(body.uid, -1, physicsClientId=client)
    np.testing.assert_allclose(np.subtract(aabb_max, aabb_min), [0.066, 0.25, 0.067], atol=0.005)
    cam = body.link_pose("camera_link").as_matrix()
    opt = body.link_pose("camera_optical_frame").as_matrix()
    np.testing.assert_allclose(cam[:3, 3], [0.033, 0, 0], atol=1e-6)  # front face of the body
    np.testing.assert_allclose(opt[:3, 2], cam[:3, 0], atol=1e-6)  # optical z = viewing direction
    np.testing.assert_allclose(opt[:3, 0], -cam[:3, 1], atol=1e-6)  # optical x = image right
    np.testing.assert_allclose(opt[:3, 1], -cam[:3, 2], atol=1e-6)  # optical y = image down


@pytest.mark.parametrize("model", _arm_models(), ids=lambda m: m.name)
@pytest.mark.parametrize("q", [np.zeros(6), HOME], ids=["zero", "home"])
def test_no_self_collision_at_rest_poses(client: int, model: Path, q: np.ndarray) -> None:
    flags = FLAGS | p.URDF_USE_SELF_COLLISION | p.URDF_USE_SELF_COLLISION_EXCLUDE_PARENT  # the seed's
    body = _load(client, model, flags=flags)
    _set_arm(body, q)
    p.performCollisionDetection(physicsClientId=client)
    names = {v: k for k, v in body.links.items()}
    arm_links = {*UR3_MASSES, *FRAME_LINKS}
    # pairs touching the arm (the RG2's own internal pairs are the gripper's business)
    contacts = [
        c
        for c in p.getContactPoints(body.uid, body.uid, physicsClientId=client)
        if c[8] < -1e-4 and (names[c[3]] in arm_links or names[c[4]] in arm_links)
    ]
    assert not contacts, [(names[c[3]], names[c[4]], c[8]) for c in contacts]


@pytest.mark.parametrize("model", _arm_models(), ids=lambda m: m.name)
def test_one_second_under_random_position_targets_is_stable(client: int, model: Path) -> None:
    body = _load(client, model)
    rng = np.random.default_rng(7)
    _set_arm(body, HOME)
    targets = HOME + rng.uniform(-0.5, 0.5, size=6)
    efforts = dict(zip(ur3.JOINT_NAMES, EFFORTS, strict=True))
    body.position_control(dict(zip(ur3.JOINT_NAMES, targets, strict=True)), efforts)
    for step in range(240):
        if step == 120:  # a second random target half way
            targets = HOME + rng.uniform(-0.5, 0.5, size=6)
            body.position_control(dict(zip(ur3.JOINT_NAMES, targets, strict=True)), efforts)
        p.stepSimulation(physicsClientId=client)
    positions = np.array([body.link_pose(name).pos for name in body.links])
    q = body.joint_positions(ur3.JOINT_NAMES)
    assert np.all(np.isfinite(positions)) and np.all(np.isfinite(q))
    assert np.linalg.norm(positions, axis=1).max() < 2.0  # base at the origin
    # nothing beyond the stretched-out arm: d1 + |a2| + |a3| + d5 + d6 + the RG2 (< 0.25 m) < 1.25 m
    assert np.linalg.norm(positions, axis=1).max() < 1.25
    np.testing.assert_allclose(q, targets, atol=0.1)


def test_kinect_falls_and_rests_on_a_plane(client: int) -> None:
    plane = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=client)
    p.createMultiBody(0, plane, physicsClientId=client)
    body = p.loadURDF(str(paths.kinect_urdf()), basePosition=(0, 0, 0.2), flags=FLAGS, physicsClientId=client)
    for _ in range(240):
        p.stepSimulation(physicsClientId=client)
    pos, _ = p.getBasePositionAndOrientation(body, physicsClientId=client)
    assert np.all(np.isfinite(pos))
    assert pos[2] == pytest.approx(0.067 / 2, abs=0.003)


def test_combined_model_has_gripper_on_tool0(client: int) -> None:
    body = _load(client, _combined_urdf())
    for name in ("rg2_base_link", "tcp"):
        assert name in body.links
    assert "gripper_finger1_joint" in body.joints
    parent = p.getJointInfo(body.uid, body.links["rg2_base_link"], physicsClientId=client)[16]
    assert parent == body.links[ur3.TOOL0_LINK]
    rng = np.random.default_rng(3)
    for q in rng.uniform(-math.pi, math.pi, size=(5, 6)):
        _set_arm(body, q)
        t_tool0 = body.link_pose(ur3.TOOL0_LINK).as_matrix()
        t_grip = body.link_pose("rg2_base_link").as_matrix()
        np.testing.assert_allclose(t_grip[:3, 2], t_tool0[:3, 2], atol=1e-6)  # +z along the flange
        np.testing.assert_allclose(t_grip[:3, 3], t_tool0[:3, 3], atol=1e-6)


def _generator():
    spec = importlib.util.spec_from_file_location("make_ur3", paths.assets_dir() / "ur3" / "make_ur3.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_shipped_urdfs_are_what_the_generator_writes() -> None:
    gen = _generator()
    folder = paths.assets_dir() / "ur3"
    written = gen.models()
    assert "ur3_visual_grabbing_with_rg2.urdf" in written
    for name, text in written.items():
        assert (folder / name).read_text() == text, f"{name} stale: run `python assets/ur3/make_ur3.py`"
