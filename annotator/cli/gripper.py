"""``annotator gripper check``: a gripper model's physics checked before it labels."""

from __future__ import annotations

import sys

import click

from annotator.cli.common import CONFIG_OPTION, CONTEXT, EXIT_OK, EXIT_SOME_FAILED, load_config


@click.group("gripper", context_settings=CONTEXT)
def gripper_group() -> None:
    """Grippers: check a gripper model of your own (docs/grippers.md)."""


@gripper_group.command("check", context_settings=CONTEXT)
@click.argument("gripper", metavar="DIR|NAME")
@CONFIG_OPTION
@click.option(
    "--fast",
    is_flag=True,
    help="Skip the slowest check (labelling a cube wider than the stroke).",
)
def check_command(gripper: str, config_file, fast: bool) -> None:
    """Run the physics checks the shipped grippers pass on a gripper model and print one verdict
    line each, with the figure measured, its limit and what to change when it fails.

    DIR|NAME is a folder with a gripper.toml and its URDF (docs/grippers.md), or a shipped
    gripper's name. The checks, in the annotation worlds' settings (--config: [physics],
    [gripper], [protocol]):

    \b
      pads follow the FK              the drive held over the stroke: pads where the FK table says
      followers' drift                the coupled followers under the full squeeze, lift and shake
      squeeze equals the grip force   the pads' normal forces on a 40 mm box
      box held through lift and shake a 200 g box through the protocol's lift and shake
      no success wider than the stroke 30 grasps labelled on a cube 30 mm wider than the stroke

    \b
    Example:
      annotator gripper check my_gripper/
      annotator gripper check rg2

    Exit codes: 0 every check passed, 1 some failed, 2 the gripper cannot be loaded (one line
    saying why) or a bad --config.
    """
    from annotator.grippers import DescriptionError, load_gripper
    from annotator.tools.common import ToolError
    from annotator.tools.gripper_check import check_gripper

    config = load_config(config_file)
    try:
        description = load_gripper(gripper)
    except DescriptionError as exc:
        raise ToolError(str(exc)) from None
    click.echo(f"gripper {description.name} ({description.folder}), grip force {description.grip_force:g} N")
    verdicts = check_gripper(description, config, wide=not fast)
    for verdict in verdicts:
        click.echo(verdict.line())
    failed = sum(not v.passed for v in verdicts)
    click.echo(f"{len(verdicts) - failed} of {len(verdicts)} checks passed")
    sys.exit(EXIT_SOME_FAILED if failed else EXIT_OK)
