"""Fit the uncertain physics to real trials: pad friction, grip force and shake severity.

The user executes some labelled grasps on their real UR3 + RG2 and records ``object_id,
grasp_id, real_success`` (optionally ``grip_force``, N, the force they used). Each of those grasps
is re-simulated (:mod:`annotator.tools.given`: the grasp the label records as commanded, as the
robot executes it) under every setting of a grid, and the simulated outcome is compared with the real one:
accuracy, precision and recall of "success", with percentile bootstrap confidence intervals
over the trials. The best setting (highest accuracy; ties: higher balanced accuracy, then the
setting nearest the labelling configuration) is written as a TOML file for ``--config``.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from annotator.config import AnnotatorConfig

if TYPE_CHECKING:  # pandas is imported where it is used: `annotator --help` stays fast
    import pandas as pd

log = logging.getLogger(__name__)

DEFAULT_FRICTIONS = (0.3, 0.45, 0.6, 0.8, 1.0)  # pad friction; OnRobot's own model uses 0.4, ACRONYM 1.0
DEFAULT_FORCES = (20.0, 30.0, 40.0)  # N; the RG2 drives 3..40 N
DEFAULT_SEVERITIES = (0.5, 1.0, 1.5)  # x the shake's amplitude and angle
BOOTSTRAP_SAMPLES = 2000
CONFIDENCE = 0.95
REAL_COLUMNS = ("object_id", "grasp_id", "real_success")


@dataclass(frozen=True)
class Setting:
    """One point of the grid: pad friction, grip force (N, None: each trial's own) and severity."""

    friction: float
    force: float | None
    severity: float

    def config(self, base: AnnotatorConfig, force: float | None = None) -> AnnotatorConfig:
        """``base`` with this setting (``force`` overrides the setting's, e.g. a trial's own)."""
        grip = force if force is not None else self.force
        gripper = dataclasses.replace(
            base.gripper,
            pad_lateral_friction=float(self.friction),
            **({"grip_force": float(grip)} if grip is not None else {}),
        )
        protocol = dataclasses.replace(
            base.protocol,
            shake_amplitude=base.protocol.shake_amplitude * self.severity,
            shake_angle=base.protocol.shake_angle * self.severity,
        )
        return dataclasses.replace(base, gripper=gripper, protocol=protocol)


@dataclass(frozen=True)
class Agreement:
    """Agreement of simulated with real outcomes; each statistic with its (low, high) interval.

    Positive is "success". ``nan`` where undefined (no simulated successes for precision, no real
    ones for recall).
    """

    n: int
    accuracy: float
    precision: float
    recall: float
    balanced: float
    accuracy_ci: tuple[float, float]
    precision_ci: tuple[float, float]
    recall_ci: tuple[float, float]


def _rates(real: np.ndarray, sim: np.ndarray) -> np.ndarray:
    """(..., 4) accuracy, precision, recall, balanced accuracy over the last axis of bool arrays."""
    tp = np.sum(real & sim, axis=-1)
    tn = np.sum(~real & ~sim, axis=-1)
    fp = np.sum(~real & sim, axis=-1)
    fn = np.sum(real & ~sim, axis=-1)
    n = real.shape[-1]
    with np.errstate(invalid="ignore", divide="ignore"):
        acc = (tp + tn) / n
        prec = tp / (tp + fp)
        rec = tp / (tp + fn)
        spec = tn / (tn + fp)
        bal = np.where(np.isnan(spec), rec, np.where(np.isnan(rec), spec, (rec + spec) / 2))
    return np.stack(np.broadcast_arrays(acc, prec, rec, bal), axis=-1)


def agreement(
    real: np.ndarray, sim: np.ndarray, samples: int = BOOTSTRAP_SAMPLES, seed: int = 0
) -> Agreement:
    """Statistics of ``sim`` against ``real`` (bool (n,)) with percentile bootstrap intervals.

    The resampling indices depend only on ``seed`` and ``n`` (the same for every setting, so
    settings are compared on the same resamples).
    """
    real, sim = np.asarray(real, bool), np.asarray(sim, bool)
    n = len(real)
    point = _rates(real, sim)
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(seed), n, 0x43414C])))
    idx = rng.integers(0, n, size=(samples, n))
    boot = _rates(real[idx], sim[idx])
    alpha = (1 - CONFIDENCE) / 2
    lo, hi = np.full(4, np.nan), np.full(4, np.nan)
    defined = ~np.all(np.isnan(boot), axis=0) if n else np.zeros(4, bool)  # e.g. precision, no successes
    if defined.any():
        lo[defined] = np.nanquantile(boot[:, defined], alpha, axis=0)
        hi[defined] = np.nanquantile(boot[:, defined], 1 - alpha, axis=0)
    return Agreement(
        n,
        *(float(v) for v in point),
        (float(lo[0]), float(hi[0])),
        (float(lo[1]), float(hi[1])),
        (float(lo[2]), float(hi[2])),
    )


