"""``annotator clutter-removal``: VGN's clutter-removal benchmark on the seed's UR3."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import click

from annotator.cli.common import (
    CONFIG_OPTION,
    CONTEXT,
    VERBOSE_OPTION,
    folder_option,
    load_config,
    objects_option,
    overwrite_option,
    seed_option,
    setup_logging,
    trials_option,
    workers_option,
)

OUTPUTS = ("rounds.csv", "grasps.csv")


def _parse_args(pairs: tuple[str, ...]) -> tuple[tuple[str, str], ...]:
    from annotator.tools.common import ToolError

    out = []
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key.isidentifier():
            raise ToolError(f"--policy-arg {pair}: give KEY=VALUE (KEY a Python name)")
        out.append((key, value))
    keys = [k for k, _ in out]
    if len(set(keys)) != len(keys):
        raise ToolError(f"--policy-arg: {sorted({k for k in keys if keys.count(k) > 1})} given twice")
    return tuple(out)


def claim_out(out_dir: Path, overwrite: bool):
    """``--out DIR`` held for this run with the store's lock (a second clutter-removal on it is
    refused naming the first) and its rounds.csv and grasps.csv claimed (:func:`annotator.tools.
    common.claim_outputs`: a file this tool did not write, or one changed since, only with
    ``overwrite``); the claims end with the command. Returns the claimed outputs."""
    from annotator.store.lock import RunLock
    from annotator.tools.common import acquire_output_lock, check_output_dir, claim_outputs

    out_dir = check_output_dir(out_dir, "--out")
    lock = RunLock(out_dir)
    acquire_output_lock(lock)
    click.get_current_context().call_on_close(lock.release)
    return claim_outputs("annotator clutter-removal", {name: out_dir / name for name in OUTPUTS}, overwrite)


def _workspace(config):
    """The piles' workspace (table frame) on the configured cell."""
    from annotator.cell.world import build_cell
    from annotator.scenes.arrange import workspace_on
    from annotator.sim.world import World

    with World() as world:
        cell = build_cell(world, config.cell, robot=False, kinect=False)
        return workspace_on(cell, config.scenes)


