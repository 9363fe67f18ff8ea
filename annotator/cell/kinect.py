"""Kinect v2 views of a PyBullet world: depth (m, or 16-bit PNG in mm), colour, segmentation.

A view is rendered from an *optical frame* (ROS REP 103: +z along the view, +x right, +y down in
the image) with pinhole intrinsics from the Kinect v2's published fields of view (KinectConfig).
Pixel ``(u, v)`` (column, row; integer at pixel centres) sees the ray through
``((u - cx) / fx, (v - cy) / fy, 1)`` in that frame, exactly: the OpenGL projection handed to
PyBullet is built from K, not from ``computeProjectionMatrixFOV`` (which takes the vertical FOV
and assumes square pixels).

Depth is the distance along the optical axis (z in the camera frame), from the z-buffer by
``z = far near / (far - (far - near) d)``; 0 where the sensor would report nothing (outside
0.5-4.5 m, or background). An optional noise model (KinectConfig) perturbs it.

Helpers: :func:`point_cloud` (camera-frame points of a depth image), :func:`project`
(camera-frame points to pixels), :func:`poses_in_camera` (label TCP poses into the camera frame),
:func:`look_at` (an optical frame looking at a point), :func:`write_depth_png` /
:func:`read_depth_png` (16-bit millimetres, readable without this package).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from annotator.config import KinectConfig
from annotator.geometry import Transform
from annotator.sim.camera import OPENGL_RENDERER, TINY_RENDERER, camera_image

# T_gl_optical: OpenGL's eye frame (looks along -z, y up) from the optical frame (z forward, y down).
_GL_FROM_OPTICAL = np.diag([1.0, -1.0, -1.0, 1.0])
BACKGROUND = -1  # segmentation value where no body is seen
DEPTH_PNG_SCALE = 1000.0  # depth PNG units per metre (millimetres, as the Kinect SDK reports)


@dataclass(frozen=True)
class Intrinsics:
    """A pinhole camera: image ``width`` x ``height`` px, focal lengths and principal point in px."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def from_fov(cls, width: int, height: int, hfov: float, vfov: float) -> Intrinsics:
        """From horizontal and vertical fields of view (degrees), principal point at the centre."""
        fx = (width / 2) / math.tan(math.radians(hfov) / 2)
        fy = (height / 2) / math.tan(math.radians(vfov) / 2)
        return cls(width, height, fx, fy, (width - 1) / 2, (height - 1) / 2)

    @property
    def K(self) -> np.ndarray:
        """(3, 3) camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def scaled(self, factor: float) -> Intrinsics:
        """The same field of view at ``factor`` times the resolution (for quick previews)."""
        w, h = max(1, round(self.width * factor)), max(1, round(self.height * factor))
        sx, sy = w / self.width, h / self.height
        return Intrinsics(
            w, h, self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5
        )

    def projection_matrix(
        self, near: float, far: float, sample: tuple[float, float] = (0.5, 0.5)
    ) -> tuple[float, ...]:
        """The OpenGL projection (16 floats, column-major, as PyBullet takes) equal to K.

        ``sample``: where the renderer samples each pixel, in pixels from its lower-left corner
        (OpenGL: the centre, (0.5, 0.5); PyBullet's TinyRenderer: the corner, (0, 0), see
        ``RENDERER_SAMPLE``). Pixel centres are at integer (u, v), row 0 at the image top.
        """
        w, h = self.width, self.height
        sx, sy = sample
        P = np.zeros((4, 4))
        P[0, 0] = 2 * self.fx / w
        P[0, 2] = (w - 2 * (self.cx + sx)) / w
        P[1, 1] = 2 * self.fy / h
        P[1, 2] = (2 * (self.cy + 1 - sy) - h) / h
        P[2, 2] = -(far + near) / (far - near)
        P[2, 3] = -2 * far * near / (far - near)
        P[3, 2] = -1.0
        return tuple(P.T.reshape(-1).tolist())


# Where each renderer samples a pixel (from its lower-left corner, in pixels). TinyRenderer
# (DIRECT mode) rasterises at pixel corners: measured, a box's mask came out one pixel wider on the
# right and the top than pixel-centre sampling predicts (tests/test_kinect.py checks every pixel).
RENDERER_SAMPLE = {TINY_RENDERER: (0.0, 0.0), OPENGL_RENDERER: (0.5, 0.5)}


def depth_intrinsics(config: KinectConfig) -> Intrinsics:
    """The depth camera's intrinsics (512 x 424 at 70.6 x 60 deg by default)."""
    return Intrinsics.from_fov(config.depth_width, config.depth_height, config.depth_hfov, config.depth_vfov)


