"""The execution's uncertainty fitted to real trials: the ``[robust]`` ranges the data identify,
the stage the perturbed trials are judged at, trial 0's gate, the trial count and the mapping of
the score, chosen by the likelihood of the real outcomes.

``annotator calibrate --fit-ranges`` runs it (docs/decisions/0027-execution-fitted-to-real-trials.md):

1. **Exploration.** Every real grasp is simulated with ``M`` perturbed trials drawn from a
   *proposal*: each group of ranges (:data:`GROUPS`: the pose errors, where the object is and
   where the hand goes; the object's friction spread) is scaled, trial by trial, by a level of
   :data:`LEVELS` drawn for it (``[robust] scale_levels``); the perturbed
   trials also run after a trial 0 that collides (``perturb_collisions``) and through the
   benchmark motion when the protocol has one. Each trial records how far it held
   (``trial_stages``); its draws are drawn again here from the same keyed generator, so nothing
   but the stages travels back from the workers.
2. **Importance weights.** For levels ``theta`` (one per group), a trial's weight is the density
   of its draws under ``theta`` over their density under the proposal (a mixture over the
   levels: no group's factor exceeds ``len(LEVELS)``). The probability that a perturbed
   execution holds through a stage is the weighted share of trials that held: ``p_i(theta)``.
3. **The execution's model.** The real grasp holds with ``e1 + (1 - e0 - e1) p_i(theta)``: the
   lapse rates ``e0``, ``e1`` are what no range explains. The levels, the stage and the lapses
   maximise the likelihood of the real outcomes; a group whose levels the data cannot tell apart
   (within the 95 % likelihood-ratio interval) keeps the run's own range.
4. **The score and its mapping.** With ``K`` trials a row's score is trial 0 (held through the
   gate, or not) plus ``Binomial(K - 1, p_i)``, over ``K``; its mapping to the probability that
   the real grasp holds is the isotonic regression of the real outcomes on the score, each grasp
   weighted by the probability of each score value (:func:`expected_mapping`). The gate and
   ``K`` are chosen by the expected likelihood and Brier score under that mapping.

The fit is cross-validated by object (:func:`cross_validate`: each fold's whole fit made on the
other objects alone). Everything after the exploration is NumPy on an (n grasps, M trials) table.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from annotator.config import AnnotatorConfig, RobustConfig
from annotator.outcome import Stage

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Component:
    """One ``[robust]`` range of a :class:`RangeGroup`: the field, its size at level 1 (``unit``: m,
    rad or a friction coefficient) and how it is drawn: ``"gauss"`` (``dims`` Gaussian components
    with that sigma) or ``"uniform"`` (uniform in +-unit)."""

    field: str
    unit: float
    kind: str = "gauss"
    dims: int = 1

    def density(self, v: np.ndarray, size: float) -> np.ndarray:
        """Density of draws ``v`` (..., dims) at the range ``size`` (sigma, or the uniform's half
        width), (...)."""
        size = max(float(size), self.unit * OWN_FLOOR)
        if self.kind == "uniform":
            return np.where(np.abs(v[..., 0]) <= size, 1.0 / (2.0 * size), 0.0)
        z = v / size
        return np.prod(np.exp(-0.5 * z * z) / (size * math.sqrt(2.0 * math.pi)), axis=-1)


@dataclass(frozen=True)
class RangeGroup:
    """Ranges the fit scales together by one level (``[robust] scale_levels`` draws one per group
    and trial): the pose errors, the friction spread."""

    name: str
    components: tuple[Component, ...]

    def density(self, draws: Draws, sizes: Mapping[str, float]) -> np.ndarray:
        """Density of every trial's draws of this group at the ranges ``sizes`` (field -> size),
        (n, M)."""
        out = np.ones(draws.values[self.components[0].field].shape[:2])
        for c in self.components:
            out = out * c.density(draws.values[c.field], sizes[c.field])
        return out

    def at(self, level: float) -> dict[str, float]:
        """This group's ranges at a scale level: field -> unit x level."""
        return {c.field: c.unit * level for c in self.components}


