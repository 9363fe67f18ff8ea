"""Scenes and their grasps in VGN's files (ethz-asl/vgn, branch corl2020).

Two layouts, both as VGN's own scripts write them:

- *raw* (``scripts/generate_data.py`` via ``src/vgn/io.py``)::

      ROOT/setup.json           {"size", "intrinsic": {"width", "height", "K"}, "max_opening_width",
                                 "finger_depth"}
      ROOT/grasps.csv           scene_id,qx,qy,qz,qw,x,y,z,width,label   (one line per grasp)
      ROOT/scenes/<id>.npz      depth_imgs (n, H, W) float32 m; extrinsics (n, 7) float32
                                [qx, qy, qz, qw, x, y, z] of T_camera_task

  VGN's ``construct_dataset.py`` turns it into the dataset below (it needs Open3D).
- *dataset* (``scripts/construct_dataset.py``, read by ``src/vgn/dataset.py``)::

      ROOT/grasps.csv           scene_id,qx,qy,qz,qw,i,j,k,width,label   (x, y, z, width / voxel)
      ROOT/scenes/<id>.npz      grid (1, 40, 40, 40) float32: VGN's TSDF grid
                                (:meth:`annotator.scenes.tsdf.TSDFVolume.vgn_grid`)

Frames. VGN's *task frame* is the workspace cube's lower corner (the table top s/6 above it, axes
of the table): :attr:`annotator.scenes.Workspace.T_table_task`. VGN's grasp frame has its fingers
closing along **y** and approaching along z, and its origin at the **palm**: the fingertips reach
``finger_depth`` (0.05 m) beyond it along z (its simulated hand is placed so, its grasp sampler
puts the origin 0 to 5 cm out of the surface, its markers draw the fingers from the origin to
``finger_depth``). Ours closes along x and sits between the pads. A grasp is written as our TCP
moved along its approach to where VGN's palm would be, the fingertips ``finger_depth`` behind
the gripper's own fingertips at the grasp's opening (:attr:`VgnSetup.fingertip`, from the
gripper's collision model), turned -90 degrees about its z so that VGN's y is our closing axis:
``T_task_vgn = T_task_table T_table_tcp Tz(reach(width) - finger_depth) Rz(-90 deg)``. For the
shipped Panda the reach is 9.25 mm, so VGN's origin is 40.75 mm behind our TCP. ``width`` is the
opening (m); ``label`` 1 for a success, 0 otherwise.

Cleaning (:func:`vgn_clean`, ``annotator export --format vgn --balance``): VGN's data notebook
(``notebooks/data.ipynb``) cleans the raw grasps before ``construct_dataset.py``: it drops grasps
whose position lies within 0.02 m of the workspace cube's sides, then drops negatives at random
until they are as many as the positives. Without it VGN's network trains on the raw balance (a
pile's labels are mostly failures) and rates few voxels above its detection threshold of 0.9.

Workspace. VGN's grids have ``DATASET_RESOLUTION`` = 40 voxels a side over the cube, and its
``Dataset`` indexes them at ``round(i, j, k)`` (float32): a grasp whose index falls outside
[0, 40) would be written at the opposite side of the grid by VGN's training (a negative index)
or raise IndexError. Such grasps (a TCP outside the cube, on objects leaning over its edge) are
left out of both layouts (:func:`inside_grid`); VGN's own generator never writes one.

Scene ids in the files are ``scene_NNNNNN``: VGN reads ``scene_id`` with ``pandas.read_csv`` and
appends ``.npz``, so an id pandas would parse as a number must not be used.

``setup.json``'s ``finger_depth``: VGN's dataset step asserts ``size == 6 * finger_depth`` and uses
it for nothing else; the writer is given it (default ``size / 6``).
"""

from __future__ import annotations

import io
import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from annotator.cell.kinect import Intrinsics
from annotator.geometry import Transform, axis_angle_to_matrix, matrix_to_quat
from annotator.scenes.records import SceneRecord
from annotator.scenes.tsdf import fuse
from annotator.tools.export import Writer, fill_bytes, write_atomically