def color_intrinsics(config: KinectConfig) -> Intrinsics:
    """The colour camera's intrinsics (1920 x 1080 at 84.1 x 53.8 deg by default)."""
    return Intrinsics.from_fov(config.color_width, config.color_height, config.color_hfov, config.color_vfov)


def view_matrix(T_world_optical: Transform) -> tuple[float, ...]:
    """PyBullet's view matrix (16 floats, column-major) of a camera at an optical frame."""
    V = _GL_FROM_OPTICAL @ T_world_optical.inverse().as_matrix()
    return tuple(V.T.reshape(-1).tolist())


def look_at(eye: np.ndarray, target: np.ndarray, up: ArrayLike = (0.0, 0.0, 1.0)) -> Transform:
    """``T_world_optical`` of a camera at ``eye`` (3,) looking at ``target`` (3,), image-up towards ``up``.

    When the view is along ``up`` the image's up is taken towards world +x instead.
    """
    eye, target = np.asarray(eye, dtype=float), np.asarray(target, dtype=float)
    z = target - eye
    z /= np.linalg.norm(z)
    up_world = np.asarray(up, dtype=float)
    if abs(float(np.dot(z, up_world / np.linalg.norm(up_world)))) > 1 - 1e-9:
        up_world = np.array([1.0, 0.0, 0.0])
    x = np.cross(-up_world, z)  # image right: x = y cross z with y (image down) along -up
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return Transform.from_rotation(np.column_stack([x, y, z]), eye)


def linearize_depth(zbuffer: np.ndarray, near: float, far: float) -> np.ndarray:
    """Depth along the optical axis (m) from PyBullet's [0, 1] z-buffer: same shape, float64."""
    d = np.asarray(zbuffer, dtype=np.float64)
    return far * near / (far - (far - near) * d)


@dataclass(frozen=True)
class KinectView:
    """One rendered view.

    ``T_world_camera``: the optical frame (the extrinsics: camera pose in the world).
    ``depth`` : (h, w) float32 m along the optical axis, 0 where nothing is measured;
    ``segmentation`` : (h, w) int32 body unique id seen at each depth pixel, ``BACKGROUND`` (-1)
    for none; ``color`` : (H, W, 3) uint8 or None, from the same optical frame.
    """

    T_world_camera: Transform
    depth_K: Intrinsics
    depth: np.ndarray
    segmentation: np.ndarray
    color_K: Intrinsics | None = None
    color: np.ndarray | None = None

    def camera_row(self) -> dict[str, float | int]:
        """Intrinsics and extrinsics as one flat record (a Parquet row a learner reads directly).

        ``fx fy cx cy width height`` of the depth image; ``x y z qx qy qz qw`` the camera (optical
        frame) in the world, quaternion xyzw.
        """
        K = self.depth_K
        pos, quat = self.T_world_camera.pos, self.T_world_camera.quat
        row: dict[str, float | int] = {"width": K.width, "height": K.height, "fx": K.fx, "fy": K.fy}
        row.update({"cx": K.cx, "cy": K.cy})
        row.update(dict(zip(("x", "y", "z"), map(float, pos), strict=True)))
        row.update(dict(zip(("qx", "qy", "qz", "qw"), map(float, quat), strict=True)))
        return row


