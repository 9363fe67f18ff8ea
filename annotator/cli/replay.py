"""``annotator replay``: one label executed by the UR3 + RG2 in the seed's cell."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from annotator.cli.common import (
    CACHE_OPTION,
    CONTEXT,
    GRASP_ID,
    LABELS_GRIPPER_OPTION,
    config_option,
    count_option,
    file_option,
    objects_option,
    overwrite_option,
)


def _fmt_q(q: np.ndarray) -> str:
    return "[" + ", ".join(f"{v:.3f}" for v in q) + "]"


@click.command("replay", context_settings=CONTEXT)
@click.argument("labels", type=click.Path(path_type=Path, exists=True))
@click.option("--object", "object_id", required=True, help="The label's object_id.")
@click.option("--grasp", "grasp_id", required=True, type=GRASP_ID, help="The label's grasp_id.")
@objects_option(
    default=Path("objects"),
    show_default=True,
    help="The folder the labels were made from (the object is found there by its id).",
)
@file_option(
    "--gif",
    "gif_path",
    help="Write the replay as a GIF.",
)
@click.option("--gui", is_flag=True, help="Show the replay in the PyBullet GUI at real time.")
@click.option(
    "--hold",
    type=click.FloatRange(min=0),
    default=None,
    help="GUI: keep the window this many seconds after the replay [default: until it is closed].",
)
@click.option(
    "--size",
    default=(320, 240),
    show_default=True,
    type=(click.IntRange(16, 4096), click.IntRange(16, 4096)),
    help="GIF frame width height (pixels, 16..4096 each).",
)
@config_option("Simulate with this TOML file [default: the configuration recorded beside the labels].")
@count_option(
    "--scene",
    default=None,
    help="Scene labels (annotate --scenes): the label's scene; (object_id, grasp_id) repeats across "
    "scenes, so scene labels need it.",
    low=0,
)
@LABELS_GRIPPER_OPTION
@CACHE_OPTION
@overwrite_option("Replace a --gif this tool did not write or that was changed since.")
def replay_command(
    labels: Path,
    object_id: str,
    grasp_id: int,
    objects_dir: Path,
    gif_path: Path | None,
    gui: bool,
    hold: float | None,
    size: tuple[int, int],
    config_file: Path | None,
    scene: int | None,
    gripper: str | None,
    cache_dir: Path | None,
    overwrite: bool,
) -> None:
    """Execute one label with the UR3 and the labels' gripper in the seed's cell (table, Kinect)
    and say what happened.

    \b
    The object rests on the table: at the label's own placement (labels of `annotate --cell`), or,
    for a floating label, in the stable pose and turn about the vertical that makes the grasp
    approach most from above while the arm can still reach it. The arm goes from the pregrasp to
    the grasp through the closed-form IK solutions of the straight approach, the RG2 closes with
    its grip force, the arm lifts 10 cm. Printed: the placement, contacts during the approach,
    the width reached, whether the object came up and how far it moved in the hand.

    \b
    Examples:
      annotator replay labels/ --object box --grasp 3 --gif box3.gif
      annotator replay labels/ --object mug --grasp 17 --gui
    """
    from annotator.cell import build_cell
    from annotator.cell.execute import execute_plan, frames_every
    from annotator.objects import ObjectDiscoveryError, ObjectError, create_body, discover_objects
    from annotator.pipeline.prepare import load_prepared
    from annotator.render import write_gif
    from annotator.tools.common import (
        claim_outputs,
        labelling_config,
        labelling_gripper,
        one_row_per_grasp,
        read_labels,
    )
    from annotator.tools.replay import default_camera, find_label, plan_replay, replay_world

    claimed = claim_outputs("annotator replay", {"--gif": gif_path}, overwrite)
    chosen = labelling_config(labels, config_file)
    config = chosen.config
    table = one_row_per_grasp(read_labels(labels), labels, scene)  # scene labels: --scene N
    try:
        row = find_label(table, object_id, grasp_id)
    except KeyError as exc:
        raise click.UsageError(f"{labels}: {exc.args[0] if exc.args else exc}") from exc
    hand = labelling_gripper(labels, gripper, table)
    click.echo(chosen.line())
    click.echo(hand.line())
    from annotator.tools.gripper_check import check_before_work

    check_before_work(hand.description, config)
    try:
        sources = {s.object_id: s for s in discover_objects(objects_dir)}
    except ObjectDiscoveryError as exc:
        raise click.UsageError(f"--objects: {exc}") from exc
    if object_id not in sources:
        raise click.UsageError(f"object {object_id!r} is not in {objects_dir} (pass --objects DIR)")
    try:
        # its decomposition from the cache, made by a worker process if the cache does not hold it
        model = load_prepared(sources[object_id], config, float(row["object_scale"]), cache_dir)
    except ObjectError as exc:
        raise click.UsageError(f"{object_id}: {exc}") from exc
    if model.mesh_sha256 != row["mesh_sha256"]:
        click.echo(
            f"warning: {sources[object_id].path} changed since it was labelled (mesh hash differs)", err=True
        )

    width_mm = float(row["width"]) * 1000
    click.echo(f"label: {object_id} #{grasp_id}: {row['outcome']}, width {width_mm:.1f} mm")
    with replay_world(model, config, gui=gui) as world:  # a light object at its finer time step
        cell = build_cell(
            world,
            config.cell,
            gripper=config.gripper,
            kinect_config=config.kinect,
            description=hand.description,
        )
        obj = create_body(world.client, model)
        plan = plan_replay(cell, model, obj, row, config)
        click.echo(plan.note)
        if not plan.reach.reachable:
            click.echo(f"not reachable: {plan.reach.reason} ({plan.reach.detail})")
            return
        click.echo(f"arm: pregrasp {_fmt_q(plan.reach.q_pregrasp)} -> grasp {_fmt_q(plan.reach.q_grasp)}")
        camera = default_camera(plan.T_world_obj, size) if gif_path else None
        every = frames_every(world.dt)
        result = execute_plan(cell, obj, plan, config, camera=camera, frame_every=every, realtime=gui)
        if result.approach_contacts:
            click.echo("contact during the approach: " + "; ".join(result.approach_contacts))
        else:
            click.echo("contact during the approach: none")
        lift_mm = config.protocol.lift_height * 1000
        pads = f"{result.pads_touching} of 2 pads on the object"
        click.echo(f"closed: width {result.closed_width * 1000:.1f} mm, {pads}")
        came_up = "came up" if result.lifted(config.protocol.lift_height) else "did not come up"
        click.echo(
            f"lift: the object {came_up} ({result.rise * 1000:.0f} of {lift_mm:.0f} mm) and moved "
            f"{result.slip * 1000:.1f} mm in the hand; {result.pads_at_end} of 2 pads on it"
        )
        held = result.held(config.protocol.lift_height, config.protocol.max_slip)
        click.echo(f"verdict: {'held' if held else 'not held'} (the label says {row['outcome']})")
        if gif_path:
            fps = 1.0 / (every * world.dt)
            written = claimed.write("--gif", lambda tmp: write_gif(result.frames, tmp, fps=fps))
            click.echo(f"gif: {len(result.frames)} frames {size[0]}x{size[1]} -> {written}")
        if gui:
            _hold_window(world, hold)


def _hold_window(world, seconds: float | None) -> None:
    """Keep the GUI open (stepping, real time) until it is closed or ``seconds`` pass."""
    import time

    start = time.monotonic()
    while seconds is None or time.monotonic() - start < seconds:
        if not world.step_while_open():
            return
        time.sleep(world.dt)