@dataclass
class CalibrationResult:
    """Every setting's agreement (``table``: one row per setting) and the best one."""

    table: pd.DataFrame
    best: Setting
    best_agreement: Agreement
    config: AnnotatorConfig
    simulated: dict[Setting, np.ndarray]


def read_real_trials(path: Path, labels: pd.DataFrame) -> pd.DataFrame:
    """REAL.csv joined with the labels (pose, width, outcome); one-line errors for bad input."""
    import pandas as pd

    from annotator.tools.common import ToolError

    try:
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
    success = real["real_success"]
    if success.dtype != bool:
        text = success.astype(str).str.strip().str.lower()
        mapping = {"1": True, "0": False, "true": True, "false": False, "yes": True, "no": False}
        if not text.isin(list(mapping)).all():
            bad = success[~text.isin(list(mapping))].iloc[0]
            raise ToolError(f"{path}: real_success must be 1/0 or true/false, got {bad!r}")
        real["real_success"] = text.map(mapping).astype(bool)
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


def _simulate_task(setting, base, span, force, seed):
    from annotator.tools.given import simulate_given

    rows, error = simulate_given(span, setting.config(base, force), seed)
    return setting, span.object_id, force, rows, error


def simulate_grid(
    trials: pd.DataFrame,
    settings: list[Setting],
    base: AnnotatorConfig,
    objects_dir: Path,
    workers: int = 1,
    seed: int = 0,
) -> dict[Setting, np.ndarray]:
    """Simulated success of every trial (row order of ``trials``) under every setting."""
    import joblib

    from annotator.objects import ObjectDiscoveryError, discover_objects
    from annotator.tools.common import ToolError
    from annotator.tools.given import GivenSpan, replay_grasps

    try:
        sources = {s.object_id: s for s in discover_objects(Path(objects_dir))}
    except ObjectDiscoveryError as exc:
        raise ToolError(str(exc)) from None
    missing = sorted(set(trials["object_id"]) - set(sources))
    if missing:
        raise ToolError(f"object(s) {missing} are not in {objects_dir}")
    has_force = "grip_force" in trials.columns
    groups = trials.groupby(["object_id", "grip_force"] if has_force else ["object_id"], sort=True)
    stroke = _max_width(base)
    tasks, where = [], {}
    for key, idx in groups.indices.items():
        key = key if isinstance(key, tuple) else (key,)
        oid, force = str(key[0]), (float(key[1]) if has_force else None)
        rows = trials.iloc[idx]
        scale = float(rows["object_scale"].iloc[0])
        T, width, quat = replay_grasps(rows, base, stroke)
        span = GivenSpan(oid, sources[oid], scale, T, width, rows["grasp_id"].to_numpy(), quat)
        where[(oid, force)] = idx
        for setting in settings:
            tasks.append(joblib.delayed(_simulate_task)(setting, base, span, force, seed))
    out = {s: np.zeros(len(trials), dtype=bool) for s in settings}
    for setting, oid, force, rows, error in joblib.Parallel(n_jobs=workers, return_as="generator_unordered")(
        tasks
    ):
        if error is not None:
            raise ToolError(f"{oid}: {error}")
        out[setting][where[(oid, force)]] = rows["success"].to_numpy(dtype=bool)
    return out


def _gripper_settings(config: AnnotatorConfig):
    """The grip force and pad friction ``config`` simulates the gripper (the RG2) with: its
    description's unless the configuration sets them."""
    from annotator.grippers import default_gripper
    from annotator.sim.gripper import GripperSettings

    return GripperSettings.resolve(default_gripper(), config.gripper)


