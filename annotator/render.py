"""Off-screen pictures of a PyBullet client: camera matrices, RGB frames, PNG and animated GIF files."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from annotator.geometry import Transform
from annotator.sim import pb


@dataclass(frozen=True)
class Camera:
    """A pinhole camera as PyBullet wants it: flat 16-float view and projection matrices and a size."""

    view: tuple[float, ...]
    projection: tuple[float, ...]
    width: int
    height: int


def orbit_camera(
    target: tuple[float, float, float],
    distance: float,
    yaw: float,
    pitch: float,
    width: int,
    height: int,
    fov: float = 60.0,
    near: float = 0.01,
    far: float = 10.0,
) -> Camera:
    """The debug visualizer's orbit camera (degrees, as ``resetDebugVisualizerCamera``) off-screen.

    ``fov`` is the vertical field of view in degrees (PyBullet's GUI uses 60 as well).
    """
    view = pb.computeViewMatrixFromYawPitchRoll(
        cameraTargetPosition=list(target), distance=distance, yaw=yaw, pitch=pitch, roll=0.0, upAxisIndex=2
    )
    projection = pb.computeProjectionMatrixFOV(fov=fov, aspect=width / height, nearVal=near, farVal=far)
    return Camera(tuple(view), tuple(projection), width, height)


def optical_camera(
    T_world_optical: Transform, fov: float, width: int, height: int, near: float, far: float
) -> Camera:
    """A camera at an optical frame (ROS convention: +z forward, +x right, +y down).

    ``fov`` is the vertical field of view in degrees (``computeProjectionMatrixFOV`` takes the vertical).
    """
    R = T_world_optical.rotation
    eye = T_world_optical.pos
    view = pb.computeViewMatrix(
        cameraEyePosition=eye.tolist(),
        cameraTargetPosition=(eye + R[:, 2]).tolist(),
        cameraUpVector=(-R[:, 1]).tolist(),
    )
    projection = pb.computeProjectionMatrixFOV(fov=fov, aspect=width / height, nearVal=near, farVal=far)
    return Camera(tuple(view), tuple(projection), width, height)


def render_rgb(client: int, camera: Camera, renderer: int = pb.ER_TINY_RENDERER) -> np.ndarray:
    """Render one frame; returns (height, width, 3) uint8 RGB."""
    _, _, rgba, _, _ = pb.getCameraImage(
        camera.width,
        camera.height,
        viewMatrix=list(camera.view),
        projectionMatrix=list(camera.projection),
        renderer=renderer,
        physicsClientId=client,
    )
    rgba = np.asarray(rgba, dtype=np.uint8).reshape(camera.height, camera.width, 4)
    return np.ascontiguousarray(rgba[:, :, :3])


def write_png(image: np.ndarray, path: Path | str) -> None:
    """Write a (h, w, 3) uint8 image as PNG."""
    from PIL import Image

    Image.fromarray(image).save(Path(path), format="PNG")


def write_gif(frames: list[np.ndarray], path: Path | str, fps: float) -> None:
    """Write (h, w, 3) uint8 frames as an endlessly looping animated GIF at ``fps`` frames per second."""
    from PIL import Image

    if not frames:
        raise ValueError("no frames to write")
    images = [Image.fromarray(f) for f in frames]
    images[0].save(
        Path(path),
        format="GIF",
        save_all=True,
        append_images=images[1:],
        duration=max(20, round(1000.0 / fps)),
        loop=0,
    )
