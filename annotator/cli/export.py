"""``annotator export``: the labels in the formats other grasp learners read."""

from __future__ import annotations

import logging
from pathlib import Path

import click

from annotator.cli.common import (
    CONTEXT,
    LABELS,
    LABELS_GRIPPER_OPTION,
    OBJECTS_OPTION,
    VERBOSE_OPTION,
    overwrite_option,
    setup_logging,
)


@click.command("export", context_settings=CONTEXT)
@LABELS
@click.option(
    "--format",
    "fmt",
    required=True,
    type=click.Choice(["acronym", "graspgen", "vgn", "contact_graspnet"]),
    help="acronym: one HDF5 file per object (needs h5py: the 'export' extra); graspgen: one JSON per object "
    "and the gripper's description for GraspGen (gripper/); for labels of annotate --scenes: vgn (VGN's "
    "grasps.csv and scenes/*.npz, its dataset/, GIGA's mesh_pose_list/; needs --views) or "
    "contact_graspnet (one npz per scene, contacts on the mesh).",
)
@click.option("--out", "out_dir", required=True, type=click.Path(path_type=Path, file_okay=False))
@OBJECTS_OPTION
@click.option("--object", "object_ids", multiple=True, help="Only this object (repeat for several).")
@overwrite_option(
    "Replace an earlier export in --out (only the files it wrote are removed; a file no export "
    "wrote is never replaced)."
)
@click.option(
    "--partial",
    is_flag=True,
    help="Export the labels of a run that has not finished, or of a scene run in which a scene failed.",
)
@click.option(
    "--balance",
    is_flag=True,
    help="vgn: clean the grasps as VGN's data notebook does before its construct_dataset.py: leave out "
    "those within 2 cm of the workspace cube's sides, then negatives at random until they are as many "
    "as the positives (both layouts; counted in _export.json).",
)
@LABELS_GRIPPER_OPTION
@VERBOSE_OPTION
def export_command(
    labels, fmt, out_dir, objects_dir, object_ids, overwrite, partial, balance, gripper, verbose
):
    """The labels in the formats existing grasp learners read, with each object's mesh.

    Both formats store the pose of the gripper's base frame (the RG2's rg2_base_link: on the
    tool flange, +z approach, +x closing; each gripper's [base] link), not our TCP:
    T_obj_base = T_obj_tcp * T_base_tcp(width)^-1, with the width of each grasp stored beside it,
    and the gripper's type (docs/tools.md, "Export"). The gripper is the one recorded with the
    labels unless --gripper. Grasps an export leaves out (VGN: outside the workspace cube;
    Contact-GraspNet: failures, successes without two contacts on their mesh) are printed and
    recorded in OUT/_export.json.

    \b
    Example:
      annotator export labels/ --format acronym --objects objects/ --out acronym/
      annotator export labels/ --format graspgen --objects objects/ --out graspgen/
      annotator export scene_labels/ --format vgn --out vgn_raw/
      annotator export scene_labels/ --format vgn --balance --out vgn_train/
      annotator export scene_labels/ --format contact_graspnet --objects objects/ --out cgn/
    """
    setup_logging(False, verbose, default=logging.WARNING)
    if fmt in ("vgn", "contact_graspnet"):
        from annotator.tools.common import ToolError
        from annotator.tools.export_scenes import export_scenes

        if object_ids:
            raise ToolError(f"--object selects objects; --format {fmt} exports whole scenes")
        result = export_scenes(
            labels, fmt, out_dir, objects_dir, overwrite=overwrite, partial=partial, balance=balance
        )
        click.echo(f"wrote {len(result.files)} {fmt} files ({result.n_grasps} grasps) to {out_dir}")
        if result.summary():
            click.echo(f"{result.summary()} (recorded in {out_dir}/_export.json)")
        return
    from annotator.tools.common import ToolError, labelling_gripper
    from annotator.tools.export import export

    if balance:
        raise ToolError("--balance is VGN's data cleanup: it applies to --format vgn only")

    hand = labelling_gripper(labels, gripper)
    click.echo(hand.line(), err=True)
    result = export(
        labels,
        fmt,
        out_dir,
        objects_dir,
        tuple(object_ids),
        hand.description,
        overwrite=overwrite,
        partial=partial,
    )
    click.echo(
        f"wrote {len(result.files)} {fmt} files ({result.n_grasps} grasps) and their meshes to {out_dir}"
    )
