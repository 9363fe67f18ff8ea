"""``annotator clutter-removal``: VGN's clutter-removal benchmark on the seed's UR3."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import click

from annotator.cli.common import CONFIG_OPTION, CONTEXT, SEED, VERBOSE_OPTION, load_config, setup_logging


@click.command("clutter-removal", context_settings=CONTEXT)
@click.option(
    "--objects",
    "objects_dir",
    required=True,
    type=click.Path(path_type=Path, file_okay=False),
    help="Folder of objects the piles are drawn from (as annotate --objects).",
)
@click.option("--rounds", required=True, type=click.IntRange(min=1, max=100_000), help="Piles to clear.")
@click.option(
    "--per-scene",
    "per_scene",
    type=click.IntRange(min=1, max=253),
    default=5,
    show_default=True,
    help="Objects dropped in each pile (VGN: 5); those that leave the workspace are not counted.",
)
@click.option(
    "--policy",
    default="labels",
    show_default=True,
    metavar="labels|random|FILE",
    help="labels: the best-scored reachable label of the scene as it is (an oracle); random: a "
    "random collision-free reachable antipodal grasp (a baseline); FILE: a learner's predictions, a "
    "CSV or Parquet file with columns round, x, y, z, qx, qy, qz, qw (TCP in the table frame), width, score.",
)
@click.option(
    "--seed", type=SEED, default=0, show_default=True, help="Round r is scene r of annotate --scenes."
)
@click.option(
    "--trials",
    type=click.IntRange(min=1),
    default=1,
    show_default=True,
    help="labels policy: trials per grasp (--trials of annotate); the best score wins.",
)
@click.option(
    "--workers",
    type=click.IntRange(min=1),
    default=None,
    help="Processes [default: all cores]; rounds in parallel.",
)
@click.option(
    "--out",
    "out_dir",
    type=click.Path(path_type=Path, file_okay=False),
    default=None,
    help="Write rounds.csv and grasps.csv (one row per attempt) here.",
)
@CONFIG_OPTION
@VERBOSE_OPTION
def clutter_removal_command(
    objects_dir, rounds, per_scene, policy, seed, trials, workers, out_dir, config_file, verbose
):
    """Clear piles of objects with the UR3, grasp after grasp, as VGN's benchmark does.

    Each round drops --per-scene objects in a pile (round r is scene r of annotate --scenes with the
    same seed); the policy proposes a grasp, the UR3 executes it (IK along the approach, close, lift
    10 cm) and a held object is taken away. A round ends when the table is clear, after two failed
    grasps in a row, or when the policy proposes nothing. Prints the grasp success rate and the
    percent cleared with 95 % intervals (docs/tools.md, "clutter-removal").

    \b
    Example:
      annotator clutter-removal --objects objects/ --rounds 20 --policy labels
      annotator clutter-removal --objects objects/ --rounds 20 --policy random --out cr_random/
    """
    setup_logging(False, verbose, default=logging.WARNING)
    from annotator.objects import ObjectDiscoveryError, ObjectError, default_cache_dir, discover_objects
    from annotator.scenes.clutter import ClutterJob, clutter_removal, read_predictions
    from annotator.tools.common import ToolError, check_output_dir

    config = load_config(config_file)
    if out_dir is not None:
        out_dir = check_output_dir(out_dir, "--out")
    name = policy if policy in ("labels", "random") else f"from {policy}"
    if policy not in ("labels", "random"):
        path = Path(policy)
        if not path.is_file():
            raise ToolError(f"--policy {policy}: not labels, random or a predictions file")
        try:
            policy = read_predictions(path)
        except ValueError as exc:
            raise ToolError(str(exc)) from None
    try:
        sources = tuple(discover_objects(objects_dir, config.objects))
    except ObjectDiscoveryError as exc:
        raise ToolError(str(exc)) from None
    job = ClutterJob(sources, per_scene, seed, policy, config, trials, cache_dir=str(default_cache_dir()))
    try:
        summary = clutter_removal(job, rounds, workers or os.cpu_count() or 1)
    except ObjectError as exc:
        raise ToolError(f"an object of the piles cannot be loaded: {exc}") from None
    for line in summary.lines(name):
        click.echo(line)
    if out_dir is not None:
        rounds_table, grasps = summary.tables()
        rounds_table.to_csv(out_dir / "rounds.csv", index=False)
        grasps.to_csv(out_dir / "grasps.csv", index=False)
        click.echo(f"wrote {out_dir / 'rounds.csv'} and {out_dir / 'grasps.csv'}")
