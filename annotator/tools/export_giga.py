"""What GIGA (UT-Austin-RPL/GIGA) reads beside VGN's raw layout: each scene's ``mesh_pose_list``.

GIGA's data generation (``scripts/generate_data_parallel.py --save-scene``) writes, per scene,
``ROOT/mesh_pose_list/<scene_id>.npz`` with one key, ``pc``: the scene's objects as a list of
``(mesh path, scale, pose)`` (``vgn.utils.implicit.get_mesh_pose_list_from_world``), saved with
``np.savez_compressed`` and so stored as a (k, 3) object array. Its readers
(``vgn/dataset_voxel.py``, ``scripts/save_occ_data_parallel.py``) load it with
``np.load(path, allow_pickle=True)["pc"]`` and rebuild the scene with
``get_scene_from_mesh_pose_list``: for each row ``trimesh.load(mesh path)``, ``apply_scale(scale)``,
``apply_transform(pose)``; its occupancy targets are sampled from that scene.

Here, per scene of a VGN export (``scene_id`` as in its ``grasps.csv``):

- mesh path: the object's mesh written once to ``ROOT/meshes/<object>.obj`` (metres, the mesh
  frame the labels use), given as an **absolute** path: GIGA loads it as given, relative to its
  own working directory, so the export is read from anywhere but not after it is moved (export
  again to a new place);
- scale: 1.0 (the mesh is in metres at the labels' scale);
- pose: ``T_task_obj`` (4, 4), the mesh frame in VGN's task frame (the world frame of VGN's and
  GIGA's simulation: the workspace cube's lower corner, table s/6 above it).
"""

from __future__ import annotations

import io
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from annotator.scenes.records import SceneRecord
from annotator.tools.export import Writer, fill_bytes, write_atomically

MESH_POSE_LIST = "mesh_pose_list"  # GIGA's folder name


def mesh_pose_list(record: SceneRecord, mesh_paths: Mapping[str, str]) -> np.ndarray:
    """(k, 3) object array, one row ``(mesh path, 1.0, T_task_obj (4, 4))`` per kept instance in
    instance order; ``mesh_paths``: object id -> the path GIGA loads."""
    T_task_table = record.workspace.T_table_task.inverse().as_matrix()
    kept = record.kept
    out = np.empty((len(kept), 3), dtype=object)
    for row, inst in enumerate(kept):
        out[row, 0] = str(mesh_paths[inst.object_id])
        out[row, 1] = 1.0
        out[row, 2] = T_task_table @ inst.T_table_obj.as_matrix()
    return out


def write_mesh_pose_lists(
    root: Path | str,
    records: list[SceneRecord],
    mesh_paths: Mapping[str, str],
    write: Writer = write_atomically,
) -> list[Path]:
    """``ROOT/mesh_pose_list/<scene name>.npz`` per record (key ``pc``, as GIGA writes it);
    ``write``: how a file is written (an export's folder's writer)."""
    from annotator.tools.export_vgn import scene_name

    root = Path(root)
    paths = []
    for record in sorted(records, key=lambda r: r.scene_id):
        buffer = io.BytesIO()
        np.savez_compressed(buffer, pc=mesh_pose_list(record, mesh_paths))
        data = buffer.getvalue()
        path = root / MESH_POSE_LIST / f"{scene_name(record.scene_id)}.npz"
        write(path, fill_bytes(data))
        paths.append(path)
    return paths
