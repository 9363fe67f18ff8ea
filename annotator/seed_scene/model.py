"""The seed scene's model: the cell (table, UR3 + gripper, Kinect) plus the seed's small cube.

The cell's bodies and poses come from :mod:`annotator.cell` (defined once); this adds the cube,
the seed's debug camera and slider start values, and arm/gripper commands by name.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pybullet_data

from annotator.cell import Cell, build_cell
from annotator.cell.placement import place, stable_poses
from annotator.config import CellConfig, GripperConfig, PhysicsConfig
from annotator.geometry import Transform
from annotator.grippers import GripperDescription
from annotator.objects import ObjectModel, create_body
from annotator.render import Camera, orbit_camera
from annotator.sim.body import Body
from annotator.sim.gripper import ParallelGripper
from annotator.sim.world import World

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SeedSceneConfig:
    """The seed scene beyond the cell, number for number (docs/robots.md, "The seed scene").

    Positions are metres in the world frame, camera angles degrees (as PyBullet's debug camera).
    """

    cell: CellConfig = field(default_factory=CellConfig)  # table, UR3 mount, Kinect
    cube_urdf: str = "cube_small.urdf"  # 50 mm, 0.1 kg; rests on the table top
    cube_pos: tuple[float, float, float] = (0.7, 0.0, 0.0)
    physics: PhysicsConfig = field(default_factory=lambda: PhysicsConfig(gravity=-9.8))  # seed: -9.8
    camera_distance: float = 2.0
    camera_yaw: float = 0.0
    camera_pitch: float = -40.0
    camera_target: tuple[float, float, float] = (0.5, -0.9, 0.5)
    # Seed slider start values for JOINT_NAMES (shoulder_pan ... wrist_3), rad; sliders span +-pi.
    initial_arm: tuple[float, ...] = (0.0, -math.pi / 2, 0.0, 0.0, math.pi / 2, 0.0)
    slider_range: float = math.pi
    gripper: GripperConfig = field(default_factory=GripperConfig)
    # The gripper on the arm's flange: a description, a shipped name or a folder (None: the RG2).
    description: GripperDescription | str | None = None
    # GUI loop rate (Hz): sliders are read and stepSimulation called once per frame, with
    # 240/gui_rate substeps of PhysicsConfig.time_step. Each call in GUI mode waits for the window
    # thread, so at 240 calls/s the loop fell behind real time under software OpenGL (Xvfb).
    gui_rate: float = 60.0
    # Headless frames: the seed camera's view matrix with a 60 deg vertical FOV. PyBullet's window
    # uses 90 deg (its projection matrix has f = 1); 60 shows the arm larger at 320 x 240, but the
    # Kinect, 1.57 m up, falls just above the frame (pass --fov 90 for the window's exact picture).
    record_fov: float = 60.0


@dataclass
class Scene:
    """The loaded seed scene: the cell (arm, gripper, table, Kinect) and the cube (or a chosen object,
    still called ``cube``)."""

    cell: Cell
    config: SeedSceneConfig
    cube: Body

    # --- the cell's parts, by name -------------------------------------------------------------

    @property
    def world(self) -> World:
        return self.cell.world

    @property
    def client(self) -> int:
        return self.cell.client

    @property
    def robot(self) -> Body:
        assert self.cell.robot is not None
        return self.cell.robot

    @property
    def gripper(self) -> ParallelGripper:
        assert self.cell.gripper is not None
        return self.cell.gripper

    @property
    def table(self) -> Body:
        return self.cell.table

    @property
    def kinect(self) -> Body:
        assert self.cell.kinect is not None
        return self.cell.kinect

    # --- commands ----------------------------------------------------------------------------

    def arm_positions(self) -> np.ndarray:
        """Current arm joint positions in JOINT_NAMES order, (6,) rad."""
        return self.cell.arm_positions()

    def command_arm(self, q: np.ndarray | tuple[float, ...]) -> None:
        """Position-control the six arm joints to ``q`` (6,) rad with the URDF effort limits as forces."""
        self.cell.command_arm(q)

    def command_gripper(self, angle: float) -> None:
        """Hold the drive position (rad or m) with the run's grip force."""
        self.gripper.hold_position(angle, self.gripper.grip_force)

    def reset_pose(self, q: np.ndarray | tuple[float, ...], gripper_angle: float) -> None:
        """Teleport arm and gripper (set-up only) and command the same targets."""
        self.cell.reset_arm(q)
        self.gripper.reset_angle(gripper_angle)
        self.command_arm(q)
        self.command_gripper(gripper_angle)

    def gripper_range(self) -> tuple[float, float]:
        """The driven joint's URDF limits (rad or m)."""
        j = self.robot.joints[self.gripper.driven]
        return j.lower, j.upper

    def seed_camera(self, width: int, height: int, fov: float | None = None) -> Camera:
        """The seed's debug camera off-screen; ``fov`` vertical, degrees (default ``record_fov``)."""
        c = self.config
        fov = c.record_fov if fov is None else fov
        return orbit_camera(
            c.camera_target, c.camera_distance, c.camera_yaw, c.camera_pitch, width, height, fov=fov
        )

    def solve_ik(self, T_world_tcp: Transform, width: float, start: np.ndarray | None = None) -> np.ndarray:
        """Arm joints (6,) placing the gripper's TCP at ``T_world_tcp`` with the pads ``width`` apart.

        The closed-form UR3 solution nearest to ``start`` (6,) (default the seed's initial pose);
        raises ``ValueError`` with the reason when the pose is out of reach.
        """
        q_seed = np.asarray(self.config.initial_arm if start is None else start, dtype=float)
        result = self.cell.ik(T_world_tcp, width, reference=q_seed)
        if not result:
            raise ValueError(f"TCP pose {T_world_tcp} at width {width * 1000:.0f} mm: {result.reason}")
        q = self.cell.nearest_ik(T_world_tcp, width, q_seed)
        assert q is not None
        return q


def open_world(config: SeedSceneConfig, *, gui: bool) -> World:
    """A world with the seed's physics settings (gravity -9.8)."""
    return World(config.physics.whole_linkage(), gui=gui)


def build_scene(world: World, config: SeedSceneConfig | None = None, obj: ObjectModel | None = None) -> Scene:
    """Load the seed scene into ``world`` and put the arm in the seed's initial pose.

    ``obj``: an object to use instead of the seed's cube, resting on the table in its most
    probable stable pose with its centre of mass over the cell's placement point (0.35 m in front
    of the arm, where it can be grasped from above; the seed's cube at 0.7 m only from the side).
    """
    config = config or SeedSceneConfig()
    cell = build_cell(world, config.cell, gripper=config.gripper, description=config.description)
    if obj is None:
        data = Path(pybullet_data.getDataPath())
        cube = Body.load(world.client, data / config.cube_urdf, Transform(config.cube_pos, [0, 0, 0, 1]))
    else:
        pose = stable_poses(obj.mesh, config.cell.placement_merge_angle)[0]
        xy = np.array([config.cell.placement_x, config.cell.placement_y])
        T_world_obj = place(pose, cell.top, xy, 0.0, obj.center_mass)
        cube = Body(world.client, create_body(world.client, obj, T_world_obj))
    scene = Scene(cell, config, cube)
    scene.reset_pose(config.initial_arm, 0.0)
    return scene
