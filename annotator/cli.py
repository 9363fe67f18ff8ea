"""Command line: ``annotate`` (the batch job) and ``annotator <subcommand>`` (job, scene, ...)."""

from __future__ import annotations

import logging
import math
import os
import sys
from pathlib import Path

import click

from annotator import __version__
from annotator.config import AnnotatorConfig

EXIT_OK, EXIT_SOME_FAILED, EXIT_USAGE = 0, 1, 2
EXIT_OUTPUT = 3  # the output folder cannot be written (disk full, read-only, permission)
EXIT_SCHEDULER = 4  # the Dask scheduler was lost
EXIT_INTERRUPTED = 130  # 128 + SIGINT, the shell convention
EXIT_TERMINATED = 143  # 128 + SIGTERM


def _positive_finite(param: click.Parameter, value: float | None) -> float | None:
    """Reject 0, negative, inf and nan at the command line (exit 2), not per object later."""
    if value is not None and not (math.isfinite(value) and value > 0):
        raise click.BadParameter(f"must be a finite number > 0, got {value}", param=param)
    return value


class _QuietLibraries(logging.Filter):
    """Dask and tornado log their own connection trouble, tracebacks included; the run says what
    matters in one line (a lost scheduler, a dead worker). ``--verbose`` shows everything."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not record.name.startswith(("distributed", "tornado")) or record.levelno >= logging.CRITICAL


def _setup_logging(quiet: bool, verbose: bool) -> None:
    level = logging.WARNING if quiet else (logging.DEBUG if verbose else logging.INFO)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    if not verbose:
        for handler in logging.getLogger().handlers:
            handler.addFilter(_QuietLibraries())


@click.command(
    "annotate",
    context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100},
)
@click.option(
    "--objects",
    "objects_dir",
    required=True,
    type=click.Path(path_type=Path, file_okay=False),
    help="Folder of object meshes (.obj .stl .ply .off .glb) and object .urdf files, searched "
    "recursively. Units are metres.",
)
@click.option(
    "--n",
    "n",
    required=True,
    type=click.IntRange(min=1, max=1_000_000),
    help="Grasp candidates per object (every one becomes a row, failures included).",
)
@click.option(
    "--out",
    "out_dir",
    default=Path("labels"),
    show_default=True,
    type=click.Path(path_type=Path, file_okay=False),
    help="Output folder: one Parquet file per object (chunk files while it runs) plus _manifest.json.",
)
@click.option(
    "--workers",
    type=click.IntRange(min=1),
    default=None,
    help="Worker processes [default: all cores]. Labels do not depend on it.",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of every random draw.")
@click.option(
    "--trials",
    type=click.IntRange(min=1),
    default=1,
    show_default=True,
    help="Perturbed trials per candidate; score = fraction that held.",
)
@click.option(
    "--scheduler",
    default=None,
    metavar="ADDRESS",
    help="Dask scheduler (tcp://host:8786): run the same work on a cluster (needs the 'cluster' extra).",
)
@click.option(
    "--scale",
    type=float,
    default=None,
    callback=lambda ctx, param, value: _positive_finite(param, value),
    help="Scale every mesh by this factor (0.001 for mm). Labels are in the scaled frame.",
)
@click.option(
    "--overwrite",
    is_flag=True,
    help="Discard the labels this tool wrote in --out and start over (other files are never touched).",
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
@click.option(
    "--views",
    type=click.IntRange(min=0),
    default=0,
    show_default=True,
    metavar="K",
    help="With --cell: K Kinect v2 views per placement (the seed's mount, then K-1 around the "
    "object): depth/colour/segmentation PNGs and camera tables in OUT/_views/.",
)
@click.option(
    "--config",
    "config_file",
    type=click.Path(path_type=Path, dir_okay=False, exists=True),
    default=None,
    help="TOML file overriding constants by section, e.g. [protocol] lift_height = 0.15.",
)
@click.option("--quiet", "-q", is_flag=True, help="No progress bar; warnings and the summary only.")
@click.option("--verbose", "-v", is_flag=True, help="Debug logging.")
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
    config_file: Path | None,
    quiet: bool,
    verbose: bool,
) -> None:
    """Sample N gripper poses around every object, simulate the RG2 grasping each one
    (close, lift, shake) and write one label row per candidate to Parquet.

    \b
    Example:
      annotate --objects objects/ --n 500
      python -c "import pandas; print(pandas.read_parquet('labels/').head())"
      annotate --objects objects/ --n 500 --cell --views 3 --out cell_labels/

    \b
    Labels are written every 10 candidates; re-running the same command resumes (finished
    objects and chunks are skipped, every file is checked against its checksum first), so
    Ctrl-C loses almost nothing. One run per --out at a time. A changed seed, N, trials, scale,
    configuration or version is refused (use --overwrite or another --out); an object whose
    file changed is redone alone.

    \b
    Exit codes:
      0    all objects done
      1    some objects failed (the others are written; reasons in the summary)
      2    usage error (bad option or config, folder in use, other settings in --out)
      3    the output folder cannot be written (disk full, read-only, permission)
      4    the Dask scheduler was lost (re-run to resume)
      130  interrupted (Ctrl-C); 143 terminated (SIGTERM); re-run to resume
    """
    _setup_logging(quiet, verbose)
    try:
        config = AnnotatorConfig.from_toml(config_file) if config_file else AnnotatorConfig()
    except (ValueError, OSError) as exc:
        raise click.UsageError(f"--config {config_file}: {exc}") from exc
    if overwrite and repair:
        raise click.UsageError("--overwrite and --repair exclude each other")
    if views and not cell:
        raise click.UsageError("--views renders the robot cell's Kinect: it needs --cell")
    run_pipeline(
        "annotate",
        objects_dir=objects_dir,
        n=n,
        out_dir=out_dir,
        workers=workers,
        seed=seed,
        trials=trials,
        scheduler=scheduler,
        scale=scale,
        overwrite=overwrite,
        repair=repair,
        quiet=quiet,
        cell=cell,
        views=views,
        config=config,
    )


def run_pipeline(
    command: str, *, config: AnnotatorConfig, candidates=None, workers: int | None, **options
) -> None:
    """Run the job's pipeline (``annotate``, or ``evaluate`` with given ``candidates``) and exit
    with the documented code; problems are one line prefixed with ``command``."""
    from annotator.pipeline.run import RunOptions, SchedulerLost, Terminated, UsageError, run
    from annotator.store import OutputError

    run_options = RunOptions(workers=workers or os.cpu_count() or 1, **options)
    try:
        summary = run(run_options, config, candidates)
    except UsageError as exc:
        raise click.UsageError(str(exc)) from exc
    except OutputError as exc:
        click.echo(f"{command}: {exc}", err=True)
        sys.exit(EXIT_OUTPUT)
    except SchedulerLost as exc:
        click.echo(f"{command}: {exc} ({run_options.scheduler}); re-run the same command to resume", err=True)
        sys.exit(EXIT_SCHEDULER)
    except KeyboardInterrupt:
        # Ctrl-C: finished work is on disk; exit 130 (128 + SIGINT), not click's "Aborted!" + 1,
        # which would read as "some objects failed".
        click.echo(f"{command}: interrupted; re-run the same command to resume", err=True)
        sys.exit(EXIT_INTERRUPTED)
    except Terminated:
        click.echo(f"{command}: terminated; re-run the same command to resume", err=True)
        sys.exit(EXIT_TERMINATED)
    sys.exit(EXIT_OK if not summary.failed else EXIT_SOME_FAILED)


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
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
    """


main.add_command(annotate_command)


def _register_optional_commands() -> None:
    from annotator.scene import scene_command
    from annotator.tools.commands import COMMANDS

    main.add_command(scene_command)
    for command in COMMANDS:
        main.add_command(command)


_register_optional_commands()


def annotate_main() -> None:
    """Entry point of the ``annotate`` console script (``annotator annotate``)."""
    annotate_command()
