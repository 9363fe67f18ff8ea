"""``annotator export --format vgn | contact_graspnet``: the labels of a scene run in the files of
VGN (:mod:`annotator.tools.export_vgn`) or Contact-GraspNet (:mod:`annotator.tools.export_cgn`).

- ``vgn``: VGN's raw layout in OUT (``setup.json``, ``grasps.csv``, ``scenes/scene_NNNNNN.npz``: what
  its ``generate_data.py`` writes, every grasp inside the workspace cube with its label) and the
  dataset its ``construct_dataset.py`` makes from it in ``OUT/dataset/`` (TSDF grids of 40³ fused
  from the scene's views), plus what GIGA reads beside them: ``meshes/`` and
  ``mesh_pose_list/scene_NNNNNN.npz`` (:mod:`annotator.tools.export_giga`). Both need the scenes'
  depth images: the run must have been made with ``--views``. Grasps outside the cube are left
  out and counted (:func:`annotator.tools.export_vgn.inside_grid`).
- ``contact_graspnet``: ``meshes/``, ``scene_contacts/NNNNNN.npz`` per scene (its positives: the
  successes, as the gripper's base pose, with their contacts on the mesh; a success without two
  is left out and counted) and, when the run has views, ``views/NNNNNN_VV.npz`` (its inference
  input).

The files an export writes are recorded in the folder's ``_export.json`` (as every export's), so
``--overwrite`` removes exactly those; so are the grasps it left out, and why.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from annotator.store.names import is_scene_unit
from annotator.tools.common import ToolError
from annotator.tools.export import ExportFolder, ExportResult, LeftOut, TcpDepth
from annotator.tools.scene_labels import SceneLabels, open_scene_labels

log = logging.getLogger(__name__)

SCENE_FORMATS = ("vgn", "contact_graspnet")


def export_scenes(
    labels_dir: Path,
    fmt: str,
    out_dir: Path,
    objects_dir: Path | None = None,
    *,
    overwrite: bool = False,
    partial: bool = False,
    balance: bool = False,
) -> ExportResult:
    """Write the scene run in ``labels_dir`` to ``out_dir`` in ``fmt`` (module docstring). A run
    that is unfinished or in which a scene failed is refused unless ``partial``. ``balance``
    (VGN only): VGN's data notebook's cleanup (:func:`annotator.tools.export_vgn.vgn_clean`)."""
    if balance and fmt != "vgn":
        raise ToolError("--balance is VGN's data cleanup: it applies to --format vgn only")
    if fmt not in SCENE_FORMATS:
        raise ToolError(f"unknown scene format {fmt!r}; choose from {', '.join(SCENE_FORMATS)}")
    scenes = open_scene_labels(labels_dir, f"export --format {fmt}")
    if not partial:
        scenes.run.require_finished("export")
        _require_no_failed_scene(scenes)
    with ExportFolder.open(Path(out_dir), overwrite=overwrite) as folder:
        depth = TcpDepth(scenes.gripper)
        ids = scenes.scene_ids()
        items = [(scenes.records[s], scenes.views(s), scenes.grasps(s)) for s in ids]
        if fmt == "vgn":
            files, left_out = _vgn(scenes, items, folder, depth, objects_dir, balance)
        else:
            files, left_out = _cgn(scenes, items, folder, depth, objects_dir)
        folder.close(fmt, Path(labels_dir), left_out)
    n = sum(len(g.width) for _, _, g in items) - sum(x.grasps for x in left_out)
    log.info("exported %d grasps of %d scenes to %s (%s)", n, len(ids), folder.path, fmt)
    return ExportResult(folder.path, files, n, left_out)


def _require_no_failed_scene(scenes: SceneLabels) -> None:
    """``--partial`` not given: a run in which a scene failed (its manifest's ``objects_failed``)
    is refused with one line, as an unfinished one is: the export would silently lack it."""
    failed = (scenes.run.manifest or {}).get("objects_failed") or {}
    failed = {unit: why for unit, why in failed.items() if is_scene_unit(unit)}  # not an object's own line
    if failed:
        unit = sorted(failed)[0]
        more = f" and {len(failed) - 1} more" if len(failed) > 1 else ""
        raise ToolError(
            f"{scenes.path}: {len(failed)} of its scenes failed ({unit}: {failed[unit]}{more}); re-run the "
            "same annotate command to retry them, or pass --partial to export the scenes that were labelled"
        )


def _meshes(scenes: SceneLabels, items, objects_dir) -> dict:
    """The meshes (mesh frame, metres) of every object kept in the scenes ``items``, by id."""
    from annotator.tools.common import object_mesh

    labels = scenes.labels
    used = sorted({inst.object_id for record, _, _ in items for inst in record.kept})
    meshes = {}
    for oid in used:
        rows = labels[labels["object_id"] == oid]
        meshes[oid] = object_mesh(scenes.path, oid, objects_dir, rows if len(rows) else None)
    return meshes


def _vgn(
    scenes: SceneLabels, items, folder: ExportFolder, depth: TcpDepth, objects_dir, balance: bool = False
) -> tuple[list[Path], list[LeftOut]]:
    from annotator.tools.export_cgn import mesh_file, write_meshes
    from annotator.tools.export_giga import MESH_POSE_LIST, write_mesh_pose_lists
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
    meshes = _meshes(scenes, items, objects_dir)
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


def _cgn(
    scenes: SceneLabels, items, folder: ExportFolder, depth: TcpDepth, objects_dir
) -> tuple[list[Path], list[LeftOut]]:
    from annotator.tools.export_cgn import mesh_file, scene_file, write_cgn

    meshes = _meshes(scenes, items, objects_dir)
    names = [mesh_file(oid) for oid in meshes]
    for record, views, _ in items:
        names.append(f"scene_contacts/{scene_file(record.scene_id)}")
        names += [f"views/{int(record.scene_id):06d}_{v.view_id:02d}.npz" for v in views]
    for name in names:
        folder.target(name)
    written = write_cgn(folder.path, items, meshes, depth.T_base_tcp, folder.write_path)
    failures = sum(int(np.sum(~np.asarray(g.success, dtype=bool))) for _, _, g in items)
    return written.paths, [
        LeftOut(failures, "failures (Contact-GraspNet stores its positives only)"),
        LeftOut(
            written.no_contact,
            "successes whose closing line does not meet their mesh on both sides (no contact points)",
        ),
    ]
