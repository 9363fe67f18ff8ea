"""``annotator show``: pictures of labelled grasps."""

from __future__ import annotations

import logging

import click

from annotator.cli.common import (
    CONTEXT,
    LABELS,
    LABELS_GRIPPER_OPTION,
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
    "--grasp", "grasp_ids", multiple=True, type=int, help="These grasp ids instead of a random choice."
)
@count_option(
    "--n",
    "n",
    default=8,
    show_default=True,
    help="Grasps on the sheet.",
)
@seed_option("Seed of the random choice of grasps.")
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
    (default 40 there) as glyphs coloured by outcome.

    \b
    Example:
      annotator show labels/ --object mug --objects objects/ --png mug.png
      annotator show labels/ --object mug --objects objects/ --outcome success --n 4 --png ok.png
      annotator show scene_labels/ --scene 3 --png scene3.png
    """
    setup_logging(False, verbose, default=logging.WARNING)
    if (object_id is None) == (scene_id is None):
        raise click.UsageError("give --object ID or --scene ID (one of them)")
    if scene_id is not None:
        if grasp_ids or overview_png:
            raise click.UsageError(
                "--grasp and --overview draw one object; --scene draws its grasps in one picture"
            )
        from annotator.tools.show_scene import show_scene

        count = n if _given(n_option="n") else 40
        done = show_scene(labels, scene_id, png, count, seed, tuple(outcomes), objects_dir, overwrite)
        click.echo(f"wrote {done.png} (scene {scene_id}: {done.kept} objects, {done.n_grasps} grasps)")
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