RAW_COLUMNS = ("scene_id", "qx", "qy", "qz", "qw", "x", "y", "z", "width", "label")
DATASET_COLUMNS = ("scene_id", "qx", "qy", "qz", "qw", "i", "j", "k", "width", "label")
DATASET_RESOLUTION = 40  # construct_dataset.py's RESOLUTION
CLEAN_MARGIN = 0.02  # m: VGN's data notebook drops positions within this of the cube's sides
# Our TCP frame (x closing, z approach) -> VGN's grasp frame (y closing, z approach): Rz(-90 deg).
T_TCP_VGN = np.eye(4)
T_TCP_VGN[:3, :3] = axis_angle_to_matrix(np.array([0.0, 0.0, 1.0]), -math.pi / 2)


def scene_name(scene_id: int) -> str:
    """The scene's id in VGN's files (not numeric: VGN appends ".npz" to what read_csv gives)."""
    return f"scene_{int(scene_id):06d}"


@dataclass(frozen=True)
class VgnSetup:
    """``setup.json``: workspace ``size`` (m), the depth camera's intrinsics, the gripper's
    ``max_opening_width`` (m) and ``finger_depth`` (m; VGN asserts size == 6 x finger_depth).

    ``fingertip``: how far the gripper's fingertips reach beyond our TCP along its approach (+z)
    at each opening, ``fingertip(width (n,) m) -> (n,) m`` (:func:`fingertip_reach`); VGN's grasp
    origin is ``finger_depth`` behind them. None: the grasps are written at our TCP unmoved (a
    gripper whose TCP already is VGN's palm)."""

    size: float
    intrinsic: Intrinsics
    max_opening_width: float
    finger_depth: float | None = None
    fingertip: Callable[[np.ndarray], np.ndarray] | None = None

    @property
    def depth(self) -> float:
        """VGN's finger depth (m): ``finger_depth``, else size / 6."""
        return float(self.size / 6 if self.finger_depth is None else self.finger_depth)

    def offset(self, width: np.ndarray) -> np.ndarray:
        """(n,) m: where VGN's grasp origin lies on our TCP's z axis for openings ``width`` (n,) m:
        the fingertips' reach less VGN's finger depth (negative: behind the TCP)."""
        width = np.asarray(width, dtype=np.float64).reshape(-1)
        if self.fingertip is None:
            return np.zeros(len(width))
        return np.asarray(self.fingertip(width), dtype=np.float64).reshape(-1) - self.depth

    def to_json(self) -> dict:
        K = self.intrinsic
        return {
            "size": float(self.size),
            "intrinsic": {
                "width": int(K.width),
                "height": int(K.height),
                "K": [float(v) for v in K.K.reshape(-1)],
            },
            "max_opening_width": float(self.max_opening_width),
            "finger_depth": self.depth,
        }


@dataclass(frozen=True)
class SceneGrasps:
    """A scene's grasps for export: ``T_table_tcp`` (n, 4, 4) TCP poses (our TCP frame) in the
    table frame, ``width`` (n,) m, ``success`` (n,) bool; ``instance_id`` and ``grasp_id`` (n,) int
    say which object and label each is."""

    scene_id: int
    T_table_tcp: np.ndarray
    width: np.ndarray
    success: np.ndarray
    instance_id: np.ndarray
    grasp_id: np.ndarray

    def take(self, mask: np.ndarray) -> SceneGrasps:
        """The grasps where ``mask`` : (n,) bool is true, in order."""
        mask = np.asarray(mask, dtype=bool)
        return SceneGrasps(
            self.scene_id,
            np.asarray(self.T_table_tcp).reshape(-1, 4, 4)[mask],
            np.asarray(self.width)[mask],
            np.asarray(self.success)[mask],
            np.asarray(self.instance_id)[mask],
            np.asarray(self.grasp_id)[mask],
        )


def tcp_to_vgn(offset: np.ndarray | float) -> np.ndarray:
    """(n, 4, 4) ``T_tcp_vgn``: VGN's grasp frame in our TCP frame, its origin ``offset`` (n,) m
    along our z (:meth:`VgnSetup.offset`), its y our closing x."""
    offset = np.atleast_1d(np.asarray(offset, dtype=np.float64))
    T = np.tile(T_TCP_VGN, (len(offset), 1, 1))
    T[:, 2, 3] = offset
    return T


