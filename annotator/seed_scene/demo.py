"""The seed scene's scripted sequence: keyframes joined smoothly, stepped in simulated time.

Sweep the joints, open the gripper, reach towards the cube, close on it, lift, hold; rendered
off-screen for ``annotator scene --headless`` or played in the GUI with ``--demo``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from annotator.geometry import Transform
from annotator.render import Camera, render_rgb
from annotator.seed_scene.model import Scene

CUBE_SIZE = 0.05  # m, the edge of pybullet_data's cube_small.urdf (the seed's cube)


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

    The cube at (0.7, 0, 0) is beyond a top-down reach of the UR3 (the closed-form IK finds no
    top-down TCP pose at the table past x = 0.52 m), so the gripper approaches from the side,
    tilted 10 deg down, closing horizontally. The poses are solved (closed form, nearest to the
    previous keyframe) for the TCP at the cube's width, where the pads meet its faces.
    """
    c = scene.config
    q0 = np.asarray(c.initial_arm)
    lower, upper = scene.gripper_range()
    closed = scene.gripper.table.angle_of(0.0)  # commanding past the cube: the grip force limits it
    sweep_a = q0 + np.array([0.8, 0.4, -0.6, 0.5, 0.0, 1.0])
    sweep_b = q0 + np.array([-0.8, 0.6, -1.2, -0.4, -0.5, -1.0])
    # Approach +x tilted 10 deg down, closing axis (gripper x) along world y.
    R = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # columns: gripper x, y, z
    tilt = math.radians(10.0)
    Ry = np.array([[math.cos(tilt), 0, math.sin(tilt)], [0, 1, 0], [-math.sin(tilt), 0, math.cos(tilt)]])
    R = Ry @ R
    approach = R[:, 2]
    grasp = np.asarray(c.cube_pos) + np.array([0.0, 0.0, 0.005])
    width = CUBE_SIZE
    q_pre = scene.solve_ik(Transform.from_rotation(R, grasp - 0.12 * approach), width)
    q_grasp = scene.solve_ik(Transform.from_rotation(R, grasp), width, start=q_pre)
    lifted = grasp + np.array([0.0, 0.0, 0.10])
    q_lift = scene.solve_ik(Transform.from_rotation(R, lifted), width, start=q_grasp)
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
    return Recording(
        frames, scene.arm_positions(), scene.gripper.measured_width(), scene.cube.base_pose().pos
    )