# The ranges the fit scales (docs/decisions/0027), each group by one level, with their sizes at
# level 1. The pose errors are one group: where the object really is (placement per horizontal
# axis, yaw) and where the hand really goes (across the approach per TCP axis, along it) all move
# the grasp against the object, and real outcomes cannot tell one from the other; their ratio is
# that of these sizes. The object's friction spread is the other.
GROUPS: tuple[RangeGroup, ...] = (
    RangeGroup(
        "pose",
        (
            Component("object_position_sigma", 0.002, dims=2),
            Component("object_yaw_sigma", 0.035),
            Component("position_sigma", 0.001, dims=2),
            Component("approach_sigma", 0.002),
        ),
    ),
    RangeGroup("friction", (Component("friction_delta", 0.1, "uniform"),)),
)
COMPONENTS: tuple[Component, ...] = tuple(c for g in GROUPS for c in g.components)
# The scale levels every group is explored at: from half to eight times its sizes.
LEVELS: tuple[float, ...] = (0.5, 1.0, 2.0, 4.0, 8.0)
# A range of 0 has no density to weigh draws by: the run's own ranges are taken at least this share
# of their units (a tenth of a micrometre of placement; nothing a grasp notices).
OWN_FLOOR = 1e-4
# Perturbed trials per real grasp in the exploration (M).
EXPLORE_TRIALS = 64
# The trial counts K a profile may choose; the smallest whose expected Brier score is within
# K_TOLERANCE of the best is chosen (more trials cost more and add less and less).
TRIAL_COUNTS: tuple[int, ...] = (5, 10, 20)
K_TOLERANCE = 0.002
# Trial 0's gates and the perturbed trials' last stage the fit chooses among.
GATES: tuple[str, ...] = ("lift", "motion", "shake")
PERTURBED_STAGES: tuple[str, ...] = ("lift", "motion")
# Probabilities are kept this far from 0 and 1 in the log-likelihood (a model fitted on a few
# hundred trials never knows a grasp holds or fails for certain).
P_CLIP = 0.01


def exploration_config(base: AnnotatorConfig, levels: Sequence[float] = LEVELS) -> AnnotatorConfig:
    """``base`` with the proposal's ``[robust]``: each range of :data:`COMPONENTS` at its unit, each
    group scaled per trial by a level of ``levels``; perturbed trials after a colliding trial 0 and
    through the benchmark motion (if any); the rest of ``base``'s ranges (mass, tilt, force,
    rotation, centre of mass) as they are. Every field is set explicitly, so a gripper's own
    ``[robust]`` table cannot replace it."""
    robust = dataclasses.asdict(base.robust)
    robust.update({c.field: c.unit for c in COMPONENTS})
    robust.update(scale_levels=tuple(float(v) for v in levels), perturb_collisions=True, motion=True)
    robust["shake"] = False
    data = base.to_dict()
    data["robust"] = robust
    return AnnotatorConfig.from_dict(data)


@dataclass(frozen=True)
class Draws:
    """Every perturbed trial's draws of each fitted range: ``values[field]`` (n grasps, M trials,
    dims) in the field's unit (m, rad, friction)."""

    values: dict[str, np.ndarray]

    @property
    def shape(self) -> tuple[int, int]:
        return self.values[COMPONENTS[0].field].shape[:2]

    def take(self, rows: np.ndarray) -> Draws:
        return Draws({k: v[rows] for k, v in self.values.items()})


def draws_of(robust: RobustConfig, seed: int, keys: Sequence[tuple[str, int]], m: int) -> Draws:
    """The draws of ``m`` perturbed trials of each grasp ``(unit, index)`` (the object and the
    grasp's index in its span: the key of :func:`annotator.rng.trial_rng`), as the workers drew
    them with ``robust`` (the ranges the trial used: the run's over the gripper's)."""
    from annotator.rng import trial_rng
    from annotator.trial import Perturbation

    n = len(keys)
    out = {c.field: np.zeros((n, m, c.dims)) for c in COMPONENTS}
    for i, (unit, index) in enumerate(keys):
        rng = trial_rng(seed, unit, int(index))
        for j in range(m):
            p = Perturbation.sample(rng, robust)
            out["object_position_sigma"][i, j] = p.object_shift[:2]
            out["object_yaw_sigma"][i, j, 0] = p.object_rotvec[2]
            out["position_sigma"][i, j] = p.T_tcp_tcp.pos[:2]
            out["approach_sigma"][i, j, 0] = p.T_tcp_tcp.pos[2]
            out["friction_delta"][i, j, 0] = p.friction_delta
    return Draws(out)