def task_poses(record: SceneRecord, grasps: SceneGrasps, offset: np.ndarray | None = None) -> np.ndarray:
    """VGN grasp frames (n, 4, 4) in the task frame of ``record``'s workspace; ``offset`` (n,) m
    where VGN's origin lies on our TCP's z (:meth:`VgnSetup.offset`; None: at the TCP)."""
    T_task_table = record.workspace.T_table_task.inverse().as_matrix()
    T_table_tcp = np.asarray(grasps.T_table_tcp, dtype=np.float64).reshape(-1, 4, 4)
    offset = np.zeros(len(T_table_tcp)) if offset is None else np.asarray(offset, dtype=np.float64)
    return T_task_table @ T_table_tcp @ tcp_to_vgn(offset).reshape(-1, 4, 4)


def voxel_indices(
    record: SceneRecord,
    grasps: SceneGrasps,
    size: float,
    resolution: int = DATASET_RESOLUTION,
    offset: np.ndarray | None = None,
) -> np.ndarray:
    """(n, 3) int: each grasp's voxel as VGN's ``Dataset`` computes it from the dataset layout
    (the position in voxels of ``size / resolution``, read as float32, rounded)."""
    position = task_poses(record, grasps, offset)[:, :3, 3] / (size / resolution)
    return np.round(position.astype(np.float32)).astype(np.int64)


def inside_grid(
    record: SceneRecord,
    grasps: SceneGrasps,
    size: float,
    resolution: int = DATASET_RESOLUTION,
    offset: np.ndarray | None = None,
) -> np.ndarray:
    """(n,) bool: the grasp's voxel index (:func:`voxel_indices`) lies in [0, resolution) on
    every axis, i.e. VGN's training can read its label from the grid."""
    index = voxel_indices(record, grasps, size, resolution, offset)
    return np.all((index >= 0) & (index < resolution), axis=1)


