"""``--format vgn``: a scene run in VGN's raw layout (``setup.json``, ``grasps.csv``,
``scenes/scene_NNNNNN.npz``: what its ``generate_data.py`` writes, every grasp inside the workspace
cube with its label), the dataset its ``construct_dataset.py`` makes from it in ``dataset/`` (TSDF
grids of 40³ fused from the scene's views) and what GIGA reads beside them (``meshes/``,
``mesh_pose_list/``: :mod:`annotator.tools.export_giga`). It needs the scenes' depth images (a run
made with ``--views``); ``--balance`` cleans the grasps as VGN's data notebook does."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from annotator.tools.formats import Exporter

if TYPE_CHECKING:
    from annotator.tools.export import ExportFolder, LeftOut, TcpDepth
    from annotator.tools.scene_labels import SceneLabels


def write_vgn(
    scenes: SceneLabels, items, folder: ExportFolder, depth: TcpDepth, objects_dir, balance: bool = False
) -> tuple[list[Path], list[LeftOut]]:
    from annotator.tools.common import ToolError
    from annotator.tools.export import LeftOut  # noqa: F811  (the records, made here)
    from annotator.tools.export_cgn import mesh_file, write_meshes
    from annotator.tools.export_giga import MESH_POSE_LIST, write_mesh_pose_lists
    from annotator.tools.export_scenes import kept_meshes
    from annotator.tools.export_vgn import (
        CLEAN_MARGIN,
        DATASET_RESOLUTION,
        VgnSetup,
        fingertip_reach,
        inside_grid,
        scene_name,
        task_poses,
        vgn_clean,
        write_vgn_dataset,
        write_vgn_raw,
    )

    missing = [record.scene_id for record, views, _ in items if not views]
    if missing:
        raise ToolError(
            f"{scenes.path}: scene {missing[0]} has no views, and VGN's files are depth images with "
            "grasps; label the scenes with --views K (VGN renders 1 to 6 per scene)"
        )
    if not items:
        raise ToolError(f"{scenes.path}: no scene to export")
    size = items[0][0].workspace.size
    setup = VgnSetup(
        size, items[0][1][0].depth_K, depth.max_width, fingertip=fingertip_reach(depth.description)
    )
    inside = [inside_grid(r, g, size, offset=setup.offset(g.width)) for r, _, g in items]
    outside = sum(int(np.sum(~m)) for m in inside)
    items = [(r, v, g.take(m)) for (r, v, g), m in zip(items, inside, strict=True)]
    near_side = dropped = 0
    if balance:
        positions = [task_poses(r, g, setup.offset(g.width))[:, :3, 3] for r, _, g in items]
        labels = [np.asarray(g.success, dtype=bool) for _, _, g in items]
        side, drop = vgn_clean(np.concatenate(positions), np.concatenate(labels), size)
        near_side, dropped = int(side.sum()), int(drop.sum())
        keep = np.split(~side & ~drop, np.cumsum([len(p) for p in positions])[:-1])
        items = [(r, v, g.take(k)) for (r, v, g), k in zip(items, keep, strict=True)]
    meshes = kept_meshes(scenes, items, objects_dir)
    names = ["setup.json", "grasps.csv", "dataset/grasps.csv", *(mesh_file(oid) for oid in meshes)]
    for record, _, _ in items:
        names += [
            f"scenes/{scene_name(record.scene_id)}.npz",
            f"dataset/scenes/{scene_name(record.scene_id)}.npz",
            f"{MESH_POSE_LIST}/{scene_name(record.scene_id)}.npz",
        ]
    for name in names:  # refuses before anything is written if a file it did not write is there
        folder.target(name)
    write = folder.write_path
    paths = write_vgn_raw(folder.path, setup, items, write)
    paths += write_vgn_dataset(folder.path / "dataset", setup, items, write=write)
    write_meshes(folder.path, meshes, write)  # GIGA's mesh_pose_list names them
    paths += [folder.path / mesh_file(oid) for oid in meshes]
    mesh_paths = {oid: str((folder.path / mesh_file(oid)).resolve()) for oid in meshes}
    paths += write_mesh_pose_lists(folder.path, [record for record, _, _ in items], mesh_paths, write)
    reason = (
        f"outside the {size:g} m workspace cube (voxel index outside [0, {DATASET_RESOLUTION}), "
        "where VGN's training cannot read a label)"
    )
    left_out = [LeftOut(outside, reason)]
    if balance:
        left_out += [
            LeftOut(
                near_side, f"within {CLEAN_MARGIN:g} m of the workspace cube's sides (VGN's data cleanup)"
            ),
            LeftOut(dropped, "negatives dropped at random to leave as many as the positives (VGN's balance)"),
        ]
    return paths, left_out


HELP = "VGN's grasps.csv and scenes/*.npz, its dataset/, GIGA's mesh_pose_list/; needs --views"
FOLDERS = ("scenes", "dataset/scenes", "dataset", "mesh_pose_list", "meshes")
EXPORTER = Exporter("vgn", "scene", HELP, 2, FOLDERS, balance=True, write_scenes=write_vgn)
