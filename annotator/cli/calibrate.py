"""``annotator calibrate``: fit the uncertain physics to real trial outcomes."""

from __future__ import annotations

import logging
from pathlib import Path

import click
import numpy as np

from annotator.cli.common import (
    CONTEXT,
    LABELS,
    LABELS_GRIPPER_OPTION,
    MAX_TRIALS,
    VERBOSE_OPTION,
    config_option,
    count_option,
    file_option,
    objects_option,
    overwrite_option,
    scale_option,
    seed_option,
    setup_logging,
    workers_option,
)
from annotator.cli.evaluate import FRAME_OPTION, RESTING_GRASPS_OPTION
from annotator.tools import calibrate as cal


def _floats(text: str, allow_zero: bool = False) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise click.BadParameter(f"{text!r}: comma-separated numbers, e.g. 0.3,0.45,0.6") from None
    low_ok = (lambda v: v >= 0) if allow_zero else (lambda v: v > 0)
    if not values or any(not np.isfinite(v) or not low_ok(v) for v in values):
        what = "numbers >= 0" if allow_zero else "positive numbers"
        raise click.BadParameter(f"{text!r}: {what}, e.g. 0.3,0.45,0.6")
    return values


@click.command("calibrate", context_settings=CONTEXT)
@LABELS
@click.argument("real_csv", type=click.Path(path_type=Path, dir_okay=False))
@objects_option(help="The folder the labels were made from (annotate --objects).")
@click.option(
    "--friction",
    default=",".join(map(str, cal.DEFAULT_FRICTIONS)),
    show_default=True,
    help="Pad friction coefficients to try.",
)
@click.option(
    "--force",
    default=None,
    help="Grip forces (N) to try; ignored when REAL.csv has a grip_force column [default: 50, 75 and "
    "100 % of the gripper's default squeeze, the RG2's 20,30,40].",
)
@click.option(
    "--severity",
    default=",".join(map(str, cal.DEFAULT_SEVERITIES)),
    show_default=True,
    help="Shake severities to try: factors on the shake's amplitude and angle (0: lift only).",
)
@click.option(
    "--objective",
    type=click.Choice(cal.OBJECTIVES),
    default="balanced",
    show_default=True,
    help="What the best setting maximises: balanced accuracy (the mean of the success and failure "
    "rates recovered; not fooled by a majority class) or accuracy.",
)
@count_option(
    "--folds",
    default=cal.DEFAULT_FOLDS,
    show_default=True,
    help="Cross-validate the choice by object in this many folds (at most one per object; 0 or 1: no "
    "cross-validation): the setting is chosen on the other objects' trials and scored on the fold's.",
    low=0,
    high=1000,
)
@file_option(
    "--write-config",
    "config_out",
    default=Path("calibrated.toml"),
    show_default=True,
    help="Where to write the best setting as a TOML file for annotate --config.",
)
@count_option(
    "--trials",
    "trials_k",
    default=5,
    show_default=True,
    high=MAX_TRIALS,
    help="Simulate every real trial this many times (annotate --trials K) at the best setting and map "
    "its score to the probability that the real grasp holds (isotonic, cross-validated by object): "
    "written as [confidence]; labels made with the file and the same --trials carry p_success.",
)
@file_option(
    "--reliability",
    "reliability_out",
    default=None,
    help="Where to draw the reliability diagram of p_success (PNG) [default: beside --write-config, "
    "NAME.reliability.png].",
)
@file_option(
    "--outcomes",
    "outcomes_out",
    default=None,
    help="Also write every simulated outcome of the grid here (Parquet: object_id, grasp_id, "
    "real_success, friction, force, severity, sim_success), for analyses of your own.",
)
@click.option(
    "--fit-ranges",
    is_flag=True,
    help="Instead of the grid: fit the execution's uncertainty to the real trials ([robust] ranges of "
    "the object's placement and yaw, the hand across and along the approach, the friction spread; the "
    "stage the perturbed trials are judged at, trial 0's gate and --trials K) by the likelihood of the "
    "real outcomes, cross-validated by object, and write it with its [confidence] mapping as the robot "
    "cell's profile (--write-config) [docs/tools.md, calibrate].",
)
@count_option(
    "--explore-trials",
    "explore_m",
    default=64,
    show_default=True,
    help="With --fit-ranges: perturbed trials per real trial in the exploration.",
    low=4,
    high=4096,
)
@click.option(
    "--levels",
    default=None,
    help="With --fit-ranges: the scale levels each group of ranges is explored at, comma-separated "
    "[default: 0.5,1,2,4,8 x the object's 2 mm and 2 deg, the hand's 1 mm across and 2 mm along, "
    "friction +-0.1].",
)
@LABELS_GRIPPER_OPTION
@FRAME_OPTION
@click.option(
    "--resting",
    is_flag=True,
    help="Simulate each grasp on its object resting on the table, as evaluate --resting [default: as "
    "the labels were simulated; a grasp table: floating].",
)
@RESTING_GRASPS_OPTION
@scale_option("A grasp table's objects: scale every mesh by this factor (labels: their own object_scale).")
@config_option(
    "The configuration the grid varies [default: the one recorded beside the labels, else the defaults]."
)
@workers_option("Worker processes [default: all cores].")
@seed_option("Seed of the bootstrap and the folds.")
@count_option(
    "--scene",
    default=None,
    help="Scene labels (annotate --scenes): the scene whose grasps were tried; (object_id, grasp_id) "
    "repeats across scenes, so scene labels need it.",
    low=0,
)
@overwrite_option(
    "Replace output files (--write-config, --reliability, --outcomes) this tool did not write or that "
    "were changed since.",
    dest="force_write",
)
@VERBOSE_OPTION
def calibrate_command(
    labels,
    real_csv,
    objects_dir,
    friction,
    force,
    severity,
    objective,
    folds,
    config_out,
    trials_k,
    reliability_out,
    outcomes_out,
    fit_ranges,
    explore_m,
    levels,
    gripper,
    frame,
    resting,
    resting_grasps,
    scale,
    config_file,
    workers,
    seed,
    scene,
    force_write,
    verbose,
):
    """Fit pad friction, grip force and shake severity to real trials, and the label's confidence.

    LABELS is a labels folder or file of this tool (its commanded grasps are replayed with the
    gripper, configuration and resting mode recorded with them) or a grasp table as evaluate reads
    it (object_id, grasp_id, pose, optional width; --frame base for base-link poses). REAL.csv has
    one row per grasp executed on the real robot: object_id, grasp_id, real_success (1/0), and
    optionally grip_force (N, the force used). Every trial is re-simulated under every setting of
    the grid; the agreement with the real outcomes (accuracy, balanced accuracy, precision and
    recall of success, with 95 % bootstrap intervals) is printed per setting, the choice is
    cross-validated by object (--folds), and the best setting is written as a TOML file for
    annotate --config. Then every trial is simulated --trials K times at the best setting and
    the share that held (score) is mapped to the probability that the real grasp holds: the
    mapping goes into the file ([confidence]), its reliability diagram beside it (PNG) and its
    Brier score is printed; labels made with the file and --trials K carry p_success.

    \b
    Example:
      annotator calibrate labels/ real_trials.csv --objects objects/
      annotator calibrate evaluated/ real.csv --objects ycb/ --severity 0,0.5,1 --folds 5
      annotate --objects objects/ --n 500 --trials 5 --config calibrated.toml --out calibrated/
    """
    setup_logging(False, verbose, default=logging.WARNING)
    import os

    from annotator.tools.common import claim_outputs

    frictions, severities = _floats(friction), _floats(severity, allow_zero=True)
    if reliability_out is None:
        reliability_out = config_out.with_suffix(".reliability.png")
    outputs = {"--write-config": config_out, "--reliability": reliability_out, "--outcomes": outcomes_out}
    claimed = claim_outputs("annotator calibrate", outputs, force_write)  # before the simulation
    resting = resting_grasps or ("object" if resting else None)
    source = cal.calibration_grasps(labels, objects_dir, gripper, frame, resting, scale, config_file, scene)
    trials = cal.read_real_trials(real_csv, source.grasps)  # a bad file is one line, before anything else
    if "labels_sha256" in trials.columns:  # read from a trial sheet: made from these labels?
        from annotator.tools.trial_sheet import check_stamp

        check_stamp(trials["labels_sha256"], source.grasps, real_csv, "LABELS")
    click.echo(source.config_line)
    click.echo(source.gripper_line)
    from annotator.tools.gripper_check import check_before_work

    check_before_work(source.gripper, source.config)
    if source.resting:
        click.echo(f"resting: each object on the table as given, grasps in the {source.resting}'s frame")
    base = source.config
    if fit_ranges:
        _fit_ranges(
            labels,
            real_csv,
            trials,
            source,
            objects_dir,
            explore_m,
            levels,
            folds,
            workers,
            seed,
            claimed,
        )
        return
    forces = _floats(force) if force is not None else cal.default_forces(source.gripper)
    settings = cal.grid(frictions, forces, severities, real_force="grip_force" in trials.columns)
    click.echo(
        f"{len(trials)} real trials ({int(trials.real_success.sum())} held) on {trials.object_id.nunique()} "
        f"objects; {len(settings)} settings, {len(settings) * len(trials)} simulated grasps"
    )
    result = cal.calibrate(
        trials,
        base,
        objects_dir,
        settings,
        workers or os.cpu_count() or 1,
        seed,
        objective=objective,
        gripper=source.gripper,
        resting=source.resting,
    )
    click.echo(cal.format_table(result))
    if folds >= 2 and trials.object_id.nunique() >= 2:
        labelled = cal._gripper_settings(base, source.gripper)
        cv = cal.cross_validate(trials, result.simulated, settings, labelled, folds, seed, objective)
        click.echo(cal.format_folds(cv))
    b, a = result.best, result.best_agreement
    click.echo(
        f"best: {cal.setting_text(b)}: accuracy {100 * a.accuracy:.1f} % [{100 * a.accuracy_ci[0]:.0f}, "
        f"{100 * a.accuracy_ci[1]:.0f}] over {a.n} trials; "
        f"{cal.agreement_text(a, ('balanced', 'precision', 'recall', 'f1'))}"
    )
    import dataclasses

    from annotator import confidence as conf

    fit = cal.fit_confidence(
        trials,
        b,
        base,
        objects_dir,
        trials_k,
        workers or os.cpu_count() or 1,
        seed,
        gripper=source.gripper,
        resting=source.resting,
        folds=folds,
    )
    click.echo(cal.confidence_text(fit))
    title = f"{source.gripper.name}, --trials {trials_k}, by object; Brier {fit.brier.value:.3f}"
    diagram = claimed.write_bytes("--reliability", conf.reliability_png([("p_success", fit.bins)], title))
    click.echo(f"wrote {diagram}")
    written = dataclasses.replace(result.config, confidence=fit.section(result.config.robust.shake))
    header = (
        f"annotator calibrate {labels} {real_csv}: best of {len(settings)} settings over {a.n} real trials "
        f"({source.gripper.name}, {objective})\n"
        f"accuracy {a.accuracy:.3f} (95 % CI {a.accuracy_ci[0]:.3f}..{a.accuracy_ci[1]:.3f}), "
        f"balanced {a.balanced:.3f}, precision {a.precision:.3f}, recall {a.recall:.3f}\n"
        f"[confidence]: p_success of the score of --trials {trials_k}, Brier {fit.brier.value:.3f} "
        "cross-validated by object\n"
        f"use: annotate --objects DIR --n N --gripper {source.gripper.name} --trials {trials_k} "
        "--config THIS_FILE"
    )
    click.echo(f"wrote {claimed.write_text('--write-config', cal.config_toml(written, header))}")
    if claimed.asked("--outcomes"):
        table = cal.outcomes_table(trials, result.simulated)
        click.echo(f"wrote {claimed.write('--outcomes', lambda tmp: table.to_parquet(tmp, index=False))}")


