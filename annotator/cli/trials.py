"""``annotator trials``: a sheet of labelled grasps to execute on your robot, and its outcomes read back."""

from __future__ import annotations

from pathlib import Path

import click

from annotator.cli.common import (
    CONTEXT,
    count_option,
    file_option,
    overwrite_option,
    seed_option,
)


@click.group("trials", context_settings=CONTEXT)
def trials_group() -> None:
    """Real trials on your own robot: a sheet to execute, read back for calibrate
    (docs/trial_records.md).

    \b
    Example:
      annotator trials sheet labels/ --n 10 --repeats 3 --out sheet.csv
      (execute every row, fill real_success with 1 or 0)
      annotator trials read sheet.csv --labels labels/ --out real_trials.csv
      annotator calibrate labels/ real_trials.csv --objects objects/
    """


def _pose(text: str | None):
    """``--object-pose "x y z qx qy qz qw"`` as a (4, 4) matrix."""
    if text is None:
        return None
    import numpy as np

    from annotator.geometry import Transform

    try:
        v = [float(t) for t in text.replace(",", " ").split()]
    except ValueError:
        v = []
    if len(v) != 7 or not np.all(np.isfinite(v)) or abs(np.linalg.norm(v[3:]) - 1.0) > 1e-3:
        raise click.BadParameter(
            'give "x y z qx qy qz qw" (m, a unit xyzw quaternion)', param_hint="--object-pose"
        )
    return Transform(v[:3], np.asarray(v[3:]) / np.linalg.norm(v[3:])).as_matrix()


@trials_group.command("sheet", context_settings=CONTEXT)
@click.argument("labels", type=click.Path(path_type=Path))
@file_option(
    "--out",
    "out_file",
    required=True,
    help="The sheet to write (CSV).",
)
@count_option(
    "--n",
    default=None,
    high=1_000_000,
    help="Grasps per object (1 .. 1,000,000) [default: every executable one].",
)
@click.option(
    "--select",
    type=click.Choice(["balanced", "all", "success", "failure"]),
    default="balanced",
    show_default=True,
    help="Which simulated outcomes: balanced (half successes, half others, as far as there are), "
    "all, success or failure. Collisions, errors and unreachable grasps are never on a sheet.",
)
@count_option(
    "--repeats",
    default=1,
    show_default=True,
    high=1000,
    help="Times each grasp is executed (rows repeat 0..R-1; 1 .. 1000).",
)
@click.option("--object", "objects", multiple=True, metavar="ID", help="Only these objects (repeatable).")
@click.option(
    "--object-pose",
    default=None,
    metavar='"x y z qx qy qz qw"',
    help="Floating labels: where you put each object (its mesh frame) in the robot's base "
    "frame (UR3 base_link), so the sheet gives the grasps in the robot's frame [default: "
    "cell and resting labels use where the object rests in the cell; floating: left empty].",
)
@seed_option("Seed of the selection.")
@overwrite_option("Replace a sheet this tool did not write, or one changed (filled) since.")
def sheet_command(labels, out_file, n, select, repeats, objects, object_pose, seed, overwrite):
    """Write a sheet of LABELS' grasps to execute on your robot, one row per trial.

    Each row gives the grasp as the labels command it: in the object's frame (x .. qw, the TCP),
    as the gripper base's pose in the object's frame (base_x .. base_qw, GraspGen's and ACRONYM's
    convention), and in the robot's base frame (robot_tcp_*, robot_flange_* for the flange; from
    the cell's placement for cell labels, or --object-pose), with the opening to approach with
    (open_width), the chord (width) and the grip force. Fill real_success with 1 (held after lift
    and shake) or 0, optionally notes; leave real_success empty for a trial not executed. The
    format: docs/trial_records.md.
    """
    from annotator.tools.common import claim_outputs, labelling_config, labelling_gripper, read_labels
    from annotator.tools.export import TcpDepth
    from annotator.tools.trial_sheet import SheetSettings, make_sheet

    claimed = claim_outputs("annotator trials sheet", {"--out": out_file}, overwrite)
    table = read_labels(labels)
    config = labelling_config(labels).config
    hand = labelling_gripper(labels, None, table)
    click.echo(hand.line(), err=True)
    settings = SheetSettings(n, select, repeats, seed, tuple(objects) or None, _pose(object_pose))
    sheet = make_sheet(table, settings, config=config, depth=TcpDepth(hand.description, config.gripper))
    out_file = claimed.write("--out", lambda tmp: sheet.to_csv(tmp, index=False, float_format="%.9g"))
    grasps = sheet.drop_duplicates(["object_id", "grasp_id"])
    located = "" if sheet["robot_tcp_x"].notna().all() else " (no robot-frame poses: give --object-pose)"
    click.echo(
        f"{len(sheet)} trials ({len(grasps)} grasps x {repeats}) on {grasps.object_id.nunique()} objects "
        f"written to {out_file}{located}"
    )


@trials_group.command("read", context_settings=CONTEXT)
@click.argument("sheet_file", metavar="SHEET", type=click.Path(path_type=Path, dir_okay=False))
@file_option(
    "--out",
    "out_file",
    required=True,
    help="REAL.csv for calibrate: object_id, grasp_id, real_success, grip_force, repeat, trial_id.",
)
@click.option(
    "--labels",
    type=click.Path(path_type=Path),
    default=None,
    help="The labels the sheet was made from: every trial must name one of their grasps, on the same mesh.",
)
@click.option(
    "--without-force",
    is_flag=True,
    help="Leave grip_force out, so calibrate searches the grip force (--force) too.",
)
@overwrite_option("Replace an output file this tool did not write, or one changed since.")
def read_command(sheet_file, out_file, labels, without_force, overwrite):
    """Read a filled SHEET back into the real-trial file annotator calibrate reads.

    Rows whose real_success is empty were not executed and are left out (counted). Exit 2 with
    one line naming the row for an outcome that is not 1/0 (true/false, yes/no, success/failure),
    a trial that names no grasp of --labels or another mesh, a sheet made from other labels than
    --labels (its labels_sha256, its poses), a column named twice, a trial_id two rows share or
    one execution on two rows.
    """
    from annotator.tools.common import claim_outputs, read_labels
    from annotator.tools.trial_sheet import read_sheet

    claimed = claim_outputs("annotator trials read", {"--out": out_file}, overwrite)
    read = read_sheet(sheet_file, read_labels(labels) if labels is not None else None)
    trials = (
        read.trials.drop(columns=["grip_force"])
        if without_force and "grip_force" in read.trials
        else read.trials
    )
    out = trials.assign(real_success=trials["real_success"].astype(int))
    out_file = claimed.write("--out", lambda tmp: out.to_csv(tmp, index=False, float_format="%.9g"))
    skipped = f"; {read.skipped} not executed (real_success empty), left out" if read.skipped else ""
    click.echo(
        f"{len(out)} trials ({int(out.real_success.sum())} held) on {out.object_id.nunique()} objects "
        f"written to {out_file}{skipped}"
    )
