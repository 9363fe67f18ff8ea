"""The seed scene (UR3 + RG2, table, Kinect, cube) as a feature: a slider GUI and headless recording.

``annotator scene`` opens the PyBullet GUI with the seed's sliders; ``annotator scene --headless
--gif out.gif`` plays a scripted sequence (sweep, reach towards the cube, open, close, lift) in
DIRECT mode and records it with the software renderer.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import click
import numpy as np
import pybullet_data

from annotator import paths
from annotator.config import GripperConfig, PhysicsConfig
from annotator.geometry import Transform
from annotator.render import Camera, optical_camera, orbit_camera, render_rgb, write_gif, write_png
from annotator.sim import pb
from annotator.sim.body import Body
from annotator.sim.rg2 import RG2, TCP_LINK
from annotator.sim.ur3 import JOINT_NAMES
from annotator.sim.world import World

log = logging.getLogger(__name__)

ROBOT_FLAGS = (
    pb.URDF_USE_SELF_COLLISION | pb.URDF_USE_SELF_COLLISION_EXCLUDE_PARENT | pb.URDF_USE_INERTIA_FROM_FILE
)
GRIPPER_SLIDER = "gripper_opening_angle"  # the seed's slider name
KINECT_OPTICAL_LINK = "camera_optical_frame"
# IK refinement stops when no arm joint moves more than this between rounds (rad); 1e-6 rad at the
# UR3's 0.5 m reach is 0.5 um, far below what a picture or the grasp can tell apart.
IK_TOLERANCE = 1e-6


@dataclass(frozen=True)
class SceneConfig:
    """The seed scene, number for number (seed script; ../shared/ROBOT_FACTS.md "Seed scene").

    Positions are metres in the world frame, camera angles degrees (as PyBullet's debug camera).
    """

    table_urdf: str = "table/table.urdf"  # from the installed pybullet_data, as the seed
    table_pos: tuple[float, float, float] = (0.5, 0.0, -0.65)  # top surface at z = -0.025
    kinect_pos: tuple[float, float, float] = (0.4, 0.0, 1.57)
    # The seed's Kinect orientation is not recorded (ROBOT_FACTS gives the position only); chosen
    # here: straight down. Ry(+pi/2) turns the body's +x (camera_link's optical axis) to -z, so the
    # 60 x 70.6 deg depth frustum covers table, cube and arm from 1.6 m above the table top.
    kinect_quat: tuple[float, float, float, float] = (0.0, math.sin(math.pi / 4), 0.0, math.cos(math.pi / 4))
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
    # Kinect v2 depth camera (ROBOT_FACTS "Kinect v2"): 512 x 424, vertical FOV 60 deg, 0.5-4.5 m.
    kinect_size: tuple[int, int] = (512, 424)
    kinect_fov: float = 60.0
    kinect_near: float = 0.5
    kinect_far: float = 4.5
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
    """The loaded seed scene in one world; ``rg2`` couples the gripper on ``robot``."""

    world: World
    config: SceneConfig
    robot: Body
    rg2: RG2
    table: Body
    kinect: Body
    cube: Body

    @property
    def client(self) -> int:
        return self.world.client

    def arm_positions(self) -> np.ndarray:
        """Current arm joint positions in JOINT_NAMES order, (6,) rad."""
        return self.robot.joint_positions(JOINT_NAMES)

    def command_arm(self, q: np.ndarray | tuple[float, ...]) -> None:
        """Position-control the six arm joints to ``q`` (6,) rad with the URDF effort limits as forces."""
        self.robot.position_control(dict(zip(JOINT_NAMES, q, strict=True)))

    def command_gripper(self, angle: float) -> None:
        """Hold the driven gripper angle (rad) with the configured grip force."""
        self.rg2.hold_position(angle, self.config.gripper.grip_force)

    def reset_pose(self, q: np.ndarray | tuple[float, ...], gripper_angle: float) -> None:
        """Teleport arm and gripper (set-up only) and command the same targets."""
        self.robot.reset_joints(dict(zip(JOINT_NAMES, map(float, q), strict=True)))
        self.rg2.reset_angle(gripper_angle)
        self.command_arm(q)
        self.command_gripper(gripper_angle)

    def gripper_range(self) -> tuple[float, float]:
        """The driven joint's URDF limits (rad)."""
        j = self.robot.joints[self.rg2.driven]
        return j.lower, j.upper

    def seed_camera(self, width: int, height: int, fov: float | None = None) -> Camera:
        """The seed's debug camera off-screen; ``fov`` vertical, degrees (default ``record_fov``)."""
        c = self.config
        fov = c.record_fov if fov is None else fov
        return orbit_camera(
            c.camera_target, c.camera_distance, c.camera_yaw, c.camera_pitch, width, height, fov=fov
        )

    def kinect_camera(self) -> Camera:
        """What the Kinect's depth camera sees (its optical frame, vertical FOV 60 deg, 512 x 424)."""
        c = self.config
        T = self.kinect.link_pose(KINECT_OPTICAL_LINK)
        return optical_camera(T, c.kinect_fov, *c.kinect_size, c.kinect_near, c.kinect_far)

    def solve_ik(
        self, T_world_tcp: Transform, start: np.ndarray | None = None, iterations: int = 20
    ) -> np.ndarray:
        """Arm joints (6,) placing the ``tcp`` link at ``T_world_tcp``; the world state is unchanged.

        PyBullet's IK linearises about the current state, so the solution is refined by resetting to
        it and solving again, inside a saved state, from ``start`` (6,) (default the initial pose, also
        the null-space rest pose). The null-space arrays cover every movable DOF, gripper joints
        included (ROBOT_FACTS pitfall 7).
        """
        movable = self.robot.movable_joints
        lower = [j.lower for j in movable]
        upper = [j.upper for j in movable]
        ranges = [u - lo for lo, u in zip(lower, upper, strict=True)]
        q = np.asarray(self.config.initial_arm if start is None else start, dtype=float)
        rest_by_name = dict(zip(JOINT_NAMES, q, strict=True))
        state = self.world.save_state()
        try:
            rest = [rest_by_name.get(j.name, self.robot.joint_position(j.name)) for j in movable]
            arm_slots = [k for k, j in enumerate(movable) if j.name in rest_by_name]
            self.robot.reset_joints(rest_by_name)
            for _ in range(iterations):
                sol = pb.calculateInverseKinematics(
                    self.robot.uid,
                    self.robot.links[TCP_LINK],
                    T_world_tcp.pos.tolist(),
                    T_world_tcp.quat.tolist(),
                    lowerLimits=lower,
                    upperLimits=upper,
                    jointRanges=ranges,
                    restPoses=rest,
                    maxNumIterations=100,
                    residualThreshold=1e-5,
                    physicsClientId=self.client,
                )
                by_name = {movable[k].name: sol[k] for k in arm_slots}
                q_new = np.array([by_name[n] for n in JOINT_NAMES])
                converged = np.abs(q_new - q).max() < IK_TOLERANCE
                q = q_new
                if converged:
                    break
                self.robot.reset_joints(dict(zip(JOINT_NAMES, q, strict=True)))
        finally:
            self.world.restore_state(state)
            self.world.remove_state(state)
        return q


def open_world(config: SceneConfig, *, gui: bool) -> World:
    """A world with the seed's physics settings (gravity -9.8)."""
    return World(config.physics, gui=gui)


def build_scene(world: World, config: SceneConfig | None = None) -> Scene:
    """Load the seed scene into ``world`` and put the arm in the seed's initial pose."""
    config = config or SceneConfig()
    client = world.client
    data = Path(pybullet_data.getDataPath())
    urdf = paths.ur3_rg2_urdf()
    robot = Body.load(client, urdf, Transform.identity(), flags=ROBOT_FLAGS)  # mounts itself
    rg2 = RG2(robot, urdf, config.gripper)
    table = Body.load(client, data / config.table_urdf, Transform(config.table_pos, [0, 0, 0, 1]))
    kinect = Body.load(
        client, paths.kinect_urdf(), Transform(config.kinect_pos, config.kinect_quat), fixed_base=True
    )
    cube = Body.load(client, data / config.cube_urdf, Transform(config.cube_pos, [0, 0, 0, 1]))
    scene = Scene(world, config, robot, rg2, table, kinect, cube)
    scene.reset_pose(config.initial_arm, 0.0)
    return scene


# --- scripted sequence ----------------------------------------------------------------------------


@dataclass(frozen=True)
class Keyframe:
    """Arm joints (6,) rad and driven gripper angle (rad) to be reached at ``time`` (s)."""

    time: float
    arm: tuple[float, ...]
    gripper: float


@dataclass(frozen=True)
class Script:
    """Keyframes joined by smooth-step joint interpolation; holds the last keyframe afterwards."""

    keyframes: tuple[Keyframe, ...]

    @property
    def duration(self) -> float:
        return self.keyframes[-1].time

    def at(self, t: float) -> tuple[np.ndarray, float]:
        """Targets at time ``t`` (s): arm (6,) rad and gripper angle (rad)."""
        frames = self.keyframes
        if t <= frames[0].time:
            return np.asarray(frames[0].arm), frames[0].gripper
        for a, b in zip(frames[:-1], frames[1:], strict=True):
            if t <= b.time:
                u = (t - a.time) / (b.time - a.time)
                u = u * u * (3.0 - 2.0 * u)  # smooth step: zero velocity at both keyframes
                arm = (1.0 - u) * np.asarray(a.arm) + u * np.asarray(b.arm)
                return arm, (1.0 - u) * a.gripper + u * b.gripper
        return np.asarray(frames[-1].arm), frames[-1].gripper


def demo_script(scene: Scene) -> Script:
    """Sweep the joints, open the gripper, reach towards the cube, close on it, lift, hold.

    The cube at (0.7, 0, 0) is beyond a top-down reach of the UR3 (500 mm reach; IK misses by
    0.30 m), so the gripper approaches from the side, tilted 10 deg down, closing horizontally.
    """
    c = scene.config
    q0 = np.asarray(c.initial_arm)
    lower, upper = scene.gripper_range()
    closed = scene.rg2.table.angle_of(0.0)  # commanding past the cube: the grip force limits it
    sweep_a = q0 + np.array([0.8, 0.4, -0.6, 0.5, 0.0, 1.0])
    sweep_b = q0 + np.array([-0.8, 0.6, -1.2, -0.4, -0.5, -1.0])
    # Approach +x tilted 10 deg down, closing axis (gripper x) along world y.
    R = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # columns: gripper x, y, z
    tilt = math.radians(10.0)
    Ry = np.array([[math.cos(tilt), 0, math.sin(tilt)], [0, 1, 0], [-math.sin(tilt), 0, math.cos(tilt)]])
    R = Ry @ R
    approach = R[:, 2]
    grasp = np.asarray(c.cube_pos) + np.array([0.0, 0.0, 0.005])
    q_pre = scene.solve_ik(Transform.from_rotation(R, grasp - 0.12 * approach))
    q_grasp = scene.solve_ik(Transform.from_rotation(R, grasp), start=q_pre)
    q_lift = scene.solve_ik(Transform.from_rotation(R, grasp + np.array([0.0, 0.0, 0.10])), start=q_grasp)
    g0 = 0.0
    keys = [
        Keyframe(0.0, tuple(q0), g0),
        Keyframe(1.0, tuple(sweep_a), upper),
        Keyframe(2.0, tuple(sweep_b), lower),
        Keyframe(3.0, tuple(q0), g0),
        Keyframe(4.5, tuple(q_pre), upper),
        Keyframe(5.5, tuple(q_grasp), upper),
        Keyframe(6.3, tuple(q_grasp), closed),
        Keyframe(7.3, tuple(q_lift), closed),
        Keyframe(7.8, tuple(q_lift), closed),
    ]
    return Script(tuple(keys))


@dataclass
class Recording:
    """What a headless run produced: RGB frames (h, w, 3) uint8 and the final state."""

    frames: list[np.ndarray]
    arm: np.ndarray
    gripper_width: float
    cube_pos: np.ndarray


def run_script(scene: Scene, script: Script, camera: Camera | None, n_frames: int) -> Recording:
    """Step the world through ``script`` (simulated time, no sleeping) and render ``n_frames`` evenly."""
    dt = scene.world.dt
    n_steps = max(1, round(script.duration / dt))
    render_at = set(np.linspace(0, n_steps, n_frames).round().astype(int).tolist()) if camera else set()
    frames: list[np.ndarray] = []
    for k in range(n_steps + 1):
        if k in render_at:
            frames.append(render_rgb(scene.client, camera))
        arm, angle = script.at(k * dt)
        scene.command_arm(arm)
        scene.command_gripper(angle)
        scene.world.step()
    return Recording(frames, scene.arm_positions(), scene.rg2.measured_width(), scene.cube.base_pose().pos)


# --- GUI ------------------------------------------------------------------------------------------


def add_sliders(scene: Scene) -> dict[str, int]:
    """The seed's sliders: six joints over +-pi at the initial pose, and the gripper angle."""
    c = scene.config
    sliders = {
        name: pb.addUserDebugParameter(name, -c.slider_range, c.slider_range, q, physicsClientId=scene.client)
        for name, q in zip(JOINT_NAMES, c.initial_arm, strict=True)
    }
    lower, upper = scene.gripper_range()
    sliders[GRIPPER_SLIDER] = pb.addUserDebugParameter(
        GRIPPER_SLIDER, lower, upper, 0.0, physicsClientId=scene.client
    )
    return sliders


def read_sliders(scene: Scene, sliders: dict[str, int]) -> tuple[np.ndarray, float]:
    read = lambda name: pb.readUserDebugParameter(sliders[name], physicsClientId=scene.client)  # noqa: E731
    return np.array([read(n) for n in JOINT_NAMES]), read(GRIPPER_SLIDER)


def screenshot(scene: Scene) -> np.ndarray:
    """The GUI window's current view, (h, w, 3) uint8, rendered with the window's own camera."""
    width, height, view, projection = pb.getDebugVisualizerCamera(physicsClientId=scene.client)[:4]
    camera = Camera(tuple(view), tuple(projection), width, height)
    return render_rgb(scene.client, camera, renderer=pb.ER_BULLET_HARDWARE_OPENGL)


def run_gui(
    config: SceneConfig,
    seconds: float | None,
    screenshot_path: Path | None,
    screenshot_at: float,
    demo: bool,
) -> None:
    """The seed's slider loop at real time until the window closes or ``seconds`` of sim time pass."""
    world = open_world(config, gui=True)
    client = world.client
    # Every PyBullet call in GUI mode waits for the window thread; loading and RG2's FK table with
    # rendering on took ~40 s under software OpenGL, ~1-10 s with it off.
    pb.configureDebugVisualizer(pb.COV_ENABLE_RENDERING, 0, physicsClientId=client)
    scene = build_scene(world, config)
    script = demo_script(scene) if demo else None
    pb.configureDebugVisualizer(pb.COV_ENABLE_RENDERING, 1, physicsClientId=client)
    pb.resetDebugVisualizerCamera(
        config.camera_distance,
        config.camera_yaw,
        config.camera_pitch,
        list(config.camera_target),
        physicsClientId=client,
    )
    sliders = add_sliders(scene)
    # One stepSimulation call per GUI frame, split into substeps of the usual time step.
    substeps = max(1, round(1.0 / (config.gui_rate * world.dt)))
    frame_dt = substeps * world.dt
    pb.setPhysicsEngineParameter(fixedTimeStep=frame_dt, numSubSteps=substeps, physicsClientId=client)
    frame, start = 0, time.monotonic()
    try:
        while seconds is None or frame * frame_dt < seconds:
            try:
                if script is not None:
                    arm, angle = script.at((frame * frame_dt) % (script.duration + 1.0))
                else:
                    arm, angle = read_sliders(scene, sliders)
                scene.command_arm(arm)
                scene.command_gripper(angle)
                pb.stepSimulation(physicsClientId=client)
            except pb.error:  # the window was closed
                break
            frame += 1
            t = frame * frame_dt
            if screenshot_path is not None and t >= screenshot_at:
                write_png(screenshot(scene), screenshot_path)
                width, height = pb.getDebugVisualizerCamera(physicsClientId=client)[:2]
                q = np.round(scene.arm_positions(), 4).tolist()
                click.echo(f"screenshot {width}x{height} at t={t:.2f} s, arm q = {q} -> {screenshot_path}")
                screenshot_path = None
            lag = start + t - time.monotonic()
            if lag > 0:
                time.sleep(lag)  # real time in the interactive loop only
        if pb.isConnected(physicsClientId=client):
            wall = time.monotonic() - start
            q = np.round(scene.arm_positions(), 4).tolist()
            click.echo(f"ran {frame * frame_dt:.2f} s simulated in {wall:.2f} s; arm q = {q}")
    finally:
        world.close()


# --- command --------------------------------------------------------------------------------------


@click.command("scene")
@click.option("--headless", is_flag=True, help="No window: play the scripted sequence in DIRECT mode.")
@click.option(
    "--gif",
    "gif_path",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Headless: write an animated GIF.",
)
@click.option(
    "--png",
    "png_path",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Headless: write the last frame as PNG.",
)
@click.option(
    "--kinect-png",
    "kinect_path",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Headless: write what the Kinect sees at the end (512x424, vertical FOV 60 deg) as PNG.",
)
@click.option(
    "--frames", default=40, show_default=True, type=click.IntRange(min=2), help="Headless: GIF frames."
)
@click.option(
    "--size", default=(320, 240), show_default=True, type=(int, int), help="Headless: frame width height."
)
@click.option(
    "--fov",
    type=click.FloatRange(1, 170),
    help="Headless: vertical field of view, degrees [default: 60; the GUI window's is 90].",
)
@click.option(
    "--seconds", type=click.FloatRange(min=0), help="GUI: quit after this much simulated (= real) time."
)
@click.option(
    "--screenshot",
    "screenshot_path",
    type=click.Path(dir_okay=False, path_type=Path),
    help="GUI: save the window's view as PNG once --screenshot-at seconds have run.",
)
@click.option(
    "--screenshot-at", default=0.5, show_default=True, type=click.FloatRange(min=0), help="GUI: when (s)."
)
@click.option(
    "--demo", is_flag=True, help="GUI: play the scripted sequence (looping) instead of reading the sliders."
)
def scene_command(
    headless: bool,
    gif_path: Path | None,
    png_path: Path | None,
    kinect_path: Path | None,
    frames: int,
    size: tuple[int, int],
    fov: float | None,
    seconds: float | None,
    screenshot_path: Path | None,
    screenshot_at: float,
    demo: bool,
) -> None:
    """The seed scene: UR3 + RG2 at the origin, table, cube and a Kinect looking down at the table.

    \b
    GUI (default): sliders for the six arm joints (+-pi, starting at 0, -pi/2, 0, 0, pi/2, 0) and
    `gripper_opening_angle`, the RG2's driven joint over the model's own URDF limits
    (-0.045 .. 1.268 rad, 0 .. 110 mm, the full RG2 stroke; the seed's slider stopped at 0.8 rad,
    which is only ~84 mm on this model). Each step the arm joints are position-controlled to the
    sliders with the URDF effort limits, the gripper holds the slider angle with the 40 N grip force
    (followers coupled by gear constraints), and the loop runs at real time. Close the window or
    pass --seconds to stop.

    \b
    Headless (--headless): no window; the scripted sequence (sweep the joints, open, reach
    towards the cube from the side, close, lift) runs in simulated time and is rendered with the
    software renderer from the seed's camera (distance 2, yaw 0, pitch -40, target 0.5 -0.9 0.5).

    \b
    Examples:
      annotator scene
      annotator scene --headless --gif scene.gif --png last.png --kinect-png kinect.png
      xvfb-run -a annotator scene --demo --seconds 3 --screenshot-at 2 --screenshot window.png
    """
    config = SceneConfig()
    if not headless:
        if gif_path or png_path or kinect_path:
            raise click.UsageError("--gif, --png and --kinect-png need --headless")
        run_gui(config, seconds, screenshot_path, screenshot_at, demo)
        return
    if screenshot_path:
        raise click.UsageError("--screenshot is for the GUI; use --png with --headless")
    with open_world(config, gui=False) as world:
        scene = build_scene(world, config)
        camera = scene.seed_camera(*size, fov=fov) if (gif_path or png_path) else None
        script = demo_script(scene)
        rec = run_script(scene, script, camera, frames if gif_path else 2)
        if gif_path:
            write_gif(rec.frames, gif_path, fps=len(rec.frames) / script.duration)
            click.echo(f"gif: {len(rec.frames)} frames {size[0]}x{size[1]} -> {gif_path}")
        if png_path:
            write_png(rec.frames[-1], png_path)
            click.echo(f"png -> {png_path}")
        if kinect_path:
            write_png(render_rgb(scene.client, scene.kinect_camera()), kinect_path)
            click.echo(f"kinect png -> {kinect_path}")
        click.echo(
            f"arm q = {np.round(rec.arm, 4).tolist()}; gripper width {rec.gripper_width * 1000:.1f} mm; "
            f"cube at {np.round(rec.cube_pos, 3).tolist()}"
        )


if __name__ == "__main__":
    scene_command()
