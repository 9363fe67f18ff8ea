"""The cell's bodies in one world: table, UR3 + gripper on its mount, Kinect v2 (numbers: CellConfig).

Everything that needs the seed's table, arm or camera builds it here, so those poses exist once:
``build_cell(world, config)`` loads what is asked for (a trial needs the table only; the scene and
replay the arm and the Kinect too) and returns a :class:`Cell` with the table's top surface, the
arm's mount pose and, when loaded, the coupled gripper on the arm's flange and the arm's kinematics.
"""

from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pybullet_data

from annotator import paths
from annotator.cell.kinect import KinectView, render_view
from annotator.cell.mount import mounted_urdf
from annotator.config import CellConfig, GripperConfig, KinectConfig
from annotator.geometry import Transform
from annotator.grippers import GripperDescription, load_gripper
from annotator.sim import ur3
from annotator.sim.body import Body
from annotator.sim.gripper import ParallelGripper
from annotator.sim.rigid import URDF_FLAGS, collision_shapes
from annotator.sim.world import World, private_client

log = logging.getLogger(__name__)

# The seed's load flags (EXCLUDE_PARENT, docs/robots.md "The seed scene") with self-collision switched on
# so the gripper's finger pairs collide (ParallelGripper filters the in-finger pairs), and inertia
# from the file.
ROBOT_FLAGS = (
    URDF_FLAGS["self_collision"]
    | URDF_FLAGS["self_collision_exclude_parent"]
    | URDF_FLAGS["inertia_from_file"]
)
KINECT_OPTICAL_LINK = "camera_optical_frame"


def _quat_z(deg: float) -> np.ndarray:
    a = math.radians(deg) / 2
    return np.array([0.0, 0.0, math.sin(a), math.cos(a)])


def _quat_y(deg: float) -> np.ndarray:
    a = math.radians(deg) / 2
    return np.array([0.0, math.sin(a), 0.0, math.cos(a)])


def robot_mount_pose(config: CellConfig) -> Transform:
    """``T_world_baselink``: where the UR3's base_link (and its massless mount) stands."""
    return Transform((config.robot_x, config.robot_y, config.robot_z), _quat_z(config.robot_yaw))


def kinect_pose(config: CellConfig) -> Transform:
    """``T_world_kinect``: the Kinect body (its URDF root), pitched then yawed (CellConfig)."""
    yaw = Transform((0, 0, 0), _quat_z(config.kinect_yaw))
    rotation = yaw * Transform((0, 0, 0), _quat_y(config.kinect_pitch))
    return Transform((config.kinect_x, config.kinect_y, config.kinect_z), rotation.quat)


def table_pose(config: CellConfig) -> Transform:
    return Transform((config.table_x, config.table_y, config.table_z), (0.0, 0.0, 0.0, 1.0))


def table_urdf(config: CellConfig) -> Path:
    return Path(pybullet_data.getDataPath()) / config.table_urdf


@functools.lru_cache(maxsize=2)
def T_kinect_optical(urdf: str | None = None) -> Transform:
    """The Kinect's optical frame in its body frame, read from the URDF (private DIRECT client)."""
    with private_client() as client:
        body = Body.load(client, urdf or paths.kinect_urdf(), fixed_base=True)
        return body.base_pose().inverse() * body.link_pose(KINECT_OPTICAL_LINK)