@dataclass(frozen=True)
class Exploration:
    """What the exploration gave for ``n`` real grasps: trial 0's stage ``stage0`` (n,) int, the
    perturbed trials' stages ``stages`` (n, M) int (:class:`annotator.outcome.Stage` values), their
    draws, the scale ``levels`` explored and ``own``: the run's own ranges (field -> size).

    A group's candidates are the levels, by index, and the run's own ranges, index
    ``len(levels)`` (:attr:`own_index`): a group the data do not identify keeps them exactly."""

    stage0: np.ndarray
    stages: np.ndarray
    draws: Draws
    levels: tuple[float, ...]
    own: Mapping[str, float]

    @classmethod
    def of(
        cls, trial_stages: Sequence[str], draws: Draws, levels: Sequence[float], own: RobustConfig
    ) -> Exploration:
        """From each grasp's ``trial_stages`` (trial 0 first, then M perturbed trials) and the
        run's own ``[robust]``."""
        m = draws.shape[1]
        bad = [s for s in trial_stages if len(s) != m + 1]
        if bad:
            raise ValueError(f"a grasp's trial_stages has {len(bad[0])} trials, not {m + 1}: {bad[0]!r}")
        digits = np.array([[int(c) for c in s] for s in trial_stages], dtype=np.int64).reshape(-1, m + 1)
        sizes = {c.field: float(getattr(own, c.field)) for c in COMPONENTS}
        return cls(digits[:, 0], digits[:, 1:], draws, tuple(float(v) for v in levels), sizes)

    @property
    def own_index(self) -> int:
        """The candidate index of the run's own ranges (after the levels)."""
        return len(self.levels)

    def sizes(self, group: RangeGroup, index: int) -> dict[str, float]:
        """A group's ranges at candidate ``index``: a level's, or the run's own."""
        if index == self.own_index:
            return {c.field: self.own[c.field] for c in group.components}
        return group.at(self.levels[index])

    def label(self, index: int) -> str:
        """``x2`` for a level, ``the run's own`` for the own ranges."""
        return "the run's own" if index == self.own_index else f"x{self.levels[index]:g}"

    def take(self, rows: np.ndarray) -> Exploration:
        """These grasps only."""
        return Exploration(self.stage0[rows], self.stages[rows], self.draws.take(rows), self.levels, self.own)

    def save(self, path: Path, key: str) -> None:
        """Write it to ``path`` (NumPy's .npz, through a temporary file and a rename) under ``key``:
        what it was explored from, so that :meth:`load` never returns another exploration's."""
        import json

        from annotator.files import atomic_write

        arrays: dict[str, Any] = {f"draw_{k}": v for k, v in self.draws.values.items()}
        meta = json.dumps({"key": key, "levels": list(self.levels), "own": dict(self.own)})
        arrays.update(stage0=self.stage0, stages=self.stages, meta=np.array(meta))
        atomic_write(path, lambda fh: np.savez(fh, **arrays))

    @classmethod
    def load(cls, path: Path, key: str) -> Exploration | None:
        """The exploration :meth:`save` wrote to ``path`` under ``key``; None if there is none, or
        it was explored from anything else, or it cannot be read."""
        import json

        try:
            with np.load(path, allow_pickle=False) as data:
                meta = json.loads(str(data["meta"]))
                if meta.get("key") != key:
                    return None
                draws = Draws({c.field: data[f"draw_{c.field}"] for c in COMPONENTS})
                return cls(data["stage0"], data["stages"], draws, tuple(meta["levels"]), meta["own"])
        except (OSError, ValueError, KeyError):
            return None

    def ratios(self) -> list[np.ndarray]:
        """Per group, the target-over-proposal density ratio of every trial at every candidate,
        (L + 1, n, M): the factors of the importance weights (at most L each at a level)."""
        out = []
        for g in GROUPS:
            grid = np.stack([g.density(self.draws, g.at(level)) for level in self.levels])  # (L, n, M)
            proposal = grid.mean(axis=0)
            target = np.concatenate([grid, g.density(self.draws, self.sizes(g, self.own_index))[None]])
            with np.errstate(invalid="ignore", divide="ignore"):
                out.append(np.where(proposal > 0, target / proposal, 0.0))
        return out


