"""``annotator evaluate``: annotate's protocol on grasps someone else proposed."""

from __future__ import annotations

import logging
from pathlib import Path

import click

from annotator.cli.common import (
    CACHE_OPTION,
    CONTEXT,
    LABELS_GRIPPER_OPTION,
    QUIET_OPTION,
    VERBOSE_OPTION,
    config_option,
    folder_option,
    objects_option,
    overwrite_option,
    run_pipeline,
    scale_option,
    seed_option,
    setup_logging,
    trials_option,
    workers_option,
)

RESTING_GRASPS_OPTION = click.option(
    "--resting-grasps",
    "resting_grasps",
    type=click.Choice(["object", "table"]),
    default=None,
    help="With --resting (implied): whether the grasps move with the object as it settles "
    "(object, the default) or stay where they were given in the table frame (table: as a robot "
    "executes them in its own frame when the object came to rest elsewhere than it was believed).",
)
FRAME_OPTION = click.option(
    "--frame",
    type=click.Choice(["tcp", "base"]),
    default="tcp",
    show_default=True,
    help="What the pose columns are: the TCP's pose (the labels' convention) or the gripper's base "
    "link's (ACRONYM's and GraspGen's: T_obj_tcp = T_obj_base * T_base_tcp(width), the model's FK).",
)


