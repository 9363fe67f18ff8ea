"""Thin click commands of the tools: replay, show, report, export, evaluate, calibrate.

Each parses its options, calls the library function and turns bad input into one line
(:class:`annotator.tools.common.ToolError`, exit code 2, or click's usage error). Heavy imports
happen inside the commands so that ``annotator --help`` stays fast. ``COMMANDS`` lists them for
:mod:`annotator.cli`.
"""

from __future__ import annotations

import logging
from pathlib import Path

import click
import numpy as np

from annotator.config import AnnotatorConfig, ConfigError
from annotator.tools import calibrate as cal

log = logging.getLogger(__name__)


def _fmt_q(q: np.ndarray) -> str:
    return "[" + ", ".join(f"{v:.3f}" for v in q) + "]"


@click.command("replay", context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.argument("labels", type=click.Path(path_type=Path, exists=True))
@click.option("--object", "object_id", required=True, help="The label's object_id.")
@click.option("--grasp", "grasp_id", required=True, type=int, help="The label's grasp_id.")
@click.option(
    "--objects",
    "objects_dir",
    default=Path("objects"),
    show_default=True,
    type=click.Path(path_type=Path, file_okay=False),
    help="The folder the labels were made from (the object is found there by its id).",
)
@click.option(
    "--gif", "gif_path", type=click.Path(dir_okay=False, path_type=Path), help="Write the replay as a GIF."
)
@click.option("--gui", is_flag=True, help="Show the replay in the PyBullet GUI at real time.")
@click.option(
    "--hold",
    type=click.FloatRange(min=0),
    default=None,
    help="GUI: keep the window this many seconds after the replay [default: until it is closed].",
)
@click.option(
    "--size", default=(320, 240), show_default=True, type=(int, int), help="GIF frame width height."
)
@click.option(
    "--config",
    "config_file",
    type=click.Path(path_type=Path, dir_okay=False, exists=True),
    help="The TOML file the labels were made with (physics, gripper, protocol, cell).",
)
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
) -> None:
    """Execute one label with the UR3 + RG2 in the seed's cell (table, Kinect) and say what happened.

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
    from annotator.dataset import SchemaError, load_labels
    from annotator.objects import (
        ObjectDiscoveryError,
        ObjectError,
        create_body,
        discover_objects,
        load_object,
    )
    from annotator.render import write_gif
    from annotator.tools.replay import (
        default_camera,
        frames_every,
        label_row,
        plan_replay,
        replay,
        replay_world,
    )

    try:
        config = AnnotatorConfig.from_toml(config_file) if config_file else AnnotatorConfig()
    except (ConfigError, OSError) as exc:
        raise click.UsageError(f"--config {config_file}: {exc}") from exc
    try:
        row = label_row(load_labels(labels), object_id, grasp_id)
    except (FileNotFoundError, SchemaError, KeyError) as exc:
        raise click.UsageError(f"{labels}: {exc.args[0] if exc.args else exc}") from exc
    try:
        sources = {s.object_id: s for s in discover_objects(objects_dir)}
    except ObjectDiscoveryError as exc:
        raise click.UsageError(f"--objects: {exc}") from exc
    if object_id not in sources:
        raise click.UsageError(f"object {object_id!r} is not in {objects_dir} (pass --objects DIR)")
    try:
        model = load_object(sources[object_id], config.objects, scale=float(row["object_scale"]))
    except ObjectError as exc:
        raise click.UsageError(f"{object_id}: {exc}") from exc
    if model.mesh_sha256 != row["mesh_sha256"]:
        click.echo(
            f"warning: {sources[object_id].path} changed since it was labelled (mesh hash differs)", err=True
        )

    width_mm = float(row["width"]) * 1000
    click.echo(f"label: {object_id} #{grasp_id}: {row['outcome']}, width {width_mm:.1f} mm")
    with replay_world(model, config, gui=gui) as world:  # a light object at its finer time step
        cell = build_cell(world, config.cell, gripper=config.gripper, kinect_config=config.kinect)
        obj = create_body(world.client, model)
        plan = plan_replay(cell, model, obj, row, config)
        click.echo(plan.note)
        if not plan.reach.reachable:
            click.echo(f"not reachable: {plan.reach.reason} ({plan.reach.detail})")
            return
        click.echo(f"arm: pregrasp {_fmt_q(plan.reach.q_pregrasp)} -> grasp {_fmt_q(plan.reach.q_grasp)}")
        camera = default_camera(plan.T_world_obj, size) if gif_path else None
        every = frames_every(world.dt)
        result = replay(cell, obj, plan, config, camera=camera, frame_every=every, realtime=gui)
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
            write_gif(result.frames, gif_path, fps=1.0 / (every * world.dt))
            click.echo(f"gif: {len(result.frames)} frames {size[0]}x{size[1]} -> {gif_path}")
        if gui:
            _hold_window(world, hold)


def _hold_window(world, seconds: float | None) -> None:
    """Keep the GUI open (stepping, real time) until it is closed or ``seconds`` pass."""
    import time

    from annotator.sim import pb

    start = time.monotonic()
    while seconds is None or time.monotonic() - start < seconds:
        try:
            pb.stepSimulation(physicsClientId=world.client)
        except pb.error:
            return
        time.sleep(world.dt)


# annotator.dataset.OUTCOMES, spelled out so that `annotator --help` does not import pandas
# (tests/tools/test_show.py checks they are the same)
OUTCOMES = ("success", "collision", "no_contact", "slipped_lift", "slipped_shake", "error")
CONTEXT = {"help_option_names": ["-h", "--help"], "max_content_width": 100}
LABELS = click.argument("labels", type=click.Path(path_type=Path))
OBJECTS_OPTION = click.option(
    "--objects",
    "objects_dir",
    type=click.Path(path_type=Path, file_okay=False),
    default=None,
    help="The folder the labels were made from (annotate --objects): where the object meshes are.",
)


def _logging(verbose: bool) -> None:
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.WARNING, format="%(levelname)s %(name)s: %(message)s"
    )


@click.command("show", context_settings=CONTEXT)
@LABELS
@click.option("--object", "object_id", required=True, help="Object id, as in the labels' object_id column.")
@click.option(
    "--png", "png", required=True, type=click.Path(path_type=Path, dir_okay=False), help="Sheet to write."
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
@click.option(
    "--n", "n", default=8, show_default=True, type=click.IntRange(min=1), help="Grasps on the sheet."
)
@click.option("--seed", default=0, show_default=True, help="Seed of the random choice of grasps.")
@click.option(
    "--overview",
    "overview_png",
    type=click.Path(path_type=Path, dir_okay=False),
    default=None,
    help="Overview picture to write [default: <png>-overview.png].",
)
@OBJECTS_OPTION
@click.option("--verbose", "-v", is_flag=True, help="Debug logging.")
def show_command(labels, object_id, png, outcomes, grasp_ids, n, seed, overview_png, objects_dir, verbose):
    """Pictures of labelled grasps: the RG2 at each label's pose and width around the object.

    Writes a sheet of N grasps (front and side view each, titled with grasp id, outcome and
    width) and an overview of every grasp of the object as a small gripper glyph coloured by
    outcome (parts behind the object faint).

    \b
    Example:
      annotator show labels/ --object mug --objects objects/ --png mug.png
      annotator show labels/ --object mug --objects objects/ --outcome success --n 4 --png ok.png
    """
    _logging(verbose)
    from annotator.tools.show import show

    result = show(
        labels, object_id, png, n, seed, tuple(outcomes), tuple(grasp_ids), objects_dir, overview_png
    )
    click.echo(f"wrote {result.sheet} ({result.n_grasps} grasps) and {result.overview}")


@click.command("report", context_settings=CONTEXT)
@LABELS
@click.option(
    "--html",
    "html_path",
    required=True,
    type=click.Path(path_type=Path, dir_okay=False),
    help="The report to write (one file; open it in any browser, offline).",
)
@OBJECTS_OPTION
@click.option(
    "--pictures",
    "picture_objects",
    default=3,
    show_default=True,
    type=click.IntRange(min=0),
    help="Objects shown with pictures (those with the most successes); 0 for none.",
)
@click.option("--verbose", "-v", is_flag=True, help="Debug logging.")
def report_command(labels, html_path, objects_dir, picture_objects, verbose):
    """A dataset at a glance: one self-contained HTML file (pictures embedded, no network).

    The run's configuration and versions (from _manifest.json), objects that failed and why,
    per-object success rates and outcome mix with mass and collision error, width and score
    histograms, the distribution of approach directions and pictures of a few objects (they
    need the meshes: --objects, the folder the labels were made from).

    \b
    Example:
      annotator report labels/ --objects objects/ --html report.html
    """
    _logging(verbose)
    from annotator.tools.report import report

    result = report(labels, html_path, objects_dir, picture_objects)
    counts = f"{result.n_objects} objects, {result.n_grasps} grasps, {result.pictures} pictures"
    click.echo(f"wrote {result.path}: {counts}")


@click.command("export", context_settings=CONTEXT)
@LABELS
@click.option(
    "--format",
    "fmt",
    required=True,
    type=click.Choice(["acronym", "graspgen"]),
    help="acronym: one HDF5 file per object (needs h5py: the 'export' extra); graspgen: one JSON per object.",
)
@click.option("--out", "out_dir", required=True, type=click.Path(path_type=Path, file_okay=False))
@OBJECTS_OPTION
@click.option("--object", "object_ids", multiple=True, help="Only this object (repeat for several).")
@click.option("--verbose", "-v", is_flag=True, help="Debug logging.")
def export_command(labels, fmt, out_dir, objects_dir, object_ids, verbose):
    """The labels in the formats existing grasp learners read, with each object's mesh.

    Both formats store the pose of the RG2's base frame (rg2_base_link: on the tool flange,
    +z approach, +x closing), not our TCP: T_obj_base = T_obj_tcp * T_base_tcp(width)^-1, with
    the width of each grasp stored beside it (docs/tools.md, "Export").

    \b
    Example:
      annotator export labels/ --format acronym --objects objects/ --out acronym/
      annotator export labels/ --format graspgen --objects objects/ --out graspgen/
    """
    _logging(verbose)
    from annotator.tools.export import export

    result = export(labels, fmt, out_dir, objects_dir, tuple(object_ids))
    click.echo(
        f"wrote {len(result.files)} {fmt} files ({result.n_grasps} grasps) and their meshes to {out_dir}"
    )


def _floats(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise click.BadParameter(f"{text!r}: comma-separated numbers, e.g. 0.3,0.45,0.6") from None
    if not values or any(not np.isfinite(v) or v <= 0 for v in values):
        raise click.BadParameter(f"{text!r}: positive numbers, e.g. 0.3,0.45,0.6")
    return values


@click.command("calibrate", context_settings=CONTEXT)
@LABELS
@click.argument("real_csv", type=click.Path(path_type=Path, dir_okay=False))
@click.option(
    "--objects",
    "objects_dir",
    required=True,
    type=click.Path(path_type=Path, file_okay=False),
    help="The folder the labels were made from (annotate --objects).",
)
@click.option(
    "--friction",
    default=",".join(map(str, cal.DEFAULT_FRICTIONS)),
    show_default=True,
    help="Pad friction coefficients to try.",
)
@click.option(
    "--force",
    default=",".join(f"{f:g}" for f in cal.DEFAULT_FORCES),
    show_default=True,
    help="Grip forces (N) to try; ignored when REAL.csv has a grip_force column.",
)
@click.option(
    "--severity",
    default=",".join(map(str, cal.DEFAULT_SEVERITIES)),
    show_default=True,
    help="Shake severities to try: factors on the shake's amplitude and angle.",
)
@click.option(
    "--write-config",
    "config_out",
    default=Path("calibrated.toml"),
    show_default=True,
    type=click.Path(path_type=Path, dir_okay=False),
    help="Where to write the best setting as a TOML file for annotate --config.",
)
@click.option(
    "--workers", type=click.IntRange(min=1), default=None, help="Worker processes [default: all cores]."
)
@click.option("--seed", default=0, show_default=True, help="Seed of the bootstrap resampling.")
@click.option("--verbose", "-v", is_flag=True, help="Debug logging.")
def calibrate_command(
    labels, real_csv, objects_dir, friction, force, severity, config_out, workers, seed, verbose
):
    """Fit pad friction, grip force and shake severity to real trials of labelled grasps.

    REAL.csv has one row per grasp executed on the real UR3 + RG2: object_id, grasp_id (of the
    labels), real_success (1/0), and optionally grip_force (N, the force used). Every trial is
    re-simulated under every setting of the grid; the agreement with the real outcomes
    (accuracy, precision and recall of success, with 95 % bootstrap intervals) is printed per
    setting, and the best setting is written as a TOML file for annotate --config.

    \b
    Example:
      annotator calibrate labels/ real_trials.csv --objects objects/
      annotate --objects objects/ --n 500 --config calibrated.toml --out labels_calibrated/
    """
    _logging(verbose)
    import os

    from annotator.tools.common import labelling_config, read_labels

    frictions, forces, severities = _floats(friction), _floats(force), _floats(severity)
    labels_df = read_labels(labels)
    trials = cal.read_real_trials(real_csv, labels_df)
    base = labelling_config(labels)
    settings = cal.grid(frictions, forces, severities, real_force="grip_force" in trials.columns)
    click.echo(
        f"{len(trials)} real trials ({int(trials.real_success.sum())} held) on {trials.object_id.nunique()} "
        f"objects; {len(settings)} settings, {len(settings) * len(trials)} simulated grasps"
    )
    result = cal.calibrate(trials, base, objects_dir, settings, workers or os.cpu_count() or 1, seed)
    click.echo(cal.format_table(result))
    b, a = result.best, result.best_agreement
    force_text = "each trial's own force" if b.force is None else f"{b.force:g} N"
    click.echo(
        f"best: pad friction {b.friction:g}, {force_text}, shake x{b.severity:g}: accuracy "
        f"{100 * a.accuracy:.1f} % [{100 * a.accuracy_ci[0]:.0f}, {100 * a.accuracy_ci[1]:.0f}] "
        f"over {a.n} trials"
    )
    header = (
        f"annotator calibrate {labels} {real_csv}: best of {len(settings)} settings over {a.n} real trials\n"
        f"accuracy {a.accuracy:.3f} (95 % CI {a.accuracy_ci[0]:.3f}..{a.accuracy_ci[1]:.3f}), "
        f"precision {a.precision:.3f}, recall {a.recall:.3f}\n"
        "use: annotate --objects DIR --n N --config THIS_FILE"
    )
    config_out.write_text(cal.config_toml(result.config, header), encoding="utf-8")
    click.echo(f"wrote {config_out}")


@click.command("evaluate", context_settings=CONTEXT)
@click.argument("grasps_file", metavar="GRASPS", type=click.Path(path_type=Path, dir_okay=False))
@click.option(
    "--objects",
    "objects_dir",
    required=True,
    type=click.Path(path_type=Path, file_okay=False),
    help="Folder of the objects the grasps refer to (object_id = path without suffix, as annotate).",
)
@click.option(
    "--out",
    "out_dir",
    required=True,
    type=click.Path(path_type=Path, file_okay=False),
    help="Output folder: label files (one per object) and _manifest.json, as annotate writes.",
)
@click.option(
    "--workers", type=click.IntRange(min=1), default=None, help="Worker processes [default: all cores]."
)
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the perturbed trials.")
@click.option(
    "--trials", type=click.IntRange(min=1), default=1, show_default=True, help="Perturbed trials per grasp."
)
@click.option("--scheduler", default=None, metavar="ADDRESS", help="Dask scheduler (tcp://host:8786).")
@click.option(
    "--scale", type=float, default=None, help="Scale every mesh by this factor (as annotate --scale)."
)
@click.option("--overwrite", is_flag=True, help="Discard existing labels in --out and start over.")
@click.option(
    "--config",
    "config_file",
    type=click.Path(path_type=Path, dir_okay=False, exists=True),
    default=None,
    help="TOML file overriding constants, as for annotate.",
)
@click.option("--quiet", "-q", is_flag=True, help="No progress bar; warnings and the summary only.")
@click.option("--verbose", "-v", is_flag=True, help="Debug logging.")
def evaluate_command(
    grasps_file,
    objects_dir,
    out_dir,
    workers,
    seed,
    trials,
    scheduler,
    scale,
    overwrite,
    config_file,
    quiet,
    verbose,
):
    """Simulate grasps someone else proposed with annotate's protocol; write label columns.

    GRASPS is a Parquet or CSV file with object_id, the TCP pose as the labels give it (x y z,
    qx qy qz qw in the object's mesh frame, metres, xyzw) and optionally width (m, the opening at
    the grasp; measured on the mesh when missing) and grasp_id. The output is what annotate
    writes (same columns, resume, determinism, workers); grasps keep their grasp_id when those
    are 0..k-1 per object, else they are numbered in the order of the file.

    \b
    Example:
      annotator evaluate predictions.parquet --objects objects/ --out evaluated/
      python -c "import pandas; print(pandas.read_parquet('evaluated/').outcome.value_counts())"

    Exit codes as annotate's: 0 all objects done, 1 some failed, 2 usage error, 3 output
    folder not writable, 4 Dask scheduler lost, 130/143 interrupted (re-run to resume).
    """
    from annotator.cli import run_pipeline

    _logging(verbose)
    from annotator.config import AnnotatorConfig
    from annotator.pipeline.worker import max_width
    from annotator.tools.evaluate import given_candidates, read_grasps

    try:
        config = AnnotatorConfig.from_toml(config_file) if config_file else AnnotatorConfig()
    except (ValueError, OSError) as exc:
        raise click.UsageError(f"--config {config_file}: {exc}") from exc
    grasps = read_grasps(grasps_file)
    if not Path(objects_dir).is_dir():
        raise click.UsageError(f"objects folder not found: {objects_dir}")
    candidates, renumbered = given_candidates(grasps, objects_dir, config, scale, max_width(config))
    if renumbered:
        click.echo(f"grasp ids of {len(renumbered)} object(s) renumbered 0..k-1 in file order", err=True)
    run_pipeline(
        "evaluate",
        objects_dir=objects_dir,
        n=max(candidates.counts.values()),
        out_dir=out_dir,
        workers=workers,
        seed=seed,
        trials=trials,
        scheduler=scheduler,
        scale=scale,
        overwrite=overwrite,
        repair=False,
        quiet=quiet,
        config=config,
        candidates=candidates,
    )


COMMANDS = [replay_command, show_command, report_command, export_command, evaluate_command, calibrate_command]
