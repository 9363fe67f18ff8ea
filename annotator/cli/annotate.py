"""``annotate`` (= ``annotator annotate``): the batch job."""

from __future__ import annotations

from pathlib import Path

import click

from annotator import __version__
from annotator.cli.common import (
    CACHE_OPTION,
    CONFIG_OPTION,
    CONTEXT,
    GRIPPER_OPTION,
    MAX_SCENES,
    MAX_VIEWS,
    QUIET_OPTION,
    VERBOSE_OPTION,
    count_option,
    folder_option,
    load_config,
    objects_option,
    overwrite_option,
    run_pipeline,
    scale_option,
    seed_option,
    setup_logging,
    trials_option,
    workers_option,
)

# Grasps per scene unless --n says otherwise: VGN's GRASPS_PER_SCENE (scripts/generate_data.py).
SCENE_GRASPS = 120


@click.command(
    "annotate",
    context_settings=CONTEXT,
)
@objects_option(
    help="Folder of object meshes (.obj .stl .ply .off .glb) and object .urdf files, searched "
    "recursively. Units are metres."
)
@count_option(
    "--n",
    "n",
    default=None,
    high=1_000_000,
    help="Grasp candidates per object (every one becomes a row, failures included); with --scenes, "
    f"per scene [default: {SCENE_GRASPS}, as VGN].",
)
@folder_option(
    "--out",
    "out_dir",
    default=Path("labels"),
    show_default=True,
    help="Output folder: one Parquet file per object (chunk files while it runs) plus _manifest.json.",
)
@workers_option("Worker processes [default: all cores]. Labels do not depend on it.", high=None)
@seed_option("Seed of every random draw.")
@trials_option(
    "Trials per candidate: trial 0 (the label), then K-1 perturbed by [robust]'s execution "
    "uncertainty, which end at the lift unless [robust] shake = true; score = fraction that held."
)
@click.option(
    "--scheduler",
    default=None,
    metavar="ADDRESS",
    help="Dask scheduler (tcp://host:8786): run the same work on a cluster (needs the 'cluster' extra).",
)
@scale_option("Scale every mesh by this factor (0.001 for mm). Labels are in the scaled frame.")
@overwrite_option(
    "Discard the labels this tool wrote in --out and start over (other files are never touched)."
)
@click.option(
    "--repair",
    is_flag=True,
    help="Rebuild a lost or unreadable _manifest.json from the label files in --out that verify.",
)
@click.option(
    "--cell",
    is_flag=True,
    help="Objects rest on the seed's table in their stable poses (the table takes part in every "
    "collision check); extra columns: placement, object pose, UR3 reachability (q_grasp_0..5).",
)
@count_option(
    "--views",
    low=0,
    high=MAX_VIEWS,
    default=0,
    show_default=True,
    metavar="K",
    help="With --cell: K Kinect v2 views per placement (the seed's mount, then K-1 around the "
    "object): depth/colour/segmentation PNGs and camera tables in OUT/_views/. With --scenes: K "
    "views per scene on VGN's sphere.",
)
@count_option(
    "--scenes",
    default=None,
    high=MAX_SCENES,
    metavar="N",
    help="Label N scenes of several objects drawn from --objects and settled on the table, each grasp "
    "tried among its neighbours (docs/scenes.md); --n grasps per scene.",
)
@click.option(
    "--per-scene",
    "per_scene",
    default="5",
    show_default=True,
    metavar="K|A-B",
    callback=lambda ctx, param, value: _count_range(value, param),
    help="With --scenes: objects per scene, K or uniformly A..B.",
)
@click.option(
    "--arrangement",
    type=click.Choice(["pile", "packed", "table"]),
    default="pile",
    show_default=True,
    help="With --scenes: dropped in a pile, packed upright (VGN), or spread on the table (ACRONYM).",
)
@GRIPPER_OPTION
@CONFIG_OPTION
@CACHE_OPTION
@QUIET_OPTION
@VERBOSE_OPTION
@click.version_option(__version__, prog_name="annotate")
def annotate_command(
    objects_dir: Path,
    n: int,
    out_dir: Path,
    workers: int | None,
    seed: int,
    trials: int,
    scheduler: str | None,
    scale: float | None,
    overwrite: bool,
    repair: bool,
    cell: bool,
    views: int,
    scenes: int | None,
    per_scene: tuple[int, int],
    arrangement: str,
    gripper: str | None,
    config_file: Path | None,
    cache_dir: Path | None,
    quiet: bool,
    verbose: bool,
) -> None:
    """Sample N gripper poses around every object, simulate the gripper (the RG2 unless
    --gripper) grasping each one (close, lift, shake) and write one label row per candidate to
    Parquet.

    \b
    Example:
      annotate --objects objects/ --n 500
      python -c "import pandas; print(pandas.read_parquet('labels/').head())"
      annotate --objects objects/ --n 500 --cell --views 3 --out cell_labels/
      annotate --objects objects/ --n 500 --gripper panda --out panda_labels/
      annotate --objects objects/ --scenes 100 --per-scene 3-8 --views 2 --out scene_labels/

    \b
    Each object's convex decomposition runs first, in a worker, once per --cache (shared by
    runs and machines); labelling starts as soon as an object is ready.

    \b
    Labels are written every 10 candidates; re-running the same command resumes (finished
    objects and chunks are skipped, every file is checked against its checksum first), so
    Ctrl-C loses almost nothing. One run per --out at a time. A changed gripper, seed, N,
    trials, scale, configuration or version is refused (use --overwrite or another --out); an
    object whose file changed is redone alone.

    \b
    Exit codes:
      0    all objects done
      1    some objects failed (the others are written; reasons in the summary)
      2    usage error (bad option or config, folder in use, other settings in --out)
      3    the output folder cannot be written (disk full, read-only, permission)
      4    the Dask scheduler was lost (re-run to resume)
      130  interrupted (Ctrl-C); 143 terminated (SIGTERM); re-run to resume
    """
    setup_logging(quiet, verbose)
    config = load_config(config_file)
    from annotator.confidence import trials_mismatch

    if trials_mismatch(config, trials):
        raise click.UsageError(f"--config {config_file}: {trials_mismatch(config, trials)}")
    if overwrite and repair:
        raise click.UsageError("--overwrite and --repair exclude each other")
    if views and not (cell or scenes):
        raise click.UsageError("--views renders the robot cell's Kinect: it needs --cell or --scenes")
    if n is None and not scenes:
        raise click.UsageError("Missing option '--n' (grasp candidates per object).")
    for name, flag in (("per_scene", "--per-scene"), ("arrangement", "--arrangement")):
        given = click.get_current_context().get_parameter_source(name) != click.core.ParameterSource.DEFAULT
        if given and not scenes:
            raise click.UsageError(f"{flag} shapes the scenes of --scenes N: it needs --scenes")
    from annotator.pipeline.object_job import ObjectOptions
    from annotator.pipeline.scene_job import SceneOptions

    if gripper is not None:
        from annotator.tools.gripper_check import check_before_work

        check_before_work(gripper, config)  # a user's gripper: its physics checked before any work
    own: ObjectOptions | SceneOptions = ObjectOptions(cell=cell, views=views)
    if scenes:
        own = SceneOptions(scenes, per_scene, arrangement, views=views, cell=cell)
    run_pipeline(
        "annotate",
        objects_dir=objects_dir,
        n=n if n is not None else SCENE_GRASPS,
        out_dir=out_dir,
        workers=workers,
        seed=seed,
        trials=trials,
        scheduler=scheduler,
        scale=scale,
        overwrite=overwrite,
        repair=repair,
        quiet=quiet,
        gripper=gripper,
        cache_dir=cache_dir,
        config=config,
        own=own,
    )


def _count_range(value: str, param: click.Parameter) -> tuple[int, int]:
    """``K`` or ``A-B`` (1 <= A <= B) as (A, B); a bad value is a usage error."""
    parts = str(value).split("-")
    try:
        lo, hi = (int(parts[0]), int(parts[-1])) if len(parts) in (1, 2) else (0, -1)
    except ValueError:
        lo, hi = 0, -1
    if not 1 <= lo <= hi:
        raise click.BadParameter(f"expected K or A-B with 1 <= A <= B, got {value!r}", param=param)
    return lo, hi
