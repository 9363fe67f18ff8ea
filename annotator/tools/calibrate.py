"""Fit the uncertain physics to real trials: pad friction, grip force and shake severity.

The user executes some grasps on their real robot and records ``object_id, grasp_id,
real_success`` (optionally ``grip_force``, N, the force they used). The grasps are labels of this
tool (their commanded grasps, as the robot executes them) or a grasp table as ``evaluate`` reads
it (TCP or base-link poses). Each is re-simulated (:mod:`annotator.tools.given`) with the
gripper the labels were made with, floating or resting on the table as they were, under every
setting of a grid, and the simulated outcome is compared with the real one: accuracy, balanced
accuracy, precision, recall and F1 of "success", with percentile bootstrap confidence intervals
over the trials. The best setting (highest ``objective``, balanced accuracy by default; ties:
the other of accuracy and balanced accuracy, then the setting nearest the labelling
configuration) is written as a TOML file for ``--config``.

Few trials on few objects are easy to over-fit, so the choice of setting is cross-validated by
object (:func:`cross_validate`): the objects are split into folds; for each fold the best setting
is chosen on the other objects' trials alone and scored on the fold's. The held-out outcomes of
all folds, pooled, say how well the procedure predicts trials on objects it has not seen.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from annotator.config import AnnotatorConfig, ConfidenceConfig

if TYPE_CHECKING:  # pandas is imported where it is used: `annotator --help` stays fast
    import pandas as pd

    from annotator.confidence import Mapping, Measure
    from annotator.tools.ranges import Exploration, Fit, HeldOut

log = logging.getLogger(__name__)

DEFAULT_FRICTIONS = (0.3, 0.45, 0.6, 0.8, 1.0)  # pad friction; OnRobot's own model uses 0.4, ACRONYM 1.0
# Grip forces tried, as shares of the gripper's default squeeze: the RG2's 20, 30 and 40 N of its 3..40 N.
DEFAULT_FORCE_SHARES = (0.5, 0.75, 1.0)
DEFAULT_FORCES = (20.0, 30.0, 40.0)  # N: the RG2's (DEFAULT_FORCE_SHARES of its 40 N)
DEFAULT_SEVERITIES = (0.5, 1.0, 1.5)  # x the shake's amplitude and angle
from annotator.agreement import (  # noqa: E402, F401  (the statistics calibrate reports, re-exported)
    BOOTSTRAP_SAMPLES,
    CONFIDENCE,
    STATISTICS,
    Agreement,
    agreement,
    agreement_text,
)

REAL_COLUMNS = ("object_id", "grasp_id", "real_success")
OBJECTIVES = ("balanced", "accuracy")  # what the best setting maximises
DEFAULT_FOLDS = 5  # object-wise cross-validation folds (at most one per object)


@dataclass(frozen=True)
class Setting:
    """One point of the grid: pad friction, grip force (N, None: each trial's own) and severity."""

    friction: float
    force: float | None
    severity: float

    def config(self, base: AnnotatorConfig, force: float | None = None) -> AnnotatorConfig:
        """``base`` with this setting (``force`` overrides the setting's, e.g. a trial's own)."""
        grip = force if force is not None else self.force
        gripper = dataclasses.replace(base.gripper, pad_lateral_friction=float(self.friction))
        if grip is not None:
            gripper = dataclasses.replace(gripper, grip_force=float(grip))
        protocol = dataclasses.replace(
            base.protocol,
            shake_amplitude=base.protocol.shake_amplitude * self.severity,
            shake_angle=base.protocol.shake_angle * self.severity,
        )
        return dataclasses.replace(base, gripper=gripper, protocol=protocol)


@dataclass
class CalibrationResult:
    """Every setting's agreement (``table``: one row per setting) and the best one by ``objective``."""

    table: pd.DataFrame
    best: Setting
    best_agreement: Agreement
    config: AnnotatorConfig
    simulated: dict[Setting, np.ndarray]
    objective: str = "balanced"


@dataclass(frozen=True)
class CalibrationGrasps:
    """The grasps real trials were run with, ready to replay: ``grasps`` has ``object_id``,
    ``grasp_id``, the commanded grasps (``cmd_*``), ``object_scale`` (NaN: the objects' own) and,
    resting, ``rest_q*``; with the configuration, gripper and resting mode to simulate them with
    and the lines that say where each came from."""

    grasps: pd.DataFrame
    config: AnnotatorConfig
    config_line: str
    gripper: object  # annotator.grippers.GripperDescription
    gripper_line: str
    resting: str | None  # None: floating; "object" or "table" (annotator.cell.resting)


def _is_label_table(path: Path) -> bool:
    """A labels folder, or a Parquet file with the label columns (else: a grasp table)."""
    if path.is_dir():
        return True
    if path.suffix.lower() != ".parquet":
        return False
    import pyarrow.parquet as pq

    from annotator.dataset import COLUMNS

    try:
        names = set(pq.read_schema(path).names)
    except Exception:  # unreadable: read_grasps names the problem
        return False
    return set(COLUMNS) <= names


def calibration_grasps(
    labels: Path,
    objects_dir: Path,
    gripper=None,
    frame: str = "tcp",
    resting: bool | str = False,
    scale: float | None = None,
    config_file: Path | None = None,
    scene: int | None = None,
) -> CalibrationGrasps:
    """What ``calibrate`` replays: a labels folder or file of this tool (with the gripper,
    configuration and resting mode recorded with it unless given), or a grasp table read as
    ``evaluate`` reads it (:func:`annotator.tools.evaluate.read_grasps`, ``frame``) and turned
    into the commanded grasps a run would simulate. Scene labels, where (object_id, grasp_id)
    repeats across scenes, only with ``scene`` named (its rows)."""
    from annotator.pipeline.modes import resting_grasps
    from annotator.tools.common import labelling_config, labelling_gripper, labels_resting, read_labels
    from annotator.tools.evaluate import commanded_table, read_grasps

    labels = Path(labels)
    chosen = labelling_config(labels, config_file)
    if _is_label_table(labels):
        from annotator.tools.common import ToolError

        if frame != "tcp":
            raise ToolError(f"{labels} holds labels: their poses are TCP poses; drop --frame {frame}")
        from annotator.tools.common import one_row_per_grasp

        table = read_labels(labels)
        hand = labelling_gripper(labels, gripper, table)
        table = one_row_per_grasp(table, labels, scene)  # a real trial names one label
        return CalibrationGrasps(
            table,
            chosen.config,
            chosen.line(),
            hand.description,
            hand.line(),
            resting_grasps(resting) or labels_resting(labels),
        )
    hand = labelling_gripper(None, gripper)
    grasps = read_grasps(labels, frame)
    stroke = _max_width(chosen.config, hand.description)
    table = commanded_table(
        grasps, objects_dir, chosen.config, scale, stroke, gripper=hand.description, frame=frame
    )
    return CalibrationGrasps(
        table, chosen.config, chosen.line(), hand.description, hand.line(), resting_grasps(resting)
    )


def read_real_trials(path: Path, labels: pd.DataFrame) -> pd.DataFrame:
    """REAL.csv joined with the labels (pose, width, outcome); one-line errors for bad input."""
    import pandas as pd

    from annotator.tools.common import ToolError, csv_header, truth_column, unique_columns

    try:
        unique_columns(csv_header(path), path)  # a column named twice: which one is meant?
        real = pd.read_csv(path)
    except FileNotFoundError:
        raise ToolError(f"no real-trial file at {path}") from None
    except (OSError, ValueError, pd.errors.ParserError) as exc:
        raise ToolError(f"{path}: not a CSV file ({exc})") from None
    missing = [c for c in REAL_COLUMNS if c not in real.columns]
    if missing:
        raise ToolError(f"{path}: missing column(s) {missing}; need {', '.join(REAL_COLUMNS)} [, grip_force]")
    if real.empty:
        raise ToolError(f"{path}: no trials")
    real["real_success"] = truth_column(real["real_success"], path, "real_success")
    real["object_id"] = real["object_id"].astype(str)
    ids = pd.to_numeric(real["grasp_id"], errors="coerce")
    bad = ids.isna() | (ids != ids.round()) | (ids < 0) | (ids > 2**62)
    if bad.any():
        row = int(np.argmax(bad.to_numpy()))
        raise ToolError(
            f"{path}: row {row}: grasp_id {real['grasp_id'].astype(str).iloc[row]} "
            "is not a non-negative integer"
        )
    real["grasp_id"] = ids.astype(np.int64)
    if "grip_force" in real.columns:
        force = pd.to_numeric(real["grip_force"], errors="coerce")
        if force.isna().any() or ((force < 0) | (force > 400)).any():
            raise ToolError(f"{path}: grip_force must be a number of newtons")
        real["grip_force"] = force.astype(float)
    merged = real.merge(labels, on=["object_id", "grasp_id"], how="left", indicator=True)
    unknown = merged[merged["_merge"] == "left_only"]
    if len(unknown):
        first = unknown.iloc[0]
        raise ToolError(
            f"{path}: {len(unknown)} trial(s) name no label, e.g. object {first.object_id!r} grasp "
            f"{int(first.grasp_id)}"
        )
    return merged.drop(columns="_merge")


def grid(
    frictions=DEFAULT_FRICTIONS,
    forces=DEFAULT_FORCES,
    severities=DEFAULT_SEVERITIES,
    real_force: bool = False,
) -> list[Setting]:
    """Every combination; with ``real_force`` each trial uses its own recorded force (no force axis)."""
    force_axis = [None] if real_force else [float(f) for f in forces]
    return [Setting(float(mu), f, float(s)) for mu in frictions for f in force_axis for s in severities]


def default_forces(gripper=None) -> tuple[float, ...]:
    """The grip forces tried by default: DEFAULT_FORCE_SHARES of the gripper's default squeeze, N
    (the RG2: 20, 30, 40; the Panda: 35, 52.5, 70), each within its force range."""
    from annotator.grippers import load_gripper

    d = load_gripper(gripper)
    return tuple(
        min(d.grip_force_max, max(d.grip_force_min, share * d.grip_force)) for share in DEFAULT_FORCE_SHARES
    )


def _setting_config(setting, base, force):
    """The configuration ``setting`` simulates with (None: ``base``), at the trial's own ``force``."""
    if setting is not None:
        return setting.config(base, force)
    if force is not None:  # the configuration as it is, at the trial's own force
        return dataclasses.replace(base, gripper=dataclasses.replace(base.gripper, grip_force=float(force)))
    return base


def span_groups(trials: pd.DataFrame) -> list[tuple[str, float | None, np.ndarray]]:
    """How :func:`simulate_grid` splits real trials into spans: ``(object_id, force, rows)`` per
    object (and per recorded ``grip_force``), ``rows`` the trials' positions in span order. A
    grasp's index in its span is the key of its perturbed trials' generator
    (:func:`annotator.rng.trial_rng` of the object and that index)."""
    has_force = "grip_force" in trials.columns
    groups = trials.groupby(["object_id", "grip_force"] if has_force else ["object_id"], sort=True)
    out = []
    for key, idx in groups.indices.items():
        key = key if isinstance(key, tuple) else (key,)
        out.append((str(key[0]), float(key[1]) if has_force else None, np.asarray(idx)))
    return out


def simulate_grid(
    trials: pd.DataFrame,
    settings: Sequence[Setting | None],
    base: AnnotatorConfig,
    objects_dir: Path,
    workers: int = 1,
    seed: int = 0,
    gripper=None,
    resting: bool | str | None = False,
    k: int = 1,
    column: str = "success",
) -> dict[Setting | None, np.ndarray]:
    """Simulated success of every trial (row order of ``trials``) under every setting (None: ``base``
    as it is), with ``gripper`` (None: the RG2), floating or ``resting`` on the table (each trial's
    ``rest_q*``); ``k``: ``--trials`` of each simulation, ``column``: the label column returned
    (``score``: floats; ``trial_stages``: strings). Every span runs through the runner's execution
    (:func:`annotator.pipeline.in_memory.run_in_memory`) on ``workers`` processes."""
    from annotator.objects import ObjectDiscoveryError, discover_objects
    from annotator.pipeline.in_memory import ExecutionOptions, run_in_memory
    from annotator.pipeline.worker_spawn import detach_local_workers
    from annotator.tools.common import ToolError
    from annotator.tools.given import GivenSpan, given_rows, given_task, replay_grasps

    detach_local_workers()  # a Ctrl-C reaches this process only

    try:
        sources = {s.object_id: s for s in discover_objects(Path(objects_dir))}
    except ObjectDiscoveryError as exc:
        raise ToolError(str(exc)) from None
    missing = sorted(set(trials["object_id"]) - set(sources))
    if missing:
        raise ToolError(f"object(s) {missing} are not in {objects_dir}")
    stroke = _max_width(base, gripper)
    rest_columns = ["rest_qx", "rest_qy", "rest_qz", "rest_qw"]
    spans, where = [], {}
    for oid, force, idx in span_groups(trials):
        rows = trials.iloc[idx]
        scale = float(rows["object_scale"].iloc[0])
        T, width, quat = replay_grasps(rows, base, stroke)
        rest = (
            rows[rest_columns].to_numpy(dtype=np.float64) if set(rest_columns) <= set(rows.columns) else None
        )
        span = GivenSpan(
            oid,
            sources[oid],
            None if np.isnan(scale) else scale,
            T,
            width,
            rows["grasp_id"].to_numpy(),
            quat,
            rest,
        )
        where[(oid, force)] = idx
        spans.append((span, force))
    # setting after setting: a worker rebuilds its world when the configuration changes, and keeps
    # the objects it had while it does not (annotator.pipeline.worker.WorkerState)
    grid = [(setting, span, force) for setting in settings for span, force in spans]
    tasks = [
        given_task(span, _setting_config(setting, base, force), seed, k, gripper=gripper, resting=resting)
        for setting, span, force in grid
    ]
    kind = {"success": bool, "trial_stages": object}.get(column, np.float64)
    out = {s: np.zeros(len(trials), dtype=kind) for s in settings}
    results = run_in_memory(tasks, ExecutionOptions(workers))
    for (setting, span, force), result in zip(grid, results, strict=True):
        rows, error = given_rows(span, result)
        if rows is None:
            raise ToolError(f"{span.object_id}: {error}")
        out[setting][where[(span.object_id, force)]] = rows[column].to_numpy(dtype=kind)
    return out


def explore(
    trials: pd.DataFrame,
    base: AnnotatorConfig,
    objects_dir: Path,
    workers: int = 1,
    seed: int = 0,
    gripper=None,
    resting: bool | str | None = False,
    m: int = 24,
    levels=None,
):
    """The exploration of :mod:`annotator.tools.ranges` on the real trials: each grasp simulated
    once (a grasp executed several times is one grasp) with ``m`` perturbed trials from the
    proposal over ``levels`` (default :data:`annotator.tools.ranges.LEVELS`), their stages read
    back and their draws drawn again, as an :class:`annotator.tools.ranges.Exploration` in the
    row order of ``trials``."""
    from annotator.grippers import load_gripper
    from annotator.tools import ranges

    levels = ranges.LEVELS if levels is None else tuple(levels)
    config = ranges.exploration_config(dataclasses.replace(base, confidence=ConfidenceConfig()), levels)
    key = ["object_id", "grasp_id"] + (["grip_force"] if "grip_force" in trials.columns else [])
    first = ~trials.duplicated(key).to_numpy()
    grasps = trials[first].reset_index(drop=True)
    stages = simulate_grid(
        grasps, [None], config, objects_dir, workers, seed, gripper, resting, m + 1, "trial_stages"
    )
    keys: list[tuple[str, int]] = [("", 0)] * len(grasps)
    for oid, _, idx in span_groups(grasps):
        for position, row in enumerate(idx):
            keys[int(row)] = (oid, position)
    robust = config.robust.over(dict(load_gripper(gripper).robust))  # what GraspTrial draws with
    draws = ranges.draws_of(robust, seed, keys, m)
    explored = ranges.Exploration.of(
        list(stages[None]), draws, levels, base.robust.over(dict(load_gripper(gripper).robust))
    )
    which = grasps.reset_index().merge(trials[key], on=key, how="right")["index"].to_numpy()
    return explored.take(which)  # every trial its grasp's exploration


@dataclass(frozen=True)
class RangesResult:
    """``calibrate --fit-ranges``: the exploration of the real trials, the fit on all of them
    (:class:`annotator.tools.ranges.Fit`), its object-wise cross-validation (None with fewer than
    two folds or objects), the real outcomes and each trial's object."""

    exploration: Exploration
    fit: Fit
    held_out: HeldOut | None
    real: np.ndarray
    objects: np.ndarray


def fit_ranges(
    trials: pd.DataFrame,
    base: AnnotatorConfig,
    objects_dir: Path,
    workers: int = 1,
    seed: int = 0,
    *,
    gripper=None,
    resting: bool | str | None = False,
    m: int = 64,
    levels=None,
    folds: int = DEFAULT_FOLDS,
    exploration=None,
) -> RangesResult:
    """Explore the real trials (:func:`explore`; ``exploration``: one already made of them), fit
    the execution's ranges, the stages, the trial count and the score's mapping to them
    (:func:`annotator.tools.ranges.fit`), and cross-validate the whole fit by object."""
    from annotator.tools import ranges

    exp = exploration
    if exp is None:
        exp = explore(trials, base, objects_dir, workers, seed, gripper, resting, m, levels)
    real = trials["real_success"].to_numpy(dtype=bool)
    objects = trials["object_id"].astype(str).to_numpy()
    held_out = None
    if folds >= 2 and len(set(objects)) >= 2:
        held_out = ranges.cross_validate(exp, real, objects, folds, seed)
    return RangesResult(exp, ranges.fit(exp, real), held_out, real, objects)


def profile_config(
    base: AnnotatorConfig, fit, real: np.ndarray | None = None, held_out_p: np.ndarray | None = None
) -> AnnotatorConfig:
    """The robot cell's profile: ``base`` with the fitted ranges (``fit``, an
    :class:`annotator.tools.ranges.Fit`: perturbed trials after a colliding trial 0, judged at the
    fitted stage), trial 0's gate and the ``[confidence]`` mapping of the score of the fitted K
    with its threshold; its Brier score and reliability those of ``held_out_p`` (the cross-validated
    P(success) of the ``real`` outcomes) where given, else of the fit on its own trials."""
    from annotator import confidence as conf

    execution = fit.execution.execution
    robust = dataclasses.replace(
        base.robust,
        **fit.ranges(),
        perturb_collisions=True,
        motion=execution.stage == "motion",
        shake=False,
        scale_levels=(),
    )
    protocol = dataclasses.replace(base.protocol, gate=fit.gate)
    scores, p = fit.scored.mapping.knots()
    if held_out_p is not None and real is not None:
        brier = conf.brier(real, held_out_p)
        bins = [b for b in conf.reliability(real, held_out_p) if b.n > 0]
    else:
        brier, bins = fit.scored.brier, []
    confidence = ConfidenceConfig(
        method="isotonic",
        trials=fit.k,
        scores=scores,
        p_success=p,
        n=len(fit.scored.p),
        brier=float(min(1.0, max(0.0, brier))),
        reliability_p=tuple(b.mean_p for b in bins),
        reliability_rate=tuple(b.real_rate for b in bins),
        reliability_n=tuple(float(b.n) for b in bins),
        perturbed_shake=False,
        threshold=fit.threshold,
        base_rate=float(fit.base_rate),
    )
    return dataclasses.replace(base, robust=robust, protocol=protocol, confidence=confidence)


# The [robust] fields a profile writes even at their defaults: a gripper's own [robust] table
# must not replace a fitted range (RobustConfig.over).
PROFILE_KEEP = {
    "robust": {
        "object_position_sigma",
        "object_yaw_sigma",
        "position_sigma",
        "approach_sigma",
        "friction_delta",
        "perturb_collisions",
        "motion",
    }
}


def ranges_text(result: RangesResult, bootstrap: int = BOOTSTRAP_SAMPLES, seed: int = 0) -> str:
    """What the fit found: the exploration, each group's level and whether the data identify it,
    the stages, lapses, K and mapping; then the cross-validated figures."""
    from annotator import confidence as conf
    from annotator.tools import ranges

    f, exp = result.fit, result.exploration
    e = f.execution.execution
    n, m = exp.stages.shape
    lines = [
        f"exploration: {n} real trials x {m} perturbed trials, levels "
        + ", ".join(f"{v:g}" for v in exp.levels)
    ]
    for i, g in enumerate(ranges.GROUPS):
        sizes = ", ".join(f"{k} {v:.4g}" for k, v in exp.sizes(g, e.theta[i]).items())
        profile = f.execution.profile[g.name]
        drop = ", ".join(f"{exp.label(j)} {v - max(profile):+.1f}" for j, v in enumerate(profile))
        how = "identified" if f.execution.identified[g.name] else "not identified: the run's own kept"
        lines.append(
            f"  {g.name}: {exp.label(e.theta[i])} ({sizes}); {how}; log-likelihood by candidate {drop}"
        )
    knots = ", ".join(f"{s:.2f} -> {p:.2f}" for s, p in zip(*f.scored.mapping.knots(), strict=True))
    lines.append(
        f"  perturbed trials judged after the {e.stage}; lapses: real fails {e.fail:g}, holds {e.hold:g} "
        "whatever the simulation says"
    )
    lines.append(
        f"  trial 0's gate: {f.gate}; --trials {f.k}; score -> p_success: {knots}; "
        f"threshold p_success >= {f.threshold:.3f}"
    )
    h = result.held_out
    if h is None:
        return "\n".join(lines)
    real = result.real
    called = h.called >= 0.5
    auc = conf.bootstrap(conf.auc, real, h.p, bootstrap, seed)
    brier = conf.bootstrap(conf.brier, real, h.p, bootstrap, seed)
    base = conf.brier(real, np.full(len(real), real.mean()))
    calls = agreement(real, called, bootstrap, seed)
    lines.append(
        f"cross-validated by object ({len(h.folds)} folds; each fold's fit on the other objects), expected "
        f"over the trials' scores: AUC {auc.text()}, Brier {brier.text()} (always the success rate: "
        f"{base:.3f}); at each fold's threshold {agreement_text(calls, ('balanced', 'precision', 'recall'))}"
    )
    for b in conf.reliability(real, h.p):
        if b.n:
            lines.append(
                f"  p_success {b.low:.1f}-{b.high:.1f}: {b.n} trials, "
                f"mean {b.mean_p:.3f}, real {b.real_rate:.3f}"
            )
    return "\n".join(lines)


# ------------------------------------------------------------------------------------ confidence


@dataclass(frozen=True)
class ConfidenceFit:
    """``score`` of ``--trials k`` mapped to P(real success) (annotator/confidence.py).

    ``mapping``: fitted on every trial (what labels use); ``score`` (n,): each trial's simulated
    score; ``p_cv`` (n,): P(success) from the mapping fitted on the other objects' trials (NaN
    with one object); ``brier`` / ``auc_score`` / ``auc_p``: the held-out Brier score and the
    AUCs with 95 % bootstrap intervals (:class:`annotator.confidence.Measure`); ``base_brier``:
    always predicting the real success rate; ``bins``: the held-out reliability table.
    """

    mapping: Mapping
    score: np.ndarray
    p_cv: np.ndarray
    brier: Measure
    auc_score: Measure
    auc_p: Measure
    base_brier: float
    bins: list
    fitted_brier: float = float("nan")  # on the trials it was fitted on (no cross-validation)

    def section(self, perturbed_shake: bool):
        """The ``[confidence]`` section that carries the mapping into ``annotate --config``;
        ``perturbed_shake``: the scores' perturbed trials shook (``[robust] shake``)."""
        from annotator.config import ConfidenceConfig

        m = self.mapping
        used = [b for b in self.bins if b.n > 0]
        brier = self.brier.value if np.isfinite(self.brier.value) else self.fitted_brier
        return ConfidenceConfig(
            method="isotonic",
            trials=m.trials,
            scores=m.scores,
            p_success=m.p,
            n=m.n,
            brier=float(brier),
            reliability_p=tuple(b.mean_p for b in used),
            reliability_rate=tuple(b.real_rate for b in used),
            reliability_n=tuple(float(b.n) for b in used),
            perturbed_shake=perturbed_shake,
        )


def fit_confidence(
    trials: pd.DataFrame,
    setting: Setting,
    base: AnnotatorConfig,
    objects_dir: Path,
    k: int,
    workers: int = 1,
    seed: int = 0,
    *,
    gripper=None,
    resting: bool | str | None = False,
    folds: int = DEFAULT_FOLDS,
    bootstrap: int = BOOTSTRAP_SAMPLES,
) -> ConfidenceFit:
    """Simulate every real trial with ``--trials k`` at ``setting`` and map its score to the real
    outcome (isotonic), cross-validated by object for the figures."""
    from annotator import confidence as conf
    from annotator.config import ConfidenceConfig

    base = dataclasses.replace(base, confidence=ConfidenceConfig())  # no p_success while fitting it
    score = simulate_grid(trials, [setting], base, objects_dir, workers, seed, gripper, resting, k, "score")[
        setting
    ]
    real = trials["real_success"].to_numpy(dtype=bool)
    objects = trials["object_id"].astype(str).to_numpy()
    mapping = conf.fit_isotonic(score, real, k)
    if len(set(objects)) >= 2 and folds >= 2:
        p_cv = conf.cross_validated(score, real, objects, k, folds, seed)
    else:
        p_cv = np.full(len(real), np.nan)
    held = np.isfinite(p_cv)
    return ConfidenceFit(
        mapping,
        score,
        p_cv,
        conf.bootstrap(conf.brier, real[held], p_cv[held], bootstrap, seed),
        conf.bootstrap(conf.auc, real, score, bootstrap, seed),
        conf.bootstrap(conf.auc, real[held], p_cv[held], bootstrap, seed),
        conf.brier(real, np.full(len(real), real.mean())),
        conf.reliability(real[held], p_cv[held]),
        conf.brier(real, mapping.p_success(score)),
    )


def confidence_text(fit: ConfidenceFit) -> str:
    """What the confidence fit found, a few lines."""
    m = fit.mapping
    knots = ", ".join(f"{s:.2f} -> {p:.2f}" for s, p in zip(m.scores, m.p, strict=True))
    lines = [
        f"confidence (--trials {m.trials}, isotonic over {m.n} real trials): score {knots}",
        f"AUC of score {fit.auc_score.text()}; cross-validated by object: AUC of p_success "
        f"{fit.auc_p.text()}, Brier {fit.brier.text()} (always the success rate: {fit.base_brier:.3f})",
    ]
    return "\n".join(lines)


def _gripper_settings(config: AnnotatorConfig, gripper=None):
    """The grip force and pad friction ``config`` simulates ``gripper`` (None: the RG2) with: its
    description's unless the configuration sets them."""
    from annotator.grippers import load_gripper
    from annotator.sim.gripper import GripperSettings

    return GripperSettings.resolve(load_gripper(gripper), config.gripper)


def _max_width(config: AnnotatorConfig, gripper=None) -> float:
    from annotator.sim.hand import max_width

    return max_width(config, gripper)


def _nearness(s: Setting, labelled) -> float:
    """How far a setting is from the labelling configuration: summed |log ratios| of its parameters."""
    near = abs(np.log(s.friction / labelled.pad_lateral_friction)) + abs(np.log(max(s.severity, 1e-3)))
    if s.force is not None:
        near += abs(np.log(s.force / labelled.grip_force))
    return float(near)


def rank(table: pd.DataFrame, objective: str = "balanced") -> pd.DataFrame:
    """The settings of a calibration table best first: ``objective`` (balanced accuracy or
    accuracy) highest, then the other one, then nearest the labelling configuration."""
    if objective not in OBJECTIVES:
        raise ValueError(f"objective {objective!r}: choose from {', '.join(OBJECTIVES)}")
    other = "accuracy" if objective == "balanced" else "balanced"
    return table.sort_values([objective, other, "_near"], ascending=[False, False, True], kind="stable")


def _record(s: Setting, sim: np.ndarray, a: Agreement, near: float) -> dict[str, Any]:
    record: dict[str, Any] = {
        "friction": s.friction,
        "force": np.nan if s.force is None else s.force,
        "severity": s.severity,
        "sim_success": float(sim.mean()) if len(sim) else float("nan"),
    }
    for name in STATISTICS:
        record[name] = a.value(name)
        record[f"{name}_lo"], record[f"{name}_hi"] = a.interval(name)
    record.update({"_near": near, "_agreement": a, "_setting": s})
    return record


def score_settings(
    real: np.ndarray,
    simulated: dict[Setting, np.ndarray],
    settings: list[Setting],
    labelled,
    bootstrap: int = BOOTSTRAP_SAMPLES,
    seed: int = 0,
    rows: np.ndarray | None = None,
) -> pd.DataFrame:
    """One row per setting: its agreement with ``real`` on the trials ``rows`` (index array; all
    when None), with the private columns ``_near``, ``_agreement`` and ``_setting``."""
    import pandas as pd

    rows = np.arange(len(real)) if rows is None else np.asarray(rows)
    records = []
    for s in settings:
        sim = simulated[s][rows]
        records.append(_record(s, sim, agreement(real[rows], sim, bootstrap, seed), _nearness(s, labelled)))
    return pd.DataFrame(records)


def calibrate(
    trials: pd.DataFrame,
    base: AnnotatorConfig,
    objects_dir: Path,
    settings: list[Setting],
    workers: int = 1,
    seed: int = 0,
    bootstrap: int = BOOTSTRAP_SAMPLES,
    *,
    objective: str = "balanced",
    gripper=None,
    resting: bool | str | None = False,
    simulated: dict[Setting, np.ndarray] | None = None,
) -> CalibrationResult:
    """Simulate ``trials`` (from :func:`read_real_trials`) under every setting and rank them by
    ``objective``; ``simulated``: outcomes already simulated (as :func:`simulate_grid` gives)."""
    if simulated is None:
        grid = simulate_grid(trials, settings, base, objects_dir, workers, seed, gripper, resting)
        simulated = {s: grid[s] for s in settings}
    real = trials["real_success"].to_numpy(dtype=bool)
    table = score_settings(real, simulated, settings, _gripper_settings(base, gripper), bootstrap, seed)
    best_row = rank(table, objective).iloc[0]
    best = best_row["_setting"]
    forces = trials["grip_force"].unique() if "grip_force" in trials.columns else []
    force = float(forces[0]) if best.force is None and len(forces) == 1 else None
    return CalibrationResult(
        table.drop(columns=["_near", "_agreement", "_setting"]),
        best,
        best_row["_agreement"],
        best.config(base, force),
        simulated,
        objective,
    )


# ------------------------------------------------------------------------------------ cross-validation


@dataclass(frozen=True)
class Fold:
    """One fold of the object-wise cross-validation: the objects held out, the setting chosen on
    the other objects' trials (and its agreement there), and its agreement on the held-out ones."""

    index: int
    held_out: tuple[str, ...]
    fitted_on: tuple[str, ...]
    best: Setting
    fit: Agreement
    held: Agreement


@dataclass(frozen=True)
class CrossValidation:
    """Folds, and the held-out predictions of all folds pooled (``predicted``, row order of the
    trials) with their agreement: what the calibration predicts on objects it has not seen."""

    folds: tuple[Fold, ...]
    predicted: np.ndarray
    pooled: Agreement


def object_folds(object_ids, folds: int, seed: int = 0) -> list[tuple[str, ...]]:
    """The objects split into ``min(folds, number of objects)`` groups of (nearly) equal size:
    sorted ids in a seeded random order, dealt out in turn. Depends only on the ids and ``seed``."""
    from annotator.rng import keyed_rng

    ids = sorted({str(o) for o in object_ids})
    k = max(1, min(int(folds), len(ids)))
    order = keyed_rng("calibrate-folds", seed, len(ids)).permutation(len(ids))
    return [tuple(sorted(ids[i] for i in order[f::k])) for f in range(k)]


def cross_validate(
    trials: pd.DataFrame,
    simulated: dict[Setting, np.ndarray],
    settings: list[Setting],
    labelled,
    folds: int = DEFAULT_FOLDS,
    seed: int = 0,
    objective: str = "balanced",
    bootstrap: int = BOOTSTRAP_SAMPLES,
) -> CrossValidation:
    """Object-wise cross-validation of the choice of setting: for each fold, the best setting by
    ``objective`` on the trials of the other objects, scored on the fold's own trials. Needs at
    least two objects. ``labelled``: the labelling configuration's gripper settings (ties)."""
    real = trials["real_success"].to_numpy(dtype=bool)
    objects = trials["object_id"].astype(str).to_numpy()
    groups = object_folds(objects, folds, seed)
    if len(groups) < 2:
        raise ValueError("cross-validation by object needs trials on at least two objects")
    predicted = np.zeros(len(trials), dtype=bool)
    out = []
    for f, held_out in enumerate(groups):
        held = np.isin(objects, held_out)
        fit_rows, held_rows = np.flatnonzero(~held), np.flatnonzero(held)
        table = score_settings(real, simulated, settings, labelled, bootstrap, seed, fit_rows)
        best_row = rank(table, objective).iloc[0]
        best = best_row["_setting"]
        predicted[held_rows] = simulated[best][held_rows]
        fitted_on = tuple(sorted(set(objects[fit_rows])))
        held_agreement = agreement(real[held_rows], simulated[best][held_rows], bootstrap, seed)
        out.append(Fold(f, tuple(held_out), fitted_on, best, best_row["_agreement"], held_agreement))
    return CrossValidation(tuple(out), predicted, agreement(real, predicted, bootstrap, seed))


def outcomes_table(trials: pd.DataFrame, simulated: dict[Setting, np.ndarray]) -> pd.DataFrame:
    """Every simulated outcome of the grid, one row per (setting, trial): ``object_id``,
    ``grasp_id``, ``real_success``, ``friction``, ``force`` (NaN: each trial's own), ``severity``,
    ``sim_success``."""
    import pandas as pd

    parts = []
    for s, sim in simulated.items():
        part = trials[["object_id", "grasp_id", "real_success"]].reset_index(drop=True).copy()
        part["friction"] = s.friction
        part["force"] = np.nan if s.force is None else s.force
        part["severity"] = s.severity
        part["sim_success"] = np.asarray(sim, dtype=bool)
        parts.append(part)
    return pd.concat(parts, ignore_index=True)


# ------------------------------------------------------------------------------------ output


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(float(v)) if isinstance(v, float) else str(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def config_toml(config: AnnotatorConfig, header: str = "", keep=None) -> str:
    """The fields of ``config`` that differ from the defaults, and those ``keep`` names per
    section (``{"robust": {"position_sigma"}}``: written even at the default, so that a gripper's
    own ``[robust]`` cannot replace them), as TOML for ``--config``."""
    defaults = AnnotatorConfig().to_dict()
    keep = keep or {}
    lines = [f"# {line}" for line in header.splitlines()]
    for section, values in config.to_dict().items():
        wanted = keep.get(section, ())
        changed = {k: v for k, v in values.items() if k in wanted or defaults.get(section, {}).get(k) != v}
        if changed:
            lines.append(f"\n[{section}]")
            lines += [f"{k} = {_toml_value(v)}" for k, v in changed.items()]
    return "\n".join(lines).lstrip("\n") + "\n"


def _pct(v: float, lo: float, hi: float, width: int = 17) -> str:
    if not np.isfinite(v):
        return f"{'n/a':>{width}}"
    return f"{100 * v:5.1f} [{100 * lo:3.0f},{100 * hi:4.0f}]".rjust(width)


def format_table(result: CalibrationResult) -> str:
    """The grid as text, best setting marked, intervals in brackets."""
    head = (
        f"  {'friction':>8} {'force N':>7} {'shake':>5} {'sim ok':>6} "
        f"{'accuracy % [95% CI]':>19} {'balanced %':>17} {'precision %':>17} {'recall %':>17}"
    )
    lines = [head]
    t = result.table
    for r in t.itertuples(index=False):
        s = result.best
        mark = (
            "*"
            if (r.friction, r.severity) == (s.friction, s.severity)
            and ((np.isnan(r.force) and s.force is None) or r.force == s.force)
            else " "
        )
        force = "real" if np.isnan(r.force) else f"{r.force:g}"
        lines.append(
            f"{mark} {r.friction:>8.2f} {force:>7} {r.severity:>5.2f} {100 * r.sim_success:>5.0f}% "
            f"{_pct(r.accuracy, r.accuracy_lo, r.accuracy_hi, 19)} "
            f"{_pct(r.balanced, r.balanced_lo, r.balanced_hi)} "
            f"{_pct(r.precision, r.precision_lo, r.precision_hi)} {_pct(r.recall, r.recall_lo, r.recall_hi)}"
        )
    return "\n".join(lines)


def setting_text(s: Setting) -> str:
    """``pad friction 0.6, 70 N, shake x1``."""
    force = "each trial's own force" if s.force is None else f"{s.force:g} N"
    return f"pad friction {s.friction:g}, {force}, shake x{s.severity:g}"


def format_folds(cv: CrossValidation) -> str:
    """Each fold (objects held out, the setting chosen on the others, its agreement on the held-out
    trials), then the pooled held-out agreement."""
    lines = []
    for f in cv.folds:
        lines.append(
            f"fold {f.index + 1}/{len(cv.folds)}: fit on {len(f.fitted_on)} objects ({f.fit.n} trials) -> "
            f"{setting_text(f.best)}; held out {', '.join(f.held_out)} ({f.held.n} trials): "
            f"{agreement_text(f.held, ('accuracy', 'balanced', 'precision'))}"
        )
    lines.append(f"cross-validated by object, {cv.pooled.n} held-out trials: {agreement_text(cv.pooled)}")
    return "\n".join(lines)
