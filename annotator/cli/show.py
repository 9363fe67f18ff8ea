"""``annotator show``: pictures of labelled grasps."""

from __future__ import annotations

import logging
from pathlib import Path

import click

from annotator.cli.common import (
    CONTEXT,
    GRASP_ID,
    LABELS,
    LABELS_GRIPPER_OPTION,
    MAX_PICTURES,
    OBJECTS_OPTION,
    OUTCOMES,
    VERBOSE_OPTION,
    count_option,
    file_option,
    overwrite_option,
    seed_option,
    setup_logging,
)


@click.command("show", context_settings=CONTEXT)
@LABELS
@click.option("--object", "object_id", default=None, help="Object id, as in the labels' object_id column.")
@count_option(
    "--scene",
    "scene_id",
    default=None,
    help="Instead of --object: a picture of this scene of annotate --scenes with its grasps.",
    low=0,
)
@file_option(
    "--png",
    "png",
    required=True,
    help="Sheet to write.",
)
@click.option(
    "--outcome",
    "outcomes",
    multiple=True,
    type=click.Choice(OUTCOMES),
    help="Only grasps with this outcome (repeat for several).",
)
@click.option(
    "--grasp", "grasp_ids", multiple=True, type=GRASP_ID, help="These grasp ids instead of a random choice."
)
@count_option(
    "--n",
    "n",
    default=8,
    show_default=True,
    high=MAX_PICTURES,
    help="Grasps on the sheet.",
)
@seed_option("Seed of the random choice of grasps.")
@click.option(
    "--attempts",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    default=None,
    help="With --scene R: instead of the labels, round R's attempts from a clutter-removal --out "
    "grasps.csv, numbered and coloured by how each ended, on the scene as it first settled (the "
    "labels' scene R is round R when both ran with the same objects, seed, --arrangement and "
    "--per-scene).",
)
@file_option(
    "--overview",
    "overview_png",
    default=None,
    help="Overview picture to write [default: <png>-overview.png].",
)
@OBJECTS_OPTION
@overwrite_option("Replace pictures of these names this tool did not write.")
@LABELS_GRIPPER_OPTION
@VERBOSE_OPTION
def show_command(
    labels,
    object_id,
    scene_id,
    png,
    outcomes,
    grasp_ids,
    n,
    seed,
    attempts,
    overview_png,
    objects_dir,
    overwrite,
    gripper,
    verbose,
):
    """Pictures of labelled grasps: the labels' gripper at each label's pose and width around the object.

    Writes a sheet of N grasps (front and side view each, titled with grasp id, outcome and
    width) and an overview of every grasp of the object as a small gripper glyph coloured by
    outcome (parts behind the object faint). With --scene ID (labels of annotate --scenes): the
    scene on the table from two views, each object named instance:object, N of its grasps
    (default 40 there) as glyphs coloured by outcome; with --attempts, a clutter-removal round's
    attempts on that scene instead, numbered, titled with what each went for and how it ended.

    \b
    Example:
      annotator show labels/ --object mug --objects objects/ --png mug.png
      annotator show labels/ --object mug --objects objects/ --outcome success --n 4 --png ok.png
      annotator show scene_labels/ --scene 3 --png scene3.png
      annotator show scene_labels/ --scene 3 --attempts cr_learned/grasps.csv --png round3.png
    """
    setup_logging(False, verbose, default=logging.WARNING)
    if (object_id is None) == (scene_id is None):
        raise click.UsageError("give --object ID or --scene ID (one of them)")
    if attempts is not None and scene_id is None:
        raise click.UsageError("--attempts draws a clutter-removal round: give --scene ROUND")
    if scene_id is not None:
        if grasp_ids or overview_png:
            raise click.UsageError(
                "--grasp and --overview draw one object; --scene draws its grasps in one picture"
            )
        from annotator.tools.show_scene import show_scene

        count = n if _given(n_option="n") else 40
        done = show_scene(
            labels, scene_id, png, count, seed, tuple(outcomes), objects_dir, overwrite, attempts=attempts
        )
        drawn = f"{done.n_grasps} attempts of {attempts}" if attempts else f"{done.n_grasps} grasps"
        click.echo(f"wrote {done.png} (scene {scene_id}: {done.kept} objects, {drawn})")
        return
    from annotator.tools.common import labelling_config, labelling_gripper, read_labels
    from annotator.tools.show import show

    source = labelling_config(labels).line()
    table = read_labels(labels)
    hand = labelling_gripper(labels, gripper, table)
    result = show(
        labels,
        object_id,
        png,
        n,
        seed,
        tuple(outcomes),
        tuple(grasp_ids),
        objects_dir,
        overview_png,
        labels=table,
        gripper=hand.description,
        overwrite=overwrite,
    )
    click.echo(
        f"wrote {result.sheet} ({result.n_grasps} grasps) and {result.overview}; {source}; {hand.line()}"
    )


def _given(n_option: str) -> bool:
    """Whether the option was given on the command line (not its default)."""
    ctx = click.get_current_context()
    return ctx.get_parameter_source(n_option) == click.core.ParameterSource.COMMANDLINE
