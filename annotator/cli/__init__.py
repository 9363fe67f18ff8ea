"""Command line: ``annotate`` (the batch job) and ``annotator <subcommand>``.

Every click command lives in this package, one module per command, each thin: it parses its
options, calls the library and turns bad input into one line and an exit code
(:mod:`annotator.cli.common`). Heavy imports happen inside the commands, so ``--help`` is fast.
"""

from __future__ import annotations

import click

from annotator import __version__
from annotator.cli.annotate import annotate_command
from annotator.cli.calibrate import calibrate_command
from annotator.cli.clutter_removal import clutter_removal_command
from annotator.cli.common import CONTEXT
from annotator.cli.evaluate import evaluate_command
from annotator.cli.export import export_command
from annotator.cli.learn import learn_group
from annotator.cli.replay import replay_command
from annotator.cli.report import report_command
from annotator.cli.scene import scene_command
from annotator.cli.show import show_command


@click.group(context_settings=CONTEXT)
@click.version_option(__version__, prog_name="annotator")
def main() -> None:
    """rg2-annotator: grasp labels for a UR3 + OnRobot RG2, simulated in PyBullet.

    \b
    annotator annotate --objects objects/ --n 500   the batch job (same as `annotate`)
    annotator scene                                 the UR3 + RG2 scene with sliders (GUI)
    annotator scene --headless --gif scene.gif      a scripted sequence rendered to a GIF

    \b
    After annotate (each command's --help says more):
    annotator replay labels/ --object box --grasp 3 --gif box3.gif
    annotator show labels/ --object mug --objects objects/ --png mug.png
    annotator report labels/ --objects objects/ --html report.html
    annotator export labels/ --format acronym --objects objects/ --out acronym/
    annotator evaluate predictions.parquet --objects objects/ --out evaluated/
    annotator calibrate labels/ real_trials.csv --objects objects/

    \b
    Scenes of several objects (annotate --scenes N, docs/scenes.md):
    annotator show scene_labels/ --scene 3 --png scene3.png
    annotator export scene_labels/ --format vgn --out vgn_raw/
    annotator clutter-removal --objects objects/ --rounds 20 --policy labels
    annotator learn train scene_labels/ --out model.npz   (docs/learning.md)
    """


for _command in (
    annotate_command,
    scene_command,
    replay_command,
    show_command,
    report_command,
    export_command,
    evaluate_command,
    calibrate_command,
    clutter_removal_command,
    learn_group,
):
    main.add_command(_command)


def annotate_main() -> None:
    """Entry point of the ``annotate`` console script (``annotator annotate``)."""
    annotate_command()
