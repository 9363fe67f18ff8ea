"""What every command shares: exit codes, logging, option types, reading a configuration file,
running the labelling pipeline with the documented exit codes."""

from __future__ import annotations

import contextlib
import logging
import math
import os
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any, NoReturn

import click

EXIT_OK, EXIT_SOME_FAILED, EXIT_USAGE = 0, 1, 2
EXIT_OUTPUT = 3  # the output folder cannot be written (disk full, read-only, permission)
EXIT_SCHEDULER = 4  # the Dask scheduler was lost
EXIT_INTERRUPTED = 130  # 128 + SIGINT, the shell convention
EXIT_TERMINATED = 143  # 128 + SIGTERM

# Seeds are stored as int64 in every label row: larger ones are refused at the command line.
SEED = click.IntRange(0, 2**63 - 1)
GRASP_ID = click.IntRange(0, 2**63 - 1)  # a label's grasp_id (int64, never negative)

CONTEXT = {"help_option_names": ["-h", "--help"], "max_content_width": 100}
# the outcomes, from annotator.outcome (no pandas: `annotator --help` stays fast)
from annotator.outcome import OUTCOMES  # noqa: E402, F401  (for the commands' choices)

LABELS = click.argument("labels", type=click.Path(path_type=Path))
VERBOSE_OPTION = click.option("--verbose", "-v", is_flag=True, help="Debug logging.")


Decorator = Callable[[Callable[..., Any]], Callable[..., Any]]


def folder_option(*decls: str, help: str, exists: bool = False, **kwargs: Any) -> Decorator:
    """An option naming a folder (a :class:`Path`; a file there is a usage error; ``exists``: it
    must exist)."""
    kind = click.Path(path_type=Path, file_okay=False, exists=exists)
    return click.option(*decls, type=kind, help=help, **kwargs)


def file_option(*decls: str, help: str, exists: bool = False, **kwargs: Any) -> Decorator:
    """An option naming a file (a :class:`Path`; a folder there is a usage error; ``exists``: it
    must exist)."""
    kind = click.Path(path_type=Path, dir_okay=False, exists=exists)
    return click.option(*decls, type=kind, help=help, **kwargs)


def count_option(*decls: str, help: str, low: int = 1, high: int | None = None, **kwargs: Any) -> Decorator:
    """An option taking a whole number in ``low..high`` (``high`` None: no upper bound)."""
    return click.option(*decls, type=click.IntRange(min=low, max=high), help=help, **kwargs)


def objects_option(help: str, **kwargs: Any) -> Decorator:
    """``--objects DIR``, the folder of object meshes (required unless a ``default`` is given)."""
    kwargs.setdefault("required", "default" not in kwargs)
    return folder_option("--objects", "objects_dir", help=help, **kwargs)


# Upper bounds of the counts every command takes, each a figure no real use comes near and that
# a typo or a hostile value must not reach (a loop of 10^9 trials, 10^6 processes):
MAX_WORKERS = 1024  # local processes; more machines: --scheduler (annotate also bounds them by memory)
MAX_TRIALS = 100  # --trials K per grasp: a score to 1 % (the defaults are 1 and 5)
MAX_VIEWS = 100  # depth views per placement, scene or attempt
MAX_SCENES = 1_000_000  # scenes of one run, as --n bounds the grasps per object
MAX_PICTURES = 400  # grasps or objects drawn on one picture or page


def workers_option(
    help: str = "Worker processes [default: all cores].", high: int | None = MAX_WORKERS
) -> Decorator:
    """``--workers N``, processes (None: all cores), at most ``high`` (None: the labelling runs,
    which bound them by the machine's memory with the figures)."""
    return count_option("--workers", help=help, default=None, high=high)


def seed_option(help: str) -> Decorator:
    """``--seed``, 0 by default, refused beyond int64 (seeds are stored in every label row)."""
    return click.option("--seed", type=SEED, default=0, show_default=True, help=help)


def trials_option(help: str) -> Decorator:
    """``--trials K``, trials per grasp, 1 by default, at most :data:`MAX_TRIALS`."""
    return count_option("--trials", help=help, default=1, show_default=True, high=MAX_TRIALS)


def scale_option(help: str) -> Decorator:
    """``--scale``, a finite factor > 0 on every mesh (None: as given)."""
    return click.option("--scale", type=float, default=None, callback=positive_finite, help=help)


def overwrite_option(help: str, dest: str = "overwrite") -> Decorator:
    """``--overwrite``, a flag that lets a command replace what it would otherwise refuse to."""
    return click.option("--overwrite", dest, is_flag=True, help=help)


QUIET_OPTION = click.option(
    "--quiet", "-q", is_flag=True, help="No progress bar; warnings and the summary only."
)
OBJECTS_OPTION = objects_option(
    help="The folder the labels were made from (annotate --objects): where the object meshes are.",
    default=None,
)


def config_option(help: str) -> Decorator:
    """``--config FILE.toml``, constants overridden by section (None: the defaults)."""
    return file_option("--config", "config_file", help=help, exists=True, default=None)