@click.command("evaluate", context_settings=CONTEXT)
@click.argument("grasps_file", metavar="GRASPS", type=click.Path(path_type=Path))
@objects_option(
    help="Folder of the objects the grasps refer to (object_id = path without suffix, as annotate)."
)
@folder_option(
    "--out",
    "out_dir",
    required=True,
    help="Output folder: label files (one per object) and _manifest.json, as annotate writes.",
)
@workers_option(high=None)
@seed_option("Seed of the perturbed trials.")
@trials_option(
    "Trials per grasp: trial 0, then K-1 perturbed by [robust] (ending at the lift unless "
    "[robust] shake = true); score = fraction that held."
)
@click.option("--scheduler", default=None, metavar="ADDRESS", help="Dask scheduler (tcp://host:8786).")
@scale_option("Scale every mesh by this factor (as annotate --scale).")
@overwrite_option("Discard existing labels in --out and start over.")
@config_option(
    "TOML file overriding constants, as for annotate [default: the configuration recorded "
    "beside GRASPS when it is a labels folder or file of this tool, else the defaults]."
)
@LABELS_GRIPPER_OPTION
@FRAME_OPTION
@click.option(
    "--resting",
    is_flag=True,
    help="Each object rests on the table (the cell's) under its lowest point in the orientation "
    "of its mesh frame (z up), or the one GRASPS gives (rest_qx rest_qy rest_qz rest_qw), settles, and "
    "the grasps move with it; the gripper closes with gravity on [default: floating, gravity off].",
)
@RESTING_GRASPS_OPTION
@click.option(
    "--real",
    "real_column",
    default=None,
    metavar="COLUMN",
    help="A column of GRASPS with each grasp's real outcome (1/0, true/false): after the run, trial "
    "0 held through each stage (close, lift, motion, shake) is compared with it: balanced accuracy, "
    "precision and recall with 95 % intervals [default: real_success, when GRASPS has it].",
)
@CACHE_OPTION
@QUIET_OPTION
@VERBOSE_OPTION
def evaluate_command(
    grasps_file,
    objects_dir,
    out_dir,
    workers,
    seed,
    trials,
    scheduler,
    scale,
    overwrite,
    config_file,
    gripper,
    frame,
    resting,
    resting_grasps,
    real_column,
    cache_dir,
    quiet,
    verbose,
):
    """Simulate grasps someone else proposed with annotate's protocol; write label columns.

    GRASPS is a Parquet or CSV file (or a labels folder) with object_id, the TCP pose as the
    labels give it (x y z, qx qy qz qw in the object's mesh frame, metres, xyzw) and optionally
    width (m, the opening at the grasp; when missing, measured on the mesh over the pads' faces so
    that the open pads clear the object) and grasp_id. With --frame base the pose is the gripper's
    base link's (ACRONYM's and GraspGen's convention). The output is what annotate writes (same
    columns, resume, determinism, workers), plus why a collision is one (collided_with: object or
    table; collision_stage: approach, closed or pregrasp); with --resting also rest_q*, the settled
    object pose obj_x .. obj_qw and settle_drift. With real outcomes (--real COLUMN, or a
    real_success column), each stage trial 0 held through is compared with them at the end.
    Grasps keep their grasp_id when those are 0..k-1
    per object, else they are numbered in the order of the file. Grasps a real robot executed
    (off-centre, on misplaced objects) want [protocol] approach = "simulated" (docs/tools.md).

    \b
    Example:
      annotator evaluate predictions.parquet --objects objects/ --out evaluated/
      annotator evaluate acronym_grasps.csv --frame base --gripper panda --objects objects/ --out ev/
      python -c "import pandas; print(pandas.read_parquet('evaluated/').outcome.value_counts())"

    Exit codes as annotate's: 0 all objects done, 1 some failed, 2 usage error, 3 output
    folder not writable, 4 Dask scheduler lost, 130/143 interrupted (re-run to resume).
    """
    setup_logging(False, verbose, default=logging.WARNING)
    from annotator.pipeline.evaluate_job import EvaluateOptions
    from annotator.pipeline.modes import resting as resting_mode
    from annotator.sim.hand import max_width
    from annotator.tools.common import labelling_config, labelling_gripper, labels_resting
    from annotator.tools.evaluate import given_candidates, read_grasps

    grasps = read_grasps(grasps_file, frame)
    real = _real_outcomes(grasps_file, real_column, grasps)
    chosen = labelling_config(grasps_file, config_file)
    config = chosen.config
    from annotator.confidence import trials_mismatch

    if trials_mismatch(config, trials):
        raise click.UsageError(f"{chosen.line()}: {trials_mismatch(config, trials)}")
    click.echo(chosen.line(), err=True)
    hand = labelling_gripper(grasps_file, gripper)
    click.echo(hand.line(), err=True)
    from annotator.tools.gripper_check import check_before_work

    check_before_work(hand.description, config)
    resting = resting_grasps or ("object" if resting else None)
    recorded = labels_resting(grasps_file)
    if resting is None and recorded is not None:
        resting = recorded
        click.echo(
            f"resting: on the table, grasps in the {recorded}'s frame, as the labels were simulated", err=True
        )
    if not Path(objects_dir).is_dir():
        raise click.UsageError(f"objects folder not found: {objects_dir}")
    stroke = max_width(config, hand.description)
    candidates = given_candidates(
        grasps, objects_dir, config, scale, stroke, gripper=hand.description, frame=frame, resting=resting
    )
    run_pipeline(
        "evaluate",
        objects_dir=objects_dir,
        n=max(candidates.counts.values()),
        out_dir=out_dir,
        workers=workers,
        seed=seed,
        trials=trials,
        scheduler=scheduler,
        scale=scale,
        overwrite=overwrite,
        repair=False,
        quiet=quiet,
        gripper=hand.description,
        cache_dir=cache_dir,
        config=config,
        own=EvaluateOptions(candidates, resting_mode(resting)),
        on_done=None if real is None else lambda: _compare_stages(out_dir, real, real_column, config),
    )


def _real_outcomes(grasps_file: Path, column: str | None, grasps):
    """The grasps' real outcomes (``--real COLUMN``, or ``real_success`` when the table has it), or
    None: nothing to compare with."""
    from annotator.tools.common import read_table
    from annotator.tools.evaluate import REAL_COLUMN, real_outcomes

    if column is None:
        if Path(grasps_file).is_dir() or REAL_COLUMN not in read_table(grasps_file, "grasps file").columns:
            return None
        column = REAL_COLUMN
    return real_outcomes(grasps_file, column, grasps)


def _compare_stages(out_dir: Path, real, column: str | None, config) -> None:
    """Print each stage of the evaluated grasps against their real outcomes."""
    from annotator.tools.common import read_labels
    from annotator.tools.evaluate import REAL_COLUMN, stage_agreement, stage_agreement_text

    rows = read_labels(out_dir)
    stages = stage_agreement(rows, real)
    rate = float(real["real_success"].mean())
    click.echo(stage_agreement_text(stages, column or REAL_COLUMN, config.protocol.gate, rate), err=True)