@click.command("clutter-removal", context_settings=CONTEXT)
@objects_option(help="Folder of objects the piles are drawn from (as annotate --objects).")
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
    "--arrangement",
    type=click.Choice(["pile", "packed"]),
    default="pile",
    show_default=True,
    help="VGN's two scenes: dropped in a pile, or packed upright (round r is scene r of annotate "
    "--scenes --arrangement A).",
)
@click.option(
    "--policy",
    default="labels",
    show_default=True,
    metavar="labels|random|vision-random|learned|MODULE:FUNCTION|NAME|FILE",
    help="labels: the best-scored reachable label of the scene as it is (an oracle on the true "
    "meshes); random: a random collision-free reachable antipodal grasp on the true meshes; "
    "vision-random: a random antipodal pair on the observed point cloud that the open gripper "
    "clears; learned: the classifier of `annotator learn train` (--policy-arg model=PATH); "
    "MODULE:FUNCTION or an entry point NAME of the group rg2_annotator.policies: your policy, called "
    "with what the Kinect sees at every attempt (docs/learning.md); FILE: a learner's predictions, a "
    "CSV or Parquet file with columns round, x, y, z, qx, qy, qz, qw (TCP in the table frame), "
    "width, score.",
)
@click.option(
    "--policy-arg",
    "policy_args",
    multiple=True,
    metavar="KEY=VALUE",
    help="Passed to a vision policy as keyword argument KEY (a string); repeat for more.",
)
@click.option(
    "--views",
    type=click.IntRange(min=1, max=100),
    default=1,
    show_default=True,
    help="Depth views a vision policy sees at every attempt (views 0..K-1 of the scene, as annotate "
    "--views renders them).",
)
@seed_option("Round r is scene r of annotate --scenes.")
@trials_option("labels policy: trials per grasp (--trials of annotate); the best score wins.")
@workers_option("Processes [default: all cores]; rounds in parallel.")
@folder_option(
    "--out",
    "out_dir",
    default=None,
    help="Write rounds.csv and grasps.csv (one row per attempt) here.",
)
@overwrite_option("Replace a rounds.csv or grasps.csv in --out that clutter-removal did not write.")
@CONFIG_OPTION
@VERBOSE_OPTION
def clutter_removal_command(
    objects_dir,
    rounds,
    per_scene,
    arrangement,
    policy,
    policy_args,
    views,
    seed,
    trials,
    workers,
    out_dir,
    overwrite,
    config_file,
    verbose,
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
      annotator clutter-removal --objects objects/ --rounds 20 --policy vision-random --out cr_vision/
      annotator clutter-removal --objects objects/ --rounds 20 --policy learned --policy-arg model=model.npz
      annotator clutter-removal --objects objects/ --rounds 20 --policy my_package.policy:grasps
    """
    setup_logging(False, verbose, default=logging.WARNING)
    from annotator.objects import ObjectDiscoveryError, ObjectError, default_cache_dir, discover_objects
    from annotator.pipeline.in_memory import ExecutionOptions
    from annotator.pipeline.worker_spawn import detach_local_workers
    from annotator.policies import PolicyError
    from annotator.policies.clutter import ClutterSetup
    from annotator.policies.loop import check_signature
    from annotator.policies.predictions import check_predictions, read_predictions
    from annotator.policies.resolve import ORACLES, is_vision_policy, load_callable
    from annotator.tools.clutter_runs import run_clutter_removal
    from annotator.tools.common import ToolError

    config = load_config(config_file)
    claimed = claim_out(out_dir, overwrite) if out_dir is not None else None
    args = _parse_args(policy_args)
    name = policy
    vision = policy not in ORACLES and is_vision_policy(policy)
    if args and not vision:
        raise ToolError("--policy-arg: only a vision policy takes arguments")
    try:
        if vision:
            from annotator.learn.policy import learned, learned_model

            check_signature(load_callable(policy), dict(args))
            if load_callable(policy) is learned:  # its model read before any work
                learned_model(dict(args).get("model"))
        elif policy not in ORACLES:
            path = Path(policy)
            if not path.is_file():
                raise ToolError(
                    f"--policy {policy}: not labels, random, vision-random, a policy (module:function "
                    "or an entry point) or a predictions file"
                )
            name = f"from {policy}"
            policy = read_predictions(path)
            from annotator.grippers import load_gripper

            stroke = load_gripper(None).stroke_max  # the arm's gripper (clutter-removal takes no --gripper)
            missing = check_predictions(policy, rounds, _workspace(config), stroke, name=str(path))
            if missing:
                logging.getLogger("annotator").warning(
                    "%s: no row for round(s) %s: they end at once", path, missing[:10]
                )
    except (PolicyError, ValueError) as exc:
        raise ToolError(str(exc)) from None
    try:
        sources = tuple(discover_objects(objects_dir, config.objects))
    except ObjectDiscoveryError as exc:
        raise ToolError(str(exc)) from None
    job = ClutterSetup(
        sources,
        per_scene,
        seed,
        policy,
        config,
        trials,
        cache_dir=str(default_cache_dir()),
        policy_args=args,
        views=views,
        arrangement=arrangement,
    )
    detach_local_workers()  # a Ctrl-C reaches this process only
    try:
        summary = run_clutter_removal(job, rounds, ExecutionOptions(workers or os.cpu_count() or 1))
    except ObjectError as exc:
        raise ToolError(f"an object of the piles cannot be loaded: {exc}") from None
    except PolicyError as exc:
        raise ToolError(f"--policy {name}: {exc}") from None
    for line in summary.lines(name):
        click.echo(line)
    if claimed is not None:
        tables = dict(zip(OUTPUTS, summary.tables(), strict=True))
        written = [
            claimed.write(name, lambda tmp, t=table: t.to_csv(tmp, index=False))
            for name, table in tables.items()
        ]
        click.echo(f"wrote {written[0]} and {written[1]}")
