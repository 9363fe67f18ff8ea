"""``annotator export`` of a scene run, in a scene format of :mod:`annotator.tools.formats`: the
files of VGN (:mod:`annotator.tools.formats.vgn`) or Contact-GraspNet
(:mod:`annotator.tools.formats.contact_graspnet`).

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

from annotator.store.names import is_scene_unit
from annotator.tools.common import ToolError
from annotator.tools.export import ExportFolder, ExportResult, TcpDepth
from annotator.tools.scene_labels import SceneLabels, open_scene_labels

log = logging.getLogger(__name__)


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
    from annotator.tools.formats import of_unit

    formats = of_unit("scene")
    if balance and not (fmt in formats and formats[fmt].balance):
        raise ToolError("--balance is VGN's data cleanup: it applies to --format vgn only")
    if fmt not in formats:
        raise ToolError(f"unknown scene format {fmt!r}; choose from {', '.join(formats)}")
    write_scenes = formats[fmt].write_scenes
    assert write_scenes is not None  # a scene format writes scenes
    scenes = open_scene_labels(labels_dir, f"export --format {fmt}")
    if not partial:
        scenes.run.require_finished("export")
        _require_no_failed_scene(scenes)
    with ExportFolder.open(Path(out_dir), overwrite=overwrite) as folder:
        depth = TcpDepth(scenes.gripper)
        ids = scenes.scene_ids()
        items = [(scenes.records[s], scenes.views(s), scenes.grasps(s)) for s in ids]
        files, left_out = write_scenes(scenes, items, folder, depth, objects_dir, balance)
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


def kept_meshes(scenes: SceneLabels, items, objects_dir) -> dict:
    """The meshes (mesh frame, metres) of every object kept in the scenes ``items``, by id."""
    from annotator.tools.common import object_mesh

    labels = scenes.labels
    used = sorted({inst.object_id for record, _, _ in items for inst in record.kept})
    meshes = {}
    for oid in used:
        rows = labels[labels["object_id"] == oid]
        meshes[oid] = object_mesh(scenes.path, oid, objects_dir, rows if len(rows) else None)
    return meshes
