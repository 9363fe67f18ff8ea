"""``annotator calibrate``: fit the uncertain physics to real trial outcomes."""

from __future__ import annotations

import logging
from pathlib import Path

import click
import numpy as np

from annotator.cli.common import CONTEXT, LABELS, SEED, VERBOSE_OPTION, setup_logging
from annotator.tools import calibrate as cal


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
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the bootstrap resampling.")
@VERBOSE_OPTION
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
    setup_logging(False, verbose, default=logging.WARNING)
    import os

    from annotator.tools.common import check_output_file, labelling_config, read_labels

    frictions, forces, severities = _floats(friction), _floats(force), _floats(severity)
    check_output_file(config_out, "--write-config")  # before the simulation, not after it
    labels_df = read_labels(labels)
    trials = cal.read_real_trials(real_csv, labels_df)
    chosen = labelling_config(labels)
    click.echo(chosen.line())
    base = chosen.config
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