def held_share(ratios: list[np.ndarray], theta: Sequence[int], held: np.ndarray) -> np.ndarray:
    """``p_i(theta)`` (n,): the importance-weighted share of each grasp's perturbed trials that
    held (``held`` (n, M) bool) under the levels ``theta`` (an index into the levels per group).
    A grasp whose weights are all zero holds with its plain share."""
    w = _weights(ratios, theta)
    total = w.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        share = (w * held).sum(axis=1) / total
    return np.where(total > 0, share, held.mean(axis=1))


def _weights(ratios: list[np.ndarray], theta: Sequence[int]) -> np.ndarray:
    w = ratios[0][theta[0]]
    for r, level in zip(ratios[1:], theta[1:], strict=True):
        w = w * r[level]
    return w


def effective_trials(ratios: list[np.ndarray], theta: Sequence[int]) -> np.ndarray:
    """Kish's effective number of the M perturbed trials per grasp under ``theta``, (n,)."""
    w = _weights(ratios, theta)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.nan_to_num(w.sum(axis=1) ** 2 / (w * w).sum(axis=1))


def _held(stage: np.ndarray, name: str) -> np.ndarray:
    """Held through the stage a gate names (``"lift"``, ``"motion"``, ``"shake"``)."""
    return np.asarray(stage) >= int(Stage.from_label(name))


# ------------------------------------------------------------------------ the execution's model

# The lapse rates tried: a real execution fails (holds) whatever the simulation says with
# probability e0 (e1): what the model cannot know (a camera's bad frame, a cable).
LAPSES: tuple[float, ...] = (0.0, 0.02, 0.05, 0.1)
# The log-likelihood a level may lose against the best and still be within the 95 %
# likelihood-ratio interval of one parameter (chi-square, one degree of freedom: 3.84 / 2).
LIKELIHOOD_INTERVAL = 3.84 / 2


@dataclass(frozen=True)
class ExecutionModel:
    """The execution's model: levels ``theta`` (index per group), the perturbed trials' last
    ``stage``, and lapse rates ``fail`` (e0) and ``hold`` (e1): the probability that the real
    grasp holds is ``e1 + (1 - e0 - e1) p_i(theta, stage)``."""

    theta: tuple[int, ...]
    stage: str
    fail: float
    hold: float

    def probability(self, p: np.ndarray) -> np.ndarray:
        return self.hold + (1.0 - self.fail - self.hold) * p


def _loglik(q: np.ndarray, y: np.ndarray) -> float:
    q = np.clip(q, P_CLIP, 1.0 - P_CLIP)
    return float(np.sum(np.where(y, np.log(q), np.log1p(-q))))


