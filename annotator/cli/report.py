"""``annotator report``: a self-contained HTML report of a labels folder."""

from __future__ import annotations

import logging

import click

from annotator.cli.common import (
    CONTEXT,
    LABELS,
    LABELS_GRIPPER_OPTION,
    MAX_PICTURES,
    OBJECTS_OPTION,
    VERBOSE_OPTION,
    count_option,
    file_option,
    overwrite_option,
    setup_logging,
)


@click.command("report", context_settings=CONTEXT)
@LABELS
@file_option(
    "--html",
    "html_path",
    required=True,
    help="The report to write (one file; open it in any browser, offline).",
)
@OBJECTS_OPTION
@count_option(
    "--pictures",
    "picture_objects",
    default=3,
    show_default=True,
    help="Objects shown with pictures (those with the most successes); 0 for none.",
    low=0,
    high=MAX_PICTURES,
)
@overwrite_option("Replace an --html file this tool did not write.")
@LABELS_GRIPPER_OPTION
@VERBOSE_OPTION
def report_command(labels, html_path, objects_dir, picture_objects, overwrite, gripper, verbose):
    """A dataset at a glance: one self-contained HTML file (pictures embedded, no network).

    The run's configuration and versions (from _manifest.json), objects that failed and why,
    per-object success rates and outcome mix with mass and collision error, width and score
    histograms, the distribution of approach directions and pictures of a few objects (they
    need the meshes: --objects, the folder the labels were made from).

    \b
    Example:
      annotator report labels/ --objects objects/ --html report.html
    """
    setup_logging(False, verbose, default=logging.WARNING)
    from annotator.tools.report import report

    result = report(labels, html_path, objects_dir, picture_objects, gripper=gripper, overwrite=overwrite)
    counts = f"{result.n_objects} objects, {result.n_grasps} grasps, {result.pictures} pictures"
    click.echo(f"wrote {result.path}: {counts}")
    if result.run_state != "finished":
        click.echo(f"note: the labels' run is {result.run_state}; the report shows what is there", err=True)