def vgn_clean(
    positions: np.ndarray, labels: np.ndarray, size: float, *, balance: bool = True, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """VGN's data notebook's cleanup of the raw grasps (module docstring): ``positions`` (n, 3) m
    in the task frame (VGN's grasp origins), ``labels`` (n,) 0/1. Returns (``near_side``, ``dropped``),
    (n,) bool each: the grasps within CLEAN_MARGIN of the cube's sides, and the negatives of the
    rest dropped at random (a generator keyed on ``seed``) to leave as many as the positives
    (none when ``balance`` is false or the negatives are fewer)."""
    from annotator.rng import keyed_rng

    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    labels = np.asarray(labels).astype(bool).reshape(-1)
    near_side = np.any((positions < CLEAN_MARGIN) | (positions > size - CLEAN_MARGIN), axis=1)
    dropped = np.zeros(len(labels), dtype=bool)
    if balance:
        negatives = np.flatnonzero(~near_side & ~labels)
        excess = len(negatives) - int(np.sum(~near_side & labels))
        if excess > 0:
            dropped[keyed_rng("vgn-balance", int(seed)).choice(negatives, excess, replace=False)] = True
    return near_side, dropped


def grasp_rows(record: SceneRecord, grasps: SceneGrasps, offset: np.ndarray | None = None) -> pd.DataFrame:
    """The scene's lines of the raw ``grasps.csv`` (RAW_COLUMNS); ``offset`` as :func:`task_poses`."""
    T = task_poses(record, grasps, offset)
    q = matrix_to_quat(T[:, :3, :3]).reshape(-1, 4)
    df = pd.DataFrame(
        {
            "scene_id": scene_name(record.scene_id),
            "qx": q[:, 0],
            "qy": q[:, 1],
            "qz": q[:, 2],
            "qw": q[:, 3],
            "x": T[:, 0, 3],
            "y": T[:, 1, 3],
            "z": T[:, 2, 3],
            "width": np.asarray(grasps.width, dtype=np.float64),
            "label": np.asarray(grasps.success, dtype=bool).astype(np.int64),
        }
    )
    return df[list(RAW_COLUMNS)]


def extrinsics(record: SceneRecord, views) -> np.ndarray:
    """(n, 7) float32 ``[qx, qy, qz, qw, x, y, z]`` of ``T_camera_task`` for each view."""
    out = np.empty((len(views), 7), np.float32)
    T_table_task = record.workspace.T_table_task
    for i, view in enumerate(views):
        T = view.T_table_camera.inverse() * T_table_task
        out[i] = np.r_[T.quat, T.pos]
    return out


def _csv_text(df: pd.DataFrame) -> str:
    """``df`` as VGN writes its CSV: a header, then ``",".join(str(value))`` per line."""
    lines = [",".join(df.columns)]
    for row in df.itertuples(index=False):
        lines.append(",".join(str(v.item() if isinstance(v, np.generic) else v) for v in row))
    return "\n".join(lines) + "\n"


def _npz_bytes(**arrays: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    return buffer.getvalue()


def _bytes_writer(write: Writer) -> Callable[[Path, bytes], object]:
    """``write`` (a :data:`annotator.tools.export.Writer`) of bytes."""
    return lambda path, data: write(path, fill_bytes(data))


def write_vgn_raw(
    root: Path | str,
    setup: VgnSetup,
    scenes: list[tuple[SceneRecord, list, SceneGrasps]],
    write: Writer = write_atomically,
) -> list[Path]:
    """Write the raw layout: ``setup.json``, ``grasps.csv`` (every scene's grasps inside the
    workspace grid (:func:`inside_grid`), in scene order) and ``scenes/<id>.npz`` per scene.
    ``scenes``: (record, its views, its grasps); ``write``: how a file is written (an export's
    folder's writer). Returns the paths."""
    _write = _bytes_writer(write)
    root = Path(root)
    paths = [root / "setup.json", root / "grasps.csv"]
    _write(paths[0], (json.dumps(setup.to_json(), indent=4) + "\n").encode())
    rows = []
    for record, views, grasps in sorted(scenes, key=lambda s: s[0].scene_id):
        if grasps.scene_id != record.scene_id:
            raise ValueError(f"grasps of scene {grasps.scene_id} given with scene {record.scene_id}")
        depth = (
            np.stack([np.asarray(v.depth, dtype=np.float32) for v in views]) if views else np.zeros((0, 0, 0))
        )
        path = root / "scenes" / f"{scene_name(record.scene_id)}.npz"
        _write(path, _npz_bytes(depth_imgs=depth.astype(np.float32), extrinsics=extrinsics(record, views)))
        paths.append(path)
        kept = grasps.take(inside_grid(record, grasps, setup.size, offset=setup.offset(grasps.width)))
        rows.append(grasp_rows(record, kept, setup.offset(kept.width)))
    table = pd.concat(rows, ignore_index=True) if rows else pd.DataFrame(columns=list(RAW_COLUMNS))
    _write(paths[1], _csv_text(table).encode())
    return paths


def write_vgn_dataset(
    root: Path | str,
    setup: VgnSetup,
    scenes: list[tuple[SceneRecord, list, SceneGrasps]],
    resolution: int = DATASET_RESOLUTION,
    write: Writer = write_atomically,
) -> list[Path]:
    """Write the dataset layout VGN trains on: ``grasps.csv`` in voxel units (the grasps inside
    the grid, :func:`inside_grid`) and each scene's TSDF grid (1, r, r, r) fused from its views
    (:mod:`annotator.scenes.tsdf`, VGN's conventions). ``write``: as :func:`write_vgn_raw`."""
    _write = _bytes_writer(write)
    root = Path(root)
    voxel = setup.size / resolution
    paths = [root / "grasps.csv"]
    rows = []
    for record, views, grasps in sorted(scenes, key=lambda s: s[0].scene_id):
        volume = fuse(views, setup.size, resolution, record.workspace.T_table_task)
        path = root / "scenes" / f"{scene_name(record.scene_id)}.npz"
        _write(path, _npz_bytes(grid=volume.vgn_grid()[None].astype(np.float32)))
        paths.append(path)
        inside = inside_grid(record, grasps, setup.size, resolution, setup.offset(grasps.width))
        kept = grasps.take(inside)
        df = grasp_rows(record, kept, setup.offset(kept.width))
        for c in ("x", "y", "z", "width"):
            df[c] = df[c] / voxel
        rows.append(df.rename(columns={"x": "i", "y": "j", "z": "k"}))
    table = pd.concat(rows, ignore_index=True) if rows else pd.DataFrame(columns=list(DATASET_COLUMNS))
    _write(paths[0], _csv_text(table[list(DATASET_COLUMNS)]).encode())
    return paths


# --- reading back (what VGN's io.py and dataset.py do, without Open3D or torch) -----------------------


def read_setup(root: Path | str) -> dict:
    """``setup.json`` as VGN's ``read_setup`` reads it: size, intrinsics (width, height, fx, fy, cx,
    cy from K), max_opening_width, finger_depth."""
    data = json.loads((Path(root) / "setup.json").read_text())
    K = data["intrinsic"]["K"]
    intrinsic = Intrinsics(data["intrinsic"]["width"], data["intrinsic"]["height"], K[0], K[4], K[2], K[5])
    return {
        "size": data["size"],
        "intrinsic": intrinsic,
        "max_opening_width": data["max_opening_width"],
        "finger_depth": data["finger_depth"],
    }


def read_grasps(root: Path | str) -> pd.DataFrame:
    """``grasps.csv`` as VGN's ``read_df``: ``pandas.read_csv``."""
    return pd.read_csv(Path(root) / "grasps.csv")


def read_sensor_data(root: Path | str, scene_id: str) -> tuple[np.ndarray, np.ndarray]:
    """A raw scene's ``(depth_imgs, extrinsics)`` as VGN's ``read_sensor_data``."""
    data = np.load(Path(root) / "scenes" / (scene_id + ".npz"))
    return data["depth_imgs"], data["extrinsics"]


def read_grid(root: Path | str, scene_id: str) -> np.ndarray:
    """A dataset scene's grid as VGN's ``read_voxel_grid``: (1, r, r, r) float32."""
    return np.load(Path(root) / "scenes" / (scene_id + ".npz"))["grid"]


def grasp_in_task(row: pd.Series) -> tuple[Transform, float, int]:
    """One raw row as VGN's ``read_grasp``: the grasp frame in the task frame (quaternion columns
    qx..qw, position x..z, by column order), width and label."""
    q = row.loc["qx":"qw"].to_numpy(np.double)
    p = row.loc["x":"z"].to_numpy(np.double)
    return Transform(p, q), float(row["width"]), int(row["label"])


def tcp_in_table(T_task_vgn: np.ndarray, record: SceneRecord, offset: float = 0.0) -> np.ndarray:
    """Our TCP pose (4, 4) in the table frame from a VGN grasp frame in the task frame, VGN's
    origin ``offset`` m along our TCP's z (:meth:`VgnSetup.offset` at the grasp's width)."""
    T_tcp_vgn = tcp_to_vgn(offset)[0]
    return record.workspace.T_table_task.as_matrix() @ np.asarray(T_task_vgn) @ np.linalg.inv(T_tcp_vgn)


def fingertip_reach(gripper=None) -> Callable[[np.ndarray], np.ndarray]:
    """``reach(width (n,) m) -> (n,) m``: how far ``gripper``'s fingertips (the farthest point of
    its collision boxes) lie beyond its TCP along the approach (+z) at each opening, from the
    model's own kinematics (:mod:`annotator.policies.gripper_boxes`); default the RG2."""
    from annotator.policies.gripper_boxes import box_corners, gripper_boxes

    boxes = gripper_boxes(gripper)

    def reach(width: np.ndarray) -> np.ndarray:
        width = np.asarray(width, dtype=np.float64).reshape(-1)
        out = np.empty(len(width))
        for k, w in enumerate(width):
            w = min(max(float(w), 0.0), boxes.max_width)
            out[k] = box_corners(boxes.at(w, w))[:, 2].max()
        return out

    return reach
