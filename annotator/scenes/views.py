"""Kinect v2 views of a scene: cameras on VGN's sphere, instance segmentation, the fused cloud.

Cameras (:func:`view_pose`): as VGN's ``generate_data.py`` samples them, on a sphere around the
workspace's centre on the table: distance, polar angle from the vertical and azimuth uniform in
the ranges of :class:`annotator.config.SceneConfig`, each view looking at that centre with image-up
towards +z. View ``v`` of scene ``s`` draws from a Generator keyed on (seed, s, v) alone, so the
first K views are the same whatever K is; its depth noise (KinectConfig's model, when asked) from
another keyed on the same.

Images (:class:`SceneView`), rendered by :mod:`annotator.cell.kinect`: depth (m along the optical
axis, 0 = no measurement, written as 16-bit millimetres), colour, and segmentation as uint8:
``0`` nothing, ``instance_id + 1`` for an object (so instance ids up to MAX_INSTANCE_ID), 254 the
robot, 255 the table. The camera's optical frame is given in the table frame (``T_table_camera``:
+z along the view, +x right, +y down in the image), its pinhole intrinsics with it.

:func:`fused_point_cloud` back-projects every view into the table frame (optionally cropped to the
workspace) with each point's segmentation value.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from annotator.cell import kinect
from annotator.cell.kinect import Intrinsics, look_at
from annotator.config import KinectConfig, SceneConfig
from annotator.dataset import keyed_rng
from annotator.geometry import Transform
from annotator.scenes.records import SceneRecord, Workspace
from annotator.scenes.world import LoadedScene

SEG_NOTHING, SEG_ROBOT, SEG_TABLE = 0, 254, 255
MAX_INSTANCE_ID = 252  # instance_id + 1 must stay below SEG_ROBOT
CAMERA_POSE_COLUMNS = ("x", "y", "z", "qx", "qy", "qz", "qw")  # T_table_camera
INTRINSIC_COLUMNS = ("width", "height", "fx", "fy", "cx", "cy")


def view_pose(record: SceneRecord, view_id: int, scenes: SceneConfig) -> Transform:
    """``T_table_camera`` of view ``view_id`` of ``record`` (VGN's sphere; Generator keyed on the
    record's seed, scene id and the view)."""
    rng = keyed_rng("scene-view", int(record.seed), int(record.scene_id), int(view_id))
    r = rng.uniform(scenes.view_radius_min, scenes.view_radius_max)
    theta = rng.uniform(0.0, math.radians(scenes.view_max_polar))
    phi = rng.uniform(0.0, 2.0 * math.pi)
    target = np.array([record.workspace.center[0], record.workspace.center[1], 0.0])
    eye = target + r * np.array(
        [math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)]
    )
    return look_at(eye, target, np.array([0.0, 0.0, 1.0]))


@dataclass(frozen=True)
class SceneView:
    """One view of a scene: ``T_table_camera`` (optical frame in the table frame), ``depth``
    (h, w) float32 m (0 = no measurement), ``segmentation`` (h, w) uint8 (module docstring),
    ``color`` (H, W, 3) uint8 or None, and the intrinsics of each."""

    scene_id: int
    view_id: int
    T_table_camera: Transform
    depth_K: Intrinsics
    depth: np.ndarray
    segmentation: np.ndarray
    color_K: Intrinsics | None = None
    color: np.ndarray | None = None

    def point_cloud(self, organized: bool = False) -> np.ndarray:
        """Camera-frame points of the depth image: (n, 3) valid pixels (row-major), or (h, w, 3)."""
        return kinect.point_cloud(self.depth, self.depth_K, organized)

    def points_in_table(self) -> np.ndarray:
        """The valid pixels' points (n, 3) in the table frame, row-major order."""
        return self.T_table_camera.apply(self.point_cloud())

    def camera_row(self) -> dict[str, float | int]:
        """Intrinsics and extrinsics as one flat record (see :func:`views_table`)."""
        K = self.depth_K
        row: dict[str, float | int] = {"scene_id": self.scene_id, "view_id": self.view_id}
        row.update(dict(zip(INTRINSIC_COLUMNS, (K.width, K.height, K.fx, K.fy, K.cx, K.cy), strict=True)))
        pose = (*self.T_table_camera.pos.tolist(), *self.T_table_camera.quat.tolist())
        row.update(dict(zip(CAMERA_POSE_COLUMNS, map(float, pose), strict=True)))
        if self.color_K is not None:
            C = self.color_K
            values = (C.width, C.height, C.fx, C.fy, C.cx, C.cy)
            row.update({f"color_{c}": v for c, v in zip(INTRINSIC_COLUMNS, values, strict=True)})
        return row


def segmentation_of(loaded: LoadedScene, body_ids: np.ndarray) -> np.ndarray:
    """PyBullet body ids (h, w) of a render -> the scene's uint8 segmentation (module docstring)."""
    seg = np.full(body_ids.shape, SEG_NOTHING, dtype=np.uint8)
    cell = loaded.cell
    seg[body_ids == cell.table.uid] = SEG_TABLE
    if cell.robot is not None:
        seg[body_ids == cell.robot.uid] = SEG_ROBOT
    for instance_id, uid in loaded.uids.items():
        if instance_id > MAX_INSTANCE_ID:
            raise ValueError(f"instance id {instance_id} does not fit the uint8 segmentation")
        seg[body_ids == uid] = instance_id + 1
    return seg


