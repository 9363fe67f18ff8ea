"""Off-screen pictures of a PyBullet client: camera matrices, RGB frames, PNG and animated GIF files."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from annotator.sim import camera as sim_camera
from annotator.sim.camera import TINY_RENDERER


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
    view = sim_camera.view_from_yaw_pitch(target, distance, yaw, pitch)
    projection = sim_camera.projection_fov(fov, width / height, near, far)
    return Camera(view, projection, width, height)


def render_rgb(client: int, camera: Camera, renderer: int = TINY_RENDERER) -> np.ndarray:
    """Render one frame; returns (height, width, 3) uint8 RGB."""
    rgba, _, _ = _camera_image(client, camera, renderer)
    return _rgb(rgba, camera)


def _camera_image(client: int, camera: Camera, renderer: int) -> tuple:
    """PyBullet's raw ``(rgba, zbuffer, segmentation)`` buffers for ``camera``."""
    return sim_camera.camera_image(
        client, camera.width, camera.height, camera.view, camera.projection, renderer
    )


def _rgb(rgba, camera: Camera) -> np.ndarray:
    """(height, width, 3) uint8 RGB from PyBullet's flat RGBA buffer."""
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


@dataclass(frozen=True)
class Frame:
    """One rendered frame with its depth and segmentation.

    ``rgb`` : (h, w, 3) uint8. ``depth`` : (h, w) float, metres along the viewing axis (eye-space
    depth; ``far`` where nothing was drawn). ``segmentation`` : (h, w) int, the body id drawn at
    each pixel (-1 for background).
    """

    rgb: np.ndarray
    depth: np.ndarray
    segmentation: np.ndarray
    camera: Camera


def _near_far(camera: Camera) -> tuple[float, float]:
    """Near and far planes of a perspective projection matrix (column-major flat, as PyBullet's)."""
    P = np.asarray(camera.projection, dtype=np.float64).reshape(4, 4).T
    a, b = P[2, 2], P[2, 3]  # a = -(f + n) / (f - n), b = -2 f n / (f - n)
    return b / (a - 1.0), b / (a + 1.0)


def render_frame(client: int, camera: Camera, renderer: int = TINY_RENDERER) -> Frame:
    """Render RGB, metric depth and body segmentation in one call (see :class:`Frame`)."""
    rgba, zbuffer, seg = _camera_image(client, camera, renderer)
    shape = (camera.height, camera.width)
    rgb = _rgb(rgba, camera)
    near, far = _near_far(camera)
    z = np.asarray(zbuffer, dtype=np.float64).reshape(shape)
    depth = far * near / (far - (far - near) * z)
    seg = np.asarray(seg, dtype=np.int64).reshape(shape)  # body ids (no link bits without the flag)
    return Frame(rgb, depth, seg, camera)


def project(camera: Camera, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates and eye-space depth of world points.

    ``points`` : (n, 3) float, m -> ``(uv (n, 2) float`` pixel column, row (row 0 at the top),
    ``depth (n,) float`` m along the viewing axis, comparable with :attr:`Frame.depth`).
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    V = np.asarray(camera.view, dtype=np.float64).reshape(4, 4).T
    P = np.asarray(camera.projection, dtype=np.float64).reshape(4, 4).T
    eye = np.c_[pts, np.ones(len(pts))] @ V.T
    clip = eye @ P.T
    ndc = clip[:, :2] / clip[:, 3:4]
    uv = np.c_[(ndc[:, 0] + 1.0) / 2.0 * camera.width, (1.0 - ndc[:, 1]) / 2.0 * camera.height]
    return uv, -eye[:, 2]


def look_at_camera(
    eye: ArrayLike,
    target: ArrayLike,
    up: ArrayLike,
    width: int,
    height: int,
    fov: float = 40.0,
    near: float = 0.01,
    far: float = 5.0,
) -> Camera:
    """A camera at ``eye`` looking at ``target`` with ``up`` upwards in the image (vertical fov, deg)."""
    view = sim_camera.view_from_eye(
        np.asarray(eye, float).tolist(), np.asarray(target, float).tolist(), np.asarray(up, float).tolist()
    )
    projection = sim_camera.projection_fov(fov, width / height, near, far)
    return Camera(view, projection, width, height)
