"""Reading the Kinect views of ``annotate --cell --views K`` back: images, cameras, labels in them.

The files need nothing of this package (any PNG and Parquet reader opens them)::

    OUT/_views/<object stem>/pPP_vVV_depth.png          uint16, millimetres along the optical axis,
                                                        0 = no measurement (outside 0.5-4.5 m)
    OUT/_views/<object stem>/pPP_vVV_color.png          RGB, same optical frame
    OUT/_views/<object stem>/pPP_vVV_segmentation.png   uint8: 0 nothing, 1 table, 2 object, 3 robot
    OUT/_views/<object stem>/pPP_cameras.parquet        one row per view of placement PP

A camera row: ``object_id placement_id view_id``; ``depth color segmentation`` (file paths relative
to OUT); the depth intrinsics ``width height fx fy cx cy`` and the colour ones ``color_*`` (pixel
(u, v) sees the ray ((u - cx) / fx, (v - cy) / fy, 1)); the camera's optical frame in the world
``x y z qx qy qz qw`` (+z forward, +x right, +y down in the image; quaternion xyzw); the object's
mesh frame in the world ``obj_x .. obj_qw`` (as in the label rows of that placement).

:func:`load_cameras` gathers every camera row; :func:`open_view` reads one view into a
:class:`View`, whose helpers give the point cloud in the camera frame and the placement's labels
transformed into it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from annotator.cell.kinect import DEPTH_PNG_SCALE, Intrinsics, point_cloud, project
from annotator.dataset import poses_as_matrices
from annotator.geometry import Transform
from annotator.store.names import ARTIFACTS_DIR

# Segmentation image values: what a learner needs, not PyBullet body ids.
SEG_NOTHING, SEG_TABLE, SEG_OBJECT, SEG_ROBOT = 0, 1, 2, 3
SEGMENTATION_CLASSES = {SEG_NOTHING: "nothing", SEG_TABLE: "table", SEG_OBJECT: "object", SEG_ROBOT: "robot"}
CAMERA_POSE_COLUMNS = ("x", "y", "z", "qx", "qy", "qz", "qw")
OBJECT_POSE_COLUMNS = ("obj_x", "obj_y", "obj_z", "obj_qx", "obj_qy", "obj_qz", "obj_qw")


def load_cameras(out_dir: str | Path) -> pd.DataFrame:
    """Every view's camera row in ``out_dir`` (a labels folder), sorted by object, placement, view.

    An empty table when the run rendered no views.
    """
    paths = sorted((Path(out_dir) / ARTIFACTS_DIR).glob("*/p*_cameras.parquet"))
    if not paths:
        return pd.DataFrame()
    cameras = pd.concat([pd.read_parquet(p) for p in paths], ignore_index=True)
    return cameras.sort_values(["object_id", "placement_id", "view_id"], ignore_index=True)


def _pose(row: pd.Series, columns: tuple[str, ...]) -> Transform:
    values = [float(row[c]) for c in columns]
    return Transform(values[:3], values[3:])


@dataclass(frozen=True)
class View:
    """One view as written: ``depth`` (h, w) float32 m (0 = no measurement), ``color`` (H, W, 3)
    uint8, ``segmentation`` (h, w) uint8 (SEGMENTATION_CLASSES), the intrinsics, the camera's
    optical frame and the object's mesh frame in the world."""

    camera: pd.Series
    depth: np.ndarray
    color: np.ndarray
    segmentation: np.ndarray
    depth_K: Intrinsics
    color_K: Intrinsics
    T_world_camera: Transform
    T_world_obj: Transform

    def point_cloud(self, organized: bool = False) -> np.ndarray:
        """Camera-frame points of the depth image: (n, 3) valid pixels, or (h, w, 3) with NaN."""
        return point_cloud(self.depth, self.depth_K, organized)

    def labels_in_camera(self, labels: pd.DataFrame) -> tuple[pd.DataFrame, np.ndarray]:
        """This placement's label rows and their TCP poses in the camera frame, (n, 4, 4).

        ``labels``: a label table (``pandas.read_parquet(OUT)``); the rows of this view's object and
        placement are kept, in their order. ``T_camera_tcp = T_world_camera^-1 T_world_obj T_obj_tcp``.
        """
        oid, placement = self.camera["object_id"], int(self.camera["placement_id"])
        rows = labels[(labels["object_id"] == oid) & (labels["placement_id"] == placement)]
        T_camera_obj = (self.T_world_camera.inverse() * self.T_world_obj).as_matrix()
        return rows, np.einsum("ij,njk->nik", T_camera_obj, poses_as_matrices(rows))

    def project(self, points_camera: np.ndarray, color: bool = False) -> np.ndarray:
        """Pixels (n, 2) (u column, v row) of camera-frame points (n, 3), in the depth image (or
        the colour image, which has the same optical frame)."""
        return project(points_camera, self.color_K if color else self.depth_K)


def open_view(out_dir: str | Path, camera: pd.Series) -> View:
    """Read the view of a camera row (from :func:`load_cameras`) from ``out_dir``."""
    from PIL import Image

    out = Path(out_dir)

    def read(column: str) -> np.ndarray:
        with Image.open(out / str(camera[column])) as image:
            return np.asarray(image)

    depth = (read("depth").astype(np.float64) / DEPTH_PNG_SCALE).astype(np.float32)
    K = [camera[c] for c in ("width", "height", "fx", "fy", "cx", "cy")]
    cK = [camera[f"color_{c}"] for c in ("width", "height", "fx", "fy", "cx", "cy")]
    return View(
        camera=camera,
        depth=depth,
        color=read("color"),
        segmentation=read("segmentation"),
        depth_K=Intrinsics(int(K[0]), int(K[1]), *map(float, K[2:])),
        color_K=Intrinsics(int(cK[0]), int(cK[1]), *map(float, cK[2:])),
        T_world_camera=_pose(camera, CAMERA_POSE_COLUMNS),
        T_world_obj=_pose(camera, OBJECT_POSE_COLUMNS),
    )
