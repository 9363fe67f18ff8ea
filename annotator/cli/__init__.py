"""Command line: ``annotate`` (the batch job) and ``annotator <subcommand>``.

Every click command lives in this package, one module per command, each thin: it parses its
options, calls the library and turns bad input into one line and an exit code
(:mod:`annotator.cli.common`). Heavy imports happen inside the commands, so ``--help`` is fast.
"""

from __future__ import annotations

import sys
from typing import Any

import click

from annotator import __version__
from annotator.cli.annotate import annotate_command
from annotator.cli.calibrate import calibrate_command
from annotator.cli.clutter_removal import clutter_removal_command
from annotator.cli.common import CONTEXT
from annotator.cli.evaluate import evaluate_command
from annotator.cli.export import export_command
from annotator.cli.gripper import gripper_group
from annotator.cli.learn import learn_group
from annotator.cli.replay import replay_command
from annotator.cli.report import report_command
from annotator.cli.scene import scene_command
from annotator.cli.show import show_command
from annotator.cli.trials import trials_group

EXIT_INTERRUPTED = 130  # 128 + SIGINT, as annotator.cli.common documents
_NO_WORK = {"--help", "-h", "--version"}


def _import_holding_ctrl_c(args: list[str]) -> None:
    """Import trimesh (and through it SciPy) with Ctrl-C held back, then raise it: trimesh guards
    its optional imports with ``except BaseException``, so a Ctrl-C landing while it is imported
    (the first seconds of a command, on a busy machine) was swallowed and the run went on to the
    end with exit 0. Skipped for ``--help`` and ``--version``, which stay fast."""
    if not args or _NO_WORK & set(args):
        return
    from annotator.store.lock import sigint_deferred

    with sigint_deferred():
        import trimesh  # noqa: F401


def _standalone(run, args, prog_name, complete_var, standalone_mode, extra) -> Any:
    """Run click's ``main`` (``run``) as click's standalone mode does, but a Ctrl-C at any time
    ends the command with 130 and one line (click: ``Aborted!`` and 1, read as "some failed")."""
    if not standalone_mode:
        return run(args, prog_name, complete_var, False, **extra)
    try:
        _import_holding_ctrl_c(sys.argv[1:] if args is None else list(args))
        rv = run(args, prog_name, complete_var, False, **extra)
    except KeyboardInterrupt:
        click.echo("interrupted", err=True)
        sys.exit(EXIT_INTERRUPTED)
    except click.exceptions.Abort as exc:
        if isinstance(exc.__cause__, KeyboardInterrupt):
            click.echo("interrupted", err=True)
            sys.exit(EXIT_INTERRUPTED)
        click.echo("Aborted!", err=True)
        sys.exit(1)
    except click.ClickException as exc:
        exc.show()
        sys.exit(exc.exit_code)
    sys.exit(rv if isinstance(rv, int) else 0)


class _Group(click.Group):
    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra) -> Any:
        return _standalone(super().main, args, prog_name, complete_var, standalone_mode, extra)


@click.group(cls=_Group, context_settings=CONTEXT)
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
    annotator gripper check my_gripper/             a gripper of your own, checked before it labels
    annotator trials sheet labels/ --out sheet.csv  grasps to execute on your robot, read back

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
    gripper_group,
    trials_group,
    learn_group,
):
    main.add_command(_command)


def annotate_main() -> None:
    """Entry point of the ``annotate`` console script (``annotator annotate``)."""
    _standalone(annotate_command.main, None, None, None, True, {})
