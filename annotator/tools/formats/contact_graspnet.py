"""``--format contact_graspnet``: a scene run in Contact-GraspNet's files (:mod:`annotator.tools.
export_cgn`): ``meshes/``, ``scene_contacts/NNNNNN.npz`` per scene (its positives: the successes, as
the gripper's base pose, with their contacts on the mesh; a success without two is left out and
counted) and, when the run has views, ``views/NNNNNN_VV.npz`` (its inference input)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from annotator.tools.formats import Exporter

if TYPE_CHECKING:
    from annotator.tools.export import ExportFolder, LeftOut, TcpDepth
    from annotator.tools.scene_labels import SceneLabels


def write_contact_graspnet(
    scenes: SceneLabels, items, folder: ExportFolder, depth: TcpDepth, objects_dir, balance: bool = False
) -> tuple[list[Path], list[LeftOut]]:
    from annotator.tools.export import LeftOut  # noqa: F811  (the records, made here)
    from annotator.tools.export_cgn import mesh_file, scene_file, write_cgn
    from annotator.tools.export_scenes import kept_meshes

    meshes = kept_meshes(scenes, items, objects_dir)
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


HELP = "one npz per scene, contacts on the mesh"
FOLDERS = ("meshes", "scene_contacts", "views")
EXPORTER = Exporter("contact_graspnet", "scene", HELP, 3, FOLDERS, write_scenes=write_contact_graspnet)