def render_views(
    loaded: LoadedScene,
    views: int,
    *,
    scenes: SceneConfig | None = None,
    kinect_config: KinectConfig | None = None,
    noise: bool = False,
    color: bool = True,
    color_scale: float = 1.0,
) -> list[SceneView]:
    """Views 0..views-1 of the loaded scene (:func:`view_pose`); ``noise`` applies the Kinect's
    depth noise model from a Generator keyed on (seed, scene, view)."""
    scenes = scenes or SceneConfig()
    kinect_config = kinect_config or KinectConfig()
    record = loaded.record
    out = []
    for v in range(views):
        T_table_camera = view_pose(record, v, scenes)
        rng = keyed_rng("scene-view-noise", int(record.seed), int(record.scene_id), v) if noise else None
        view = kinect.render_view(
            loaded.client,
            record.T_world_table * T_table_camera,
            kinect_config,
            color=color,
            color_scale=color_scale,
            rng=rng,
        )
        seg = segmentation_of(loaded, view.segmentation)
        out.append(
            SceneView(
                record.scene_id, v, T_table_camera, view.depth_K, view.depth, seg, view.color_K, view.color
            )
        )
    return out


@dataclass(frozen=True)
class FusedCloud:
    """Points of several views in the table frame: ``points`` (n, 3) m, ``segmentation`` (n,)
    uint8 (the views' values), ``view_id`` (n,) int of the view each came from."""

    points: np.ndarray
    segmentation: np.ndarray
    view_id: np.ndarray


def fused_point_cloud(views: list[SceneView], crop: Workspace | None = None) -> FusedCloud:
    """Every valid depth pixel of ``views`` back-projected into the table frame, in view order;
    with ``crop``, only the points inside that workspace's box."""
    points, segs, ids = [], [], []
    for view in views:
        valid = view.depth > 0
        points.append(view.points_in_table())
        segs.append(view.segmentation[valid])
        ids.append(np.full(int(valid.sum()), view.view_id, dtype=np.int64))
    if not points:
        return FusedCloud(np.zeros((0, 3)), np.zeros(0, np.uint8), np.zeros(0, np.int64))
    cloud = FusedCloud(np.concatenate(points), np.concatenate(segs), np.concatenate(ids))
    if crop is None:
        return cloud
    inside = crop.contains(cloud.points)
    return FusedCloud(cloud.points[inside], cloud.segmentation[inside], cloud.view_id[inside])


# --- files --------------------------------------------------------------------------------------------


def _png(image: np.ndarray) -> bytes:
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image)).save(buffer, format="PNG")
    return buffer.getvalue()


def view_files(views: list[SceneView]) -> dict[str, bytes]:
    """A scene's views as files (name -> bytes): ``vVV_depth.png`` (uint16 mm), ``vVV_color.png``,
    ``vVV_segmentation.png`` (uint8) and ``cameras.parquet`` (one :meth:`SceneView.camera_row` per
    view, with the image names)."""
    files: dict[str, bytes] = {}
    rows = []
    for view in views:
        stem = f"v{view.view_id:02d}"
        row = view.camera_row()
        files[f"{stem}_depth.png"] = _png(kinect.depth_to_png_array(view.depth))
        files[f"{stem}_segmentation.png"] = _png(view.segmentation)
        row["depth_file"] = f"{stem}_depth.png"
        row["segmentation_file"] = f"{stem}_segmentation.png"
        if view.color is not None:
            files[f"{stem}_color.png"] = _png(view.color)
            row["color_file"] = f"{stem}_color.png"
        rows.append(row)
    buffer = io.BytesIO()
    pd.DataFrame(rows).to_parquet(buffer, index=False)
    files["cameras.parquet"] = buffer.getvalue()
    return files


def write_views(folder: Path | str, views: list[SceneView]) -> list[Path]:
    """Write :func:`view_files` into ``folder`` (created); the paths written."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, data in view_files(views).items():
        (folder / name).write_bytes(data)
        paths.append(folder / name)
    return paths


def _intrinsics(row: pd.Series, prefix: str = "") -> Intrinsics:
    w, h, fx, fy, cx, cy = (row[f"{prefix}{c}"] for c in INTRINSIC_COLUMNS)
    return Intrinsics(int(w), int(h), float(fx), float(fy), float(cx), float(cy))


def read_views(folder: Path | str) -> list[SceneView]:
    """The views of :func:`write_views` back (depth at the PNG's millimetre resolution)."""
    from PIL import Image

    folder = Path(folder)
    cameras = pd.read_parquet(folder / "cameras.parquet").sort_values("view_id", ignore_index=True)

    def image(name: object) -> np.ndarray:
        with Image.open(folder / str(name)) as im:
            return np.asarray(im)

    views = []
    for _, row in cameras.iterrows():
        pose = [float(row[c]) for c in CAMERA_POSE_COLUMNS]
        has_color = "color_file" in row and isinstance(row["color_file"], str)
        views.append(
            SceneView(
                int(row["scene_id"]),
                int(row["view_id"]),
                Transform.exact(pose[:3], pose[3:]),
                _intrinsics(row),
                kinect.read_depth_png(folder / str(row["depth_file"])),
                image(row["segmentation_file"]),
                _intrinsics(row, "color_") if has_color else None,
                image(row["color_file"]) if has_color else None,
            )
        )
    return views