def _max_width(config: AnnotatorConfig) -> float:
    from annotator.pipeline.worker import max_width

    return max_width(config)


def calibrate(
    trials: pd.DataFrame,
    base: AnnotatorConfig,
    objects_dir: Path,
    settings: list[Setting],
    workers: int = 1,
    seed: int = 0,
    bootstrap: int = BOOTSTRAP_SAMPLES,
) -> CalibrationResult:
    """Simulate ``trials`` (from :func:`read_real_trials`) under every setting and rank them."""
    simulated = simulate_grid(trials, settings, base, objects_dir, workers, seed)
    real = trials["real_success"].to_numpy(dtype=bool)
    records = []
    labelled = _gripper_settings(base)
    for s in settings:
        a = agreement(real, simulated[s], bootstrap, seed)
        # nearness to the labelling configuration, for ties: log ratios of each parameter
        near = abs(np.log(s.friction / labelled.pad_lateral_friction)) + abs(np.log(s.severity))
        if s.force is not None:
            near += abs(np.log(s.force / labelled.grip_force))
        records.append(
            {
                "friction": s.friction,
                "force": np.nan if s.force is None else s.force,
                "severity": s.severity,
                "sim_success": float(simulated[s].mean()),
                "accuracy": a.accuracy,
                "accuracy_lo": a.accuracy_ci[0],
                "accuracy_hi": a.accuracy_ci[1],
                "precision": a.precision,
                "precision_lo": a.precision_ci[0],
                "precision_hi": a.precision_ci[1],
                "recall": a.recall,
                "recall_lo": a.recall_ci[0],
                "recall_hi": a.recall_ci[1],
                "balanced": a.balanced,
                "_near": near,
                "_agreement": a,
                "_setting": s,
            }
        )
    import pandas as pd

    table = pd.DataFrame(records)
    ranked = table.sort_values(
        ["accuracy", "balanced", "_near"], ascending=[False, False, True], kind="stable"
    )
    best_row = ranked.iloc[0]
    best = best_row["_setting"]
    forces = trials["grip_force"].unique() if "grip_force" in trials.columns else []
    force = float(forces[0]) if best.force is None and len(forces) == 1 else None
    result = CalibrationResult(
        table.drop(columns=["_near", "_agreement", "_setting"]),
        best,
        best_row["_agreement"],
        best.config(base, force),
        simulated,
    )
    return result


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


def config_toml(config: AnnotatorConfig, header: str = "") -> str:
    """The fields of ``config`` that differ from the defaults, as TOML for ``--config``."""
    defaults = AnnotatorConfig().to_dict()
    lines = [f"# {line}" for line in header.splitlines()]
    for section, values in config.to_dict().items():
        changed = {k: v for k, v in values.items() if defaults[section].get(k) != v}
        if changed:
            lines.append(f"\n[{section}]")
            lines += [f"{k} = {_toml_value(v)}" for k, v in changed.items()]
    return "\n".join(lines).lstrip("\n") + "\n"


def format_table(result: CalibrationResult) -> str:
    """The grid as text, best setting marked, intervals in brackets."""

    def pct(v: float, lo: float, hi: float) -> str:
        if not np.isfinite(v):
            return f"{'n/a':>19}"
        return f"{100 * v:5.1f} [{100 * lo:4.0f},{100 * hi:4.0f}]".rjust(19)

    head = (
        f"  {'friction':>8} {'force N':>7} {'shake':>5} {'sim ok':>6} "
        f"{'accuracy % [95% CI]':>19} {'precision %':>19} {'recall %':>19}"
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
        force = "real" if np.isnan(r.force) else f"{r.force:.0f}"
        lines.append(
            f"{mark} {r.friction:>8.2f} {force:>7} {r.severity:>5.2f} {100 * r.sim_success:>5.0f}% "
            f"{pct(r.accuracy, r.accuracy_lo, r.accuracy_hi)} "
            f"{pct(r.precision, r.precision_lo, r.precision_hi)} {pct(r.recall, r.recall_lo, r.recall_hi)}"
        )
    return "\n".join(lines)