CONFIG_OPTION = config_option(
    "TOML file overriding constants by section, e.g. [protocol] lift_height = 0.15."
)
CACHE_OPTION = folder_option(
    "--cache",
    "cache_dir",
    default=None,
    metavar="DIR",
    help="Decomposition cache folder for every worker, local or on a cluster (e.g. a shared "
    "filesystem); content-addressed, safe to share between runs and machines [default: "
    "$RG2_CACHE_DIR, else ~/.cache/rg2-annotator; a cluster's workers their own].",
)


def _shipped() -> str:
    from annotator.grippers import shipped_grippers

    return ", ".join(shipped_grippers())


# The gripper simulated by a run: a shipped description's name or a folder with gripper.toml.
GRIPPER_OPTION = click.option(
    "--gripper",
    "gripper",
    default=None,
    metavar="NAME|DIR",
    help=f"The gripper: a shipped one ({_shipped()}) or a folder with its gripper.toml and URDF "
    "(docs/grippers.md) [default: rg2].",
)
# The gripper of a tool reading labels: the one recorded with them unless this is given.
LABELS_GRIPPER_OPTION = click.option(
    "--gripper",
    "gripper",
    default=None,
    metavar="NAME|DIR",
    help=f"The gripper: a shipped one ({_shipped()}) or a folder with its gripper.toml [default: "
    "the gripper recorded with the labels, else rg2].",
)


def positive_finite(ctx: click.Context, param: click.Parameter, value: float | None) -> float | None:
    """Reject 0, negative, inf and nan at the command line (exit 2), not per object later."""
    if value is not None and not (math.isfinite(value) and value > 0):
        raise click.BadParameter(f"must be a finite number > 0, got {value}", param=param)
    return value


class _QuietLibraries(logging.Filter):
    """Dask and tornado log their own connection trouble, tracebacks included; the run says what
    matters in one line (a lost scheduler, a dead worker). ``--verbose`` shows everything."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not record.name.startswith(("distributed", "tornado")) or record.levelno >= logging.CRITICAL


def setup_logging(quiet: bool, verbose: bool, *, default: int = logging.INFO) -> None:
    """``--quiet``: warnings only; ``--verbose``: debug; else ``default``."""
    level = logging.WARNING if quiet else (logging.DEBUG if verbose else default)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    if not verbose:
        for handler in logging.getLogger().handlers:
            handler.addFilter(_QuietLibraries())


def load_config(config_file: Path | None):
    """The :class:`AnnotatorConfig` of ``--config`` (defaults without one); a bad file is a usage error."""
    from annotator.config import AnnotatorConfig

    try:
        return AnnotatorConfig.from_toml(config_file) if config_file else AnnotatorConfig()
    except (ValueError, OSError) as exc:
        raise click.UsageError(f"--config {config_file}: {exc}") from exc


# After an interrupt everything finished is on disk; if the interpreter's exit then waits longer
# than this (s) on a worker pool that does not wind down (a worker still starting on a machine
# short of CPU), the process ends anyway, with the same exit code.
EXIT_GRACE_SECONDS = 15.0


def _exit_soon(command: str, code: int) -> NoReturn:
    """``sys.exit(code)``, with a watchdog that ends the process ``EXIT_GRACE_SECONDS`` later if
    the exit handlers (joblib's pool shutdown) have not returned by then."""

    def force() -> None:
        with contextlib.suppress(Exception):
            sys.stderr.write(f"{command}: worker processes did not stop in time; exiting\n")
            sys.stderr.flush()
            sys.stdout.flush()
        os._exit(code)

    watchdog = threading.Timer(EXIT_GRACE_SECONDS, force)
    watchdog.daemon = True
    watchdog.start()
    sys.exit(code)


def run_pipeline(
    command: str,
    *,
    config: Any,
    own: Any = None,
    workers: int | None,
    on_done: Callable[[], None] | None = None,
    **options: Any,
) -> None:
    """Run a labelling job with the run's ``options`` (:class:`annotator.pipeline.options.
    RunOptions`) and the job's ``own`` options, which choose the job (``annotate``: None or
    ``ObjectOptions``; ``evaluate``: ``EvaluateOptions``; ``annotate --scenes``: ``SceneOptions``),
    and exit with the documented code; problems are one line prefixed with ``command``.
    ``on_done()`` runs once the run has finished (all objects done or some failed), before the exit."""
    from annotator.pipeline.run import RunOptions, SchedulerLost, Terminated, UsageError, run
    from annotator.store import OutputError

    run_options = RunOptions(workers=workers or os.cpu_count() or 1, **options)
    try:
        summary = run(run_options, config, own)
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
        _exit_soon(command, EXIT_INTERRUPTED)
    except Terminated:
        click.echo(f"{command}: terminated; re-run the same command to resume", err=True)
        _exit_soon(command, EXIT_TERMINATED)
    if on_done is not None:
        on_done()
    sys.exit(EXIT_OK if not summary.failed else EXIT_SOME_FAILED)