@dataclass(frozen=True)
class TableTop:
    """The table's top surface: ``T_world_top`` at its centre (+z up, out of the surface) and its
    half extents ``half_size`` (2,) m along the top frame's x and y."""

    T_world_top: Transform
    half_size: np.ndarray

    @property
    def z(self) -> float:
        """Height of the surface in the world, m."""
        return float(self.T_world_top.pos[2])

    def contains(self, points_world: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Which points (n, 3) lie over the top, at least ``margin`` m inside its edges: (n,) bool."""
        local = self.T_world_top.inverse().apply(np.atleast_2d(points_world))
        return np.all(np.abs(local[:, :2]) <= self.half_size - margin, axis=1)


def table_top_of(body: Body) -> TableTop:
    """The top face of the table's collision box (the seed's table: one box on its base link)."""
    boxes = [s for s in collision_shapes(body.client, body.uid) if s.kind == "box"]
    if not boxes:
        raise ValueError("the table has no collision box for its top")
    top = max(boxes, key=lambda s: s.local_position[2] + s.dimensions[2] / 2)  # the highest box
    size = np.asarray(top.dimensions)
    local_pos, local_quat = np.asarray(top.local_position), np.asarray(top.local_orientation)
    # collision shape frames are given in the link's inertial frame: base_pose is the URDF frame
    T_world_com = body.base_pose() * body.T_com_base.inverse()
    T_world_box = T_world_com * Transform(local_pos, local_quat)
    T_world_top = T_world_box * Transform((0.0, 0.0, size[2] / 2), (0.0, 0.0, 0.0, 1.0))
    return TableTop(T_world_top, size[:2] / 2)


@dataclass
class Cell:
    """The cell's bodies in ``world``; ``robot``, ``gripper`` and ``kinect`` are None when not loaded.

    ``robot`` is the UR3 with the gripper on its flange (one multibody, :mod:`annotator.cell.mount`),
    ``gripper`` that gripper's coupled linkage on it.
    """

    world: World
    config: CellConfig
    table: Body
    top: TableTop
    robot: Body | None = None
    gripper: ParallelGripper | None = None
    kinect: Body | None = None
    kinect_config: KinectConfig = field(default_factory=KinectConfig)

    @property
    def client(self) -> int:
        return self.world.client

    @property
    def T_world_baselink(self) -> Transform:
        """The arm's base_link in the world: the loaded model's pose, else the configured mount."""
        if self.robot is not None:
            return self.robot.link_pose(ur3.BASE_LINK)
        return robot_mount_pose(self.config)

    @property
    def frames(self) -> ur3.ArmFrames:
        """The arm's fixed frames and its gripper's tool point (from the model's own FK)."""
        if self.gripper is None:
            return ur3.arm_frames(None)
        g = self.gripper
        return ur3.arm_frames(str(g.urdf), g.config, g.description)

    def T_world_kinect_optical(self) -> Transform:
        """The Kinect's optical frame (+z viewing direction, +x right, +y down in the image)."""
        if self.kinect is not None:
            return self.kinect.link_pose(KINECT_OPTICAL_LINK)
        return kinect_pose(self.config) * T_kinect_optical()

    def render_kinect(
        self,
        T_world_camera: Transform | None = None,
        *,
        color: bool = True,
        color_scale: float = 1.0,
        rng: np.random.Generator | None = None,
    ) -> KinectView:
        """A Kinect v2 view (depth, segmentation, colour) from the cell's Kinect or ``T_world_camera``."""
        T = self.T_world_kinect_optical() if T_world_camera is None else T_world_camera
        return render_view(self.client, T, self.kinect_config, color=color, color_scale=color_scale, rng=rng)

    # --- the arm -------------------------------------------------------------------------------

    def _require_robot(self) -> Body:
        if self.robot is None:
            raise ValueError("this cell was built without the robot")
        return self.robot

    def arm_positions(self) -> np.ndarray:
        """Current arm joint positions in ur3.JOINT_NAMES order, (6,) rad."""
        return self._require_robot().joint_positions(ur3.JOINT_NAMES)

    def reset_arm(self, q: np.ndarray | tuple[float, ...]) -> None:
        """Teleport the six arm joints to ``q`` (6,) rad (set-up only)."""
        self._require_robot().reset_joints(dict(zip(ur3.JOINT_NAMES, map(float, q), strict=True)))

    def command_arm(self, q: np.ndarray | tuple[float, ...]) -> None:
        """Position-control the six arm joints to ``q`` (6,) rad with the URDF effort limits."""
        self._require_robot().position_control(dict(zip(ur3.JOINT_NAMES, q, strict=True)))

    def arm_limits(self) -> np.ndarray:
        """The arm joints' position limits (6, 2) rad, as the loaded model declares them."""
        return ur3.arm_limits(self._require_robot())

    def tcp_pose(self, q: np.ndarray, width: float) -> Transform:
        """``T_world_tcp`` for arm joints ``q`` (6,) and opening ``width`` (m), by DH kinematics."""
        return self.T_world_baselink * self.frames.tcp_pose(q, width)

    def ik(self, T_world_tcp: Transform, width: float, reference: np.ndarray | None = None) -> ur3.IKResult:
        """Closed-form IK for the gripper's TCP at ``T_world_tcp`` with opening ``width`` (m)."""
        T_baselink_tcp = self.T_world_baselink.inverse() * T_world_tcp
        return self.frames.ik_tcp(T_baselink_tcp, width, limits=self.arm_limits(), reference=reference)

    def nearest_ik(self, T_world_tcp: Transform, width: float, q_seed: np.ndarray) -> np.ndarray | None:
        """The IK solution (6,) nearest to ``q_seed`` (6,) (ur3.nearest_ik), or None when unreachable."""
        T_baselink_tcp = self.T_world_baselink.inverse() * T_world_tcp
        T_base_tool0 = self.frames.T_base_tool0(T_baselink_tcp, width)
        return ur3.nearest_ik(T_base_tool0, q_seed, self.arm_limits())


def build_cell(
    world: World,
    config: CellConfig | None = None,
    *,
    robot: bool = True,
    kinect: bool = True,
    gripper: GripperConfig | None = None,
    kinect_config: KinectConfig | None = None,
    description: GripperDescription | str | None = None,
) -> Cell:
    """Load the cell's table and, if asked, the UR3 with the gripper ``description`` (default the
    RG2) on its flange (its followers coupled, configured by ``gripper``) and the Kinect.

    The arm is loaded without ``useFixedBase``: its URDF mounts itself (a massless ``world`` root).
    """
    config = config or CellConfig()
    client = world.client
    table = Body.load(client, table_urdf(config), table_pose(config))
    cell = Cell(world, config, table, table_top_of(table), kinect_config=kinect_config or KinectConfig())
    if robot:
        described = load_gripper(description)
        urdf = mounted_urdf(described)
        cell.robot = Body.load(client, urdf, robot_mount_pose(config), flags=ROBOT_FLAGS)
        cell.gripper = ParallelGripper(cell.robot, described, gripper, urdf=urdf)
    if kinect:
        cell.kinect = Body.load(client, paths.kinect_urdf(), kinect_pose(config), fixed_base=True)
    log.debug("cell built: table top at z = %.4f m", cell.top.z)
    return cell