def _best_lapses(p: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """(log-likelihood, e0, e1) of the best lapse rates for the shares ``p``."""
    best = (-math.inf, 0.0, 0.0)
    for e0 in LAPSES:
        for e1 in LAPSES:
            if e0 + e1 >= 1.0:
                continue
            v = _loglik(e1 + (1.0 - e0 - e1) * p, y)
            if v > best[0] + 1e-12:
                best = (v, e0, e1)
    return best


@dataclass(frozen=True)
class ExecutionFit:
    """The fitted :class:`ExecutionModel`, its log-likelihood, per group the profile likelihood over the
    levels (the best log-likelihood with that group at each level, all trials) and whether the
    data identify it (:func:`fit_execution`)."""

    execution: ExecutionModel
    loglik: float
    profile: dict[str, list[float]]
    identified: dict[str, bool]


def _table(
    exp: Exploration, y: np.ndarray, stages: Sequence[str], trials: np.ndarray | None = None
) -> dict[tuple[tuple[int, ...], str], tuple[float, float, float]]:
    """(levels, stage) -> (log-likelihood, e0, e1) of the best lapses, over every level of every
    group, using the perturbed trials ``trials`` (column indices; None: all)."""
    ratios = exp.ratios()
    if trials is not None:
        ratios = [r[:, :, trials] for r in ratios]
    out = {}
    for stage in stages:
        held = _held(exp.stages, stage)
        if trials is not None:
            held = held[:, trials]
        for theta in itertools.product(range(exp.own_index + 1), repeat=len(GROUPS)):
            out[(theta, stage)] = _best_lapses(held_share(ratios, theta, held), y)
    return out


def fit_execution(
    exp: Exploration,
    real: np.ndarray,
    stages: Sequence[str] = PERTURBED_STAGES,
) -> ExecutionFit:
    """The levels, perturbed stage and lapses that maximise the likelihood of ``real`` (n,) under
    the model of :class:`ExecutionModel`, each group free only where the data identify it; the others
    keep the run's own ranges (:attr:`Exploration.own_index`).

    A group is identified when its best level found on one half of the perturbed trials (even and
    odd columns) beats the run's own ranges on the other half by more than the 95 % likelihood-ratio
    interval (:data:`LIKELIHOOD_INTERVAL`), both ways: the importance weights make the likelihood
    of every level noisy, and a level chosen on noise does not win on trials it was not chosen on.
    """
    y = np.asarray(real, dtype=bool)
    base = (exp.own_index,) * len(GROUPS)
    m = exp.stages.shape[1]
    halves = (np.arange(0, m, 2), np.arange(1, m, 2))
    tables = [_table(exp, y, stages, h) for h in halves]
    found = {}
    for i, g in enumerate(GROUPS):
        wins = []
        for mine, other in ((tables[0], tables[1]), (tables[1], tables[0])):
            (theta, stage), _ = max(mine.items(), key=lambda kv: kv[1][0])
            at_base = theta[:i] + (base[i],) + theta[i + 1 :]
            wins.append(other[(theta, stage)][0] - other[(at_base, stage)][0] > LIKELIHOOD_INTERVAL)
        found[g.name] = all(wins)
    table = _table(exp, y, stages)
    n_levels = exp.own_index + 1
    profile = {
        g.name: [max(v[0] for (t, _), v in table.items() if t[i] == level) for level in range(n_levels)]
        for i, g in enumerate(GROUPS)
    }

    def allowed(theta: tuple[int, ...]) -> bool:
        return all(found[g.name] or theta[i] == base[i] for i, g in enumerate(GROUPS))

    (theta, stage), (ll, e0, e1) = max(
        ((key, v) for key, v in table.items() if allowed(key[0])), key=lambda kv: kv[1][0]
    )
    return ExecutionFit(ExecutionModel(theta, stage, e0, e1), ll, profile, found)


# ------------------------------------------------------------------------ the score and its mapping


def score_pmf(first: np.ndarray, p: np.ndarray, k: int) -> np.ndarray:
    """(n, k + 1): the probability that a grasp's score of ``k`` trials is ``j / k``: trial 0's
    ``first`` (n,) bool plus ``Binomial(k - 1, p)`` perturbed trials that held."""
    from scipy.stats import binom

    n = len(p)
    held = binom.pmf(np.arange(k)[None, :], k - 1, np.clip(p, 0.0, 1.0)[:, None])  # (n, k)
    out = np.zeros((n, k + 1))
    f = np.asarray(first, dtype=bool)
    out[~f, :k] = held[~f]
    out[f, 1:] = held[f]
    return out


@dataclass(frozen=True)
class ExpectedMapping:
    """The isotonic mapping of a score of ``k`` trials (values ``j / k``) to the probability that
    the real grasp holds: ``p`` (k + 1,), not decreasing, fitted on grasps weighted by the
    probability of each score value. Score values no grasp can reach take their neighbours'."""

    k: int
    p: np.ndarray

    def knots(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """The ``[confidence]`` knots: the score values where the probability changes, and it."""
        scores = np.arange(self.k + 1) / self.k
        change = np.diff(self.p) != 0
        keep = np.r_[True, change] | np.r_[change, True]
        return tuple(float(v) for v in scores[keep]), tuple(float(v) for v in self.p[keep])


def expected_mapping(pmf: np.ndarray, real: np.ndarray) -> ExpectedMapping:
    """Weighted pool-adjacent-violators over the score values: the real success rate at each
    value, each grasp counted with its probability of scoring it, pooled until it rises."""
    weight = pmf.sum(axis=0)
    success = (pmf * np.asarray(real, dtype=np.float64)[:, None]).sum(axis=0)
    k = pmf.shape[1] - 1
    blocks: list[list[float]] = []  # [successes, weight, first value, last value]
    for j in range(k + 1):
        if weight[j] <= 1e-12:
            continue
        blocks.append([success[j], weight[j], j, j])
        while len(blocks) > 1 and blocks[-2][0] / blocks[-2][1] >= blocks[-1][0] / blocks[-1][1]:
            s, w, _, last = blocks.pop()
            blocks[-1][0] += s
            blocks[-1][1] += w
            blocks[-1][3] = last
    p = np.full(k + 1, np.nan)
    for s, w, first, last in blocks:
        p[int(first) : int(last) + 1] = s / w
    known = ~np.isnan(p)
    if not known.any():
        p[:] = float(np.mean(real)) if len(real) else 0.5
    else:  # values no grasp reaches: the nearest fitted value below, else above (still monotone)
        idx = np.arange(k + 1)
        below = np.maximum.accumulate(np.where(known, idx, -1))
        p = np.where(below >= 0, p[np.maximum(below, 0)], p[np.argmax(known)])
    return ExpectedMapping(k, np.clip(p, 0.0, 1.0))


@dataclass(frozen=True)
class Scored:
    """Scores of ``k`` trials with trial 0 judged at ``gate`` on some grasps: their mapping, the
    expected log-likelihood and Brier score (means per grasp) of the real outcomes under it, each
    grasp's expected P(success) ``p`` and score distribution ``pmf`` (n, k + 1)."""

    gate: str
    k: int
    mapping: ExpectedMapping
    loglik: float
    brier: float
    p: np.ndarray
    pmf: np.ndarray


def score(
    first_stage: np.ndarray,
    share: np.ndarray,
    real: np.ndarray,
    gate: str,
    k: int,
    mapping: ExpectedMapping | None = None,
) -> Scored:
    """The scores of ``k`` trials (trial 0 held through ``gate`` by ``first_stage``, the perturbed
    ones with probability ``share``), their mapping fitted on ``real`` (unless given: held-out
    grasps are scored with their training mapping) and how well it predicts ``real``."""
    pmf = score_pmf(_held(first_stage, gate), share, k)
    if mapping is None:
        mapping = expected_mapping(pmf, real)
    m = np.clip(mapping.p, P_CLIP, 1.0 - P_CLIP)
    y = np.asarray(real, dtype=bool)
    loglik = float(np.mean((pmf * np.where(y[:, None], np.log(m)[None], np.log1p(-m)[None])).sum(axis=1)))
    brier = float(np.mean((pmf * (mapping.p[None, :] - y[:, None]) ** 2).sum(axis=1)))
    return Scored(gate, k, mapping, loglik, brier, pmf @ mapping.p, pmf)


def threshold_index(pmf: np.ndarray, real: np.ndarray) -> int:
    """The score value ``j`` (success: score >= j / k) with the highest expected balanced accuracy
    on these grasps; ties: the higher one (fewer false successes)."""
    y = np.asarray(real, dtype=bool)
    at_least = np.cumsum(pmf[:, ::-1], axis=1)[:, ::-1]  # P(score >= j / k), (n, k + 1)
    tpr = at_least[y].mean(axis=0) if y.any() else np.zeros(pmf.shape[1])
    tnr = 1.0 - at_least[~y].mean(axis=0) if (~y).any() else np.zeros(pmf.shape[1])
    bal = (tpr + tnr) / 2
    return int(np.flatnonzero(bal >= bal.max() - 1e-12)[-1])


# ------------------------------------------------------------------------ the profile


@dataclass(frozen=True)
class Fit:
    """A fitted profile: the execution's model, trial 0's gate, the trial count, the mapping of
    the score and the p_success ``threshold`` at which it calls a grasp a success."""

    execution: ExecutionFit
    scored: Scored
    exploration: Exploration  # what it was fitted on (its levels and the run's own ranges)
    threshold: float
    base_rate: float  # the real success rate of the trials it was fitted on

    @property
    def gate(self) -> str:
        return self.scored.gate

    @property
    def k(self) -> int:
        return self.scored.k

    def ranges(self) -> dict[str, float]:
        """The ``[robust]`` fields of the fitted levels (or the run's own, where kept)."""
        out: dict[str, float] = {}
        for g, t in zip(GROUPS, self.execution.execution.theta, strict=True):
            out.update(self.exploration.sizes(g, t))
        return out


def fit(
    exp: Exploration,
    real: np.ndarray,
    ks: Sequence[int] = TRIAL_COUNTS,
    gates: Sequence[str] = GATES,
) -> Fit:
    """The profile of these grasps: the execution (:func:`fit_execution`), then trial 0's gate
    with the highest expected log-likelihood at the largest K, then the smallest K within
    :data:`K_TOLERANCE` of the best expected Brier score, its mapping and threshold."""
    y = np.asarray(real, dtype=bool)
    ex = fit_execution(exp, y)
    e = ex.execution
    share = held_share(exp.ratios(), e.theta, _held(exp.stages, e.stage))  # what the K trials draw from
    top = max(ks)
    gate = max(gates, key=lambda g: score(exp.stage0, share, y, g, top).loglik)
    by_k = [score(exp.stage0, share, y, gate, int(k)) for k in sorted(ks)]
    least = min(s.brier for s in by_k)
    chosen = next(s for s in by_k if s.brier <= least + K_TOLERANCE)
    j = threshold_index(chosen.pmf, y)
    return Fit(ex, chosen, exp, float(chosen.mapping.p[j]), float(y.mean()) if len(y) else 0.0)


@dataclass(frozen=True)
class HeldOut:
    """Object-wise cross-validation of the whole fit: each fold's held-out objects and its
    :class:`Fit` made on the other objects; every grasp's expected P(success) ``p`` and its
    probability of being called a success ``called`` by its fold's fit."""

    folds: tuple[tuple[tuple[str, ...], Fit], ...]
    p: np.ndarray
    called: np.ndarray


def cross_validate(
    exp: Exploration,
    real: np.ndarray,
    objects: np.ndarray,
    folds: int,
    seed: int = 0,
    ks: Sequence[int] = TRIAL_COUNTS,
) -> HeldOut:
    """For each fold of objects (:func:`annotator.confidence.object_folds`), the fit on the other
    objects' grasps applied to the fold's: its ranges, stages, lapses, K, mapping and threshold."""
    from annotator.confidence import object_folds

    objects = np.asarray(objects).astype(str)
    groups = object_folds(objects, folds, seed)
    if len(groups) < 2:
        raise ValueError("cross-validation by object needs trials on at least two objects")
    y = np.asarray(real, dtype=bool)
    p = np.full(len(y), np.nan)
    called = np.full(len(y), np.nan)
    out = []
    for held_out in groups:
        held = np.isin(objects, held_out)
        f = fit(exp.take(np.flatnonzero(~held)), y[~held], ks)
        part = exp.take(np.flatnonzero(held))
        e = f.execution.execution
        share = held_share(part.ratios(), e.theta, _held(part.stages, e.stage))
        s = score(part.stage0, share, y[held], f.gate, f.k, f.scored.mapping)
        p[held] = s.p
        called[held] = s.pmf[:, f.scored.mapping.p >= f.threshold - 1e-12].sum(axis=1)
        out.append((tuple(map(str, held_out)), f))
    return HeldOut(tuple(out), p, called)