def _render(
    client: int, T_world_optical: Transform, K: Intrinsics, config: KinectConfig, renderer: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rgb (h, w, 3) uint8, depth (h, w) m (inf where nothing is drawn), segmentation (h, w) int32)."""
    near, far = config.near_plane, config.far_plane
    rgba, zbuffer, seg = camera_image(
        client,
        K.width,
        K.height,
        view_matrix(T_world_optical),
        K.projection_matrix(near, far, RENDERER_SAMPLE[renderer]),
        renderer,
    )
    rgb = np.asarray(rgba, dtype=np.uint8).reshape(K.height, K.width, 4)[:, :, :3]
    zb = np.asarray(zbuffer, dtype=np.float64).reshape(K.height, K.width)
    depth = linearize_depth(zb, near, far)
    depth[zb >= 1.0] = np.inf  # the far plane: nothing there
    segmentation = np.asarray(seg, dtype=np.int64).reshape(K.height, K.width)
    # with object-and-link flags the id carries the link in its high bits; keep the body id
    segmentation = np.where(segmentation < 0, BACKGROUND, segmentation & ((1 << 24) - 1)).astype(np.int32)
    return np.ascontiguousarray(rgb), depth, segmentation


def apply_depth_noise(depth: np.ndarray, config: KinectConfig, rng: np.random.Generator) -> np.ndarray:
    """The documented noise model (KinectConfig): Gaussian sigma = noise_sigma_1m z^2 along the
    ray, rounded to noise_quantum; 0 (no measurement) stays 0. ``depth`` (h, w) m -> same."""
    d = np.asarray(depth, dtype=np.float64)
    valid = d > 0
    noisy = d + rng.standard_normal(d.shape) * config.noise_sigma_1m * d * d
    if config.noise_quantum > 0:
        noisy = np.round(noisy / config.noise_quantum) * config.noise_quantum
    return np.where(valid, noisy, 0.0)


def render_view(
    client: int,
    T_world_camera: Transform,
    config: KinectConfig | None = None,
    *,
    color: bool = True,
    color_scale: float = 1.0,
    rng: np.random.Generator | None = None,
    renderer: int = TINY_RENDERER,
) -> KinectView:
    """Render depth, segmentation and (if ``color``) colour from the optical frame ``T_world_camera``.

    ``color_scale`` < 1 renders the colour image at a lower resolution with the same field of view
    (a full 1920 x 1080 software render takes a few seconds). ``rng`` turns the depth noise on.
    """
    config = config or KinectConfig()
    K = depth_intrinsics(config)
    _, depth, segmentation = _render(client, T_world_camera, K, config, renderer)
    out_of_range = ~np.isfinite(depth) | (depth < config.min_range) | (depth > config.max_range)
    depth = np.where(out_of_range, 0.0, depth)
    if rng is not None:
        depth = apply_depth_noise(depth, config, rng)
    color_K, rgb = None, None
    if color:
        color_K = color_intrinsics(config)
        if color_scale != 1.0:
            color_K = color_K.scaled(color_scale)
        rgb, _, _ = _render(client, T_world_camera, color_K, config, renderer)
    return KinectView(T_world_camera, K, depth.astype(np.float32), segmentation, color_K, rgb)


# --- using the images ------------------------------------------------------------------------------


def point_cloud(depth: np.ndarray, K: Intrinsics, organized: bool = False) -> np.ndarray:
    """Camera-frame points of a depth image (h, w) m: (n, 3) for the valid pixels, row-major order,
    or (h, w, 3) with NaN where depth is 0 if ``organized``."""
    d = np.asarray(depth, dtype=np.float64)
    v, u = np.indices(d.shape)
    pts = np.stack([(u - K.cx) / K.fx * d, (v - K.cy) / K.fy * d, d], axis=-1)
    if organized:
        return np.where((d > 0)[..., None], pts, np.nan)
    return pts[d > 0]


def project(points_camera: np.ndarray, K: Intrinsics) -> np.ndarray:
    """Pixel coordinates (n, 2) (u column, v row) of camera-frame points (n, 3) with z > 0."""
    p = np.atleast_2d(np.asarray(points_camera, dtype=np.float64))
    return np.stack([K.fx * p[:, 0] / p[:, 2] + K.cx, K.fy * p[:, 1] / p[:, 2] + K.cy], axis=1)


def poses_in_camera(T_world_camera: Transform, T_world_obj: Transform, T_obj_tcp: np.ndarray) -> np.ndarray:
    """Label TCP poses (n, 4, 4) in the object's mesh frame -> (n, 4, 4) in the camera (optical) frame.

    ``T_camera_tcp = T_world_camera^-1 T_world_obj T_obj_tcp`` (``annotator.dataset.poses_as_matrices``
    gives ``T_obj_tcp``).
    """
    T_camera_obj = (T_world_camera.inverse() * T_world_obj).as_matrix()
    return np.einsum("ij,njk->nik", T_camera_obj, np.asarray(T_obj_tcp, dtype=np.float64).reshape(-1, 4, 4))


def depth_to_png_array(depth: np.ndarray) -> np.ndarray:
    """Depth (h, w) m -> (h, w) uint16 millimetres (0 = no measurement; saturates at 65.535 m)."""
    mm = np.round(np.asarray(depth, dtype=np.float64) * DEPTH_PNG_SCALE)
    return np.clip(np.nan_to_num(mm, nan=0.0), 0, 65535).astype(np.uint16)


def write_depth_png(depth: np.ndarray, path: Path | str) -> None:
    """Write depth (h, w) m as a 16-bit greyscale PNG in millimetres (OpenCV, PIL, imageio read it)."""
    from PIL import Image

    Image.fromarray(depth_to_png_array(depth)).save(Path(path), format="PNG")


def read_depth_png(path: Path | str) -> np.ndarray:
    """Read a depth PNG of :func:`write_depth_png`: (h, w) float32 metres."""
    from PIL import Image

    with Image.open(Path(path)) as im:
        return (np.asarray(im, dtype=np.float64) / DEPTH_PNG_SCALE).astype(np.float32)