def _check_levels(levels, config) -> None:
    """Every range the exploration reaches (each group's sizes at the highest level) within its
    [robust] bound; one line naming the field otherwise, before any simulation."""
    import dataclasses

    from annotator.config import ConfigError
    from annotator.tools import ranges
    from annotator.tools.common import ToolError

    top = max(levels)
    for group in ranges.GROUPS:
        try:
            dataclasses.replace(config.robust, **group.at(top))
        except ConfigError as exc:
            raise ToolError(f"--levels up to {top:g}: {exc}") from None


def _fit_ranges(
    labels,
    real_csv,
    trials,
    source,
    objects_dir,
    m,
    levels,
    folds,
    workers,
    seed,
    claimed,
) -> None:
    """``calibrate --fit-ranges``: explore, fit, cross-validate, write the profile (``claimed``: the
    command's outputs, :class:`annotator.tools.common.ToolOutputs`)."""
    import os

    from annotator import confidence as conf
    from annotator.tools import ranges

    level_values = _floats(levels) if levels is not None else ranges.LEVELS
    _check_levels(level_values, source.config)
    click.echo(
        f"{len(trials)} real trials ({int(trials.real_success.sum())} held) on {trials.object_id.nunique()} "
        f"objects; exploring each with {m} perturbed trials"
    )
    result = cal.fit_ranges(
        trials,
        source.config,
        objects_dir,
        workers or os.cpu_count() or 1,
        seed,
        gripper=source.gripper,
        resting=source.resting,
        m=m,
        levels=level_values,
        folds=folds,
    )
    click.echo(cal.ranges_text(result, seed=seed))
    held_p = None if result.held_out is None else result.held_out.p
    profile = cal.profile_config(source.config, result.fit, result.real, held_p)
    f = result.fit
    if result.held_out is not None:
        bins = conf.reliability(result.real, result.held_out.p)
        title = (
            f"{source.gripper.name}, profile --trials {f.k}, by object; Brier {profile.confidence.brier:.3f}"
        )
        diagram = conf.reliability_png([("p_success (cross-validated)", bins)], title)
        click.echo(f"wrote {claimed.write_bytes('--reliability', diagram)}")
    header = (
        f"annotator calibrate --fit-ranges {labels} {real_csv}: the execution fitted to {len(trials)} real "
        f"trials ({source.gripper.name}); the robot cell's profile\n"
        f"[confidence]: p_success of the score of --trials {f.k}, Brier {profile.confidence.brier:.3f} "
        "cross-validated by object; call a grasp a success at p_success >= "
        f"{profile.confidence.threshold:.3f}\n"
        f"use: annotate --objects DIR --n N --gripper {source.gripper.name} --trials {f.k} --config THIS_FILE"
    )
    text = cal.config_toml(profile, header, cal.PROFILE_KEEP)
    click.echo(f"wrote {claimed.write_text('--write-config', text)}")
    if claimed.asked("--outcomes"):
        table = trials[["object_id", "grasp_id", "real_success"]].reset_index(drop=True).copy()
        exp = result.exploration
        table["trial_stages"] = [
            str(a) + "".join(map(str, row)) for a, row in zip(exp.stage0, exp.stages, strict=True)
        ]
        click.echo(f"wrote {claimed.write('--outcomes', lambda tmp: table.to_parquet(tmp, index=False))}")
