"""The label's confidence: a mapping from ``score`` to the probability that the real grasp holds.

``annotator calibrate --trials K`` fits it on real trials (:func:`fit_isotonic`), cross-validated
by object (:func:`cross_validated`), and writes it into the configuration's ``[confidence]``
section; labels made with that configuration carry ``p_success`` (:meth:`Mapping.p_success`).

The mapping is isotonic (docs/decisions/0019-score-calibration.md): ``score`` takes only K + 1
values (the fraction of K trials that held), so the fit is the real success rate at each value,
pooled with its neighbours where the rates would otherwise fall as the score rises; between the
fitted values it is linear. Also here: the measures of a probability against real outcomes (AUC,
Brier score, reliability bins) with bootstrap intervals, and the reliability diagram drawn with
PIL (:func:`reliability_png`).
"""

from __future__ import annotations

import io
import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)

BOOTSTRAP_SAMPLES = 2000
CONFIDENCE = 0.95  # of the percentile bootstrap intervals
RELIABILITY_BINS = 5  # equal-width bins of the predicted probability in the diagram


@dataclass(frozen=True)
class Mapping:
    """A monotone mapping from ``score`` to P(real success).

    ``scores`` (m,) increasing knots in [0, 1]; ``p`` (m,) the probability at each knot, not
    decreasing; linear in between, constant beyond the ends. ``trials``: the K of the labels it
    was fitted on (``score`` of ``--trials K``); ``n``: the real trials it was fitted on.
    """

    scores: tuple[float, ...]
    p: tuple[float, ...]
    trials: int
    n: int = 0

    def p_success(self, score: np.ndarray | float) -> np.ndarray:
        """P(real success) for ``score`` (any shape), float64."""
        return np.interp(np.asarray(score, dtype=np.float64), self.scores, self.p)


def mapping_of(section) -> Mapping | None:
    """The :class:`Mapping` a ``[confidence]`` section (:class:`annotator.config.ConfidenceConfig`)
    holds, or None (``method = "none"``: labels carry no ``p_success``)."""
    if section.method == "none":
        return None
    return Mapping(section.scores, section.p_success, section.trials, section.n)


def fit_isotonic(score: np.ndarray, real: np.ndarray, trials: int) -> Mapping:
    """The isotonic regression of ``real`` (bool (n,)) on ``score`` (float (n,)) by pool adjacent
    violators: the mean real outcome at each distinct score, blocks pooled (weighted by their
    trials) until the means rise with the score. Knots at each block's mean score."""
    score = np.asarray(score, dtype=np.float64)
    real = np.asarray(real, dtype=np.float64)
    if len(score) == 0:
        raise ValueError("no trials to fit a confidence mapping on")
    values, inverse = np.unique(score, return_inverse=True)
    weight = np.bincount(inverse).astype(np.float64)
    mean = np.bincount(inverse, weights=real) / weight
    xs = list(values * weight)
    blocks: list[list[float]] = []  # [sum of real, weight, sum of scores]
    for m, w, x in zip(mean, weight, xs, strict=True):
        blocks.append([m * w, w, x])
        while len(blocks) > 1 and blocks[-2][0] / blocks[-2][1] >= blocks[-1][0] / blocks[-1][1]:
            s, w2, x2 = blocks.pop()
            blocks[-1][0] += s
            blocks[-1][1] += w2
            blocks[-1][2] += x2
    knots = tuple(float(b[2] / b[1]) for b in blocks)
    p = tuple(float(b[0] / b[1]) for b in blocks)
    return Mapping(knots, p, int(trials), int(len(score)))


def object_folds(objects: np.ndarray, folds: int, seed: int = 0) -> list[np.ndarray]:
    """The distinct objects split into ``folds`` groups (at most one per object), shuffled by seed."""
    from annotator.rng import keyed_rng

    ids = np.array(sorted(set(map(str, objects))))
    k = max(1, min(int(folds), len(ids)))
    order = keyed_rng("confidence-folds", int(seed), len(ids)).permutation(len(ids))
    return [np.sort(ids[order[f::k]]) for f in range(k)]


def cross_validated(
    score: np.ndarray, real: np.ndarray, objects: np.ndarray, trials: int, folds: int = 5, seed: int = 0
) -> np.ndarray:
    """Held-out P(success) of every trial: for each fold of objects, the mapping fitted on the other
    objects' trials applied to the fold's. Needs trials on at least two objects."""
    objects = np.asarray(objects).astype(str)
    groups = object_folds(objects, folds, seed)
    if len(groups) < 2:
        raise ValueError("cross-validation by object needs trials on at least two objects")
    out = np.full(len(score), np.nan)
    score, real = np.asarray(score, dtype=np.float64), np.asarray(real, dtype=bool)
    for held_out in groups:
        held = np.isin(objects, held_out)
        out[held] = fit_isotonic(score[~held], real[~held], trials).p_success(score[held])
    return out


# ------------------------------------------------------------------------------------ measures


def auc(real: np.ndarray, predicted: np.ndarray) -> float:
    """Area under the ROC curve of ``predicted`` (float (n,)) for ``real`` (bool (n,)), ties half:
    the probability that a real success is ranked above a real failure. NaN without both."""
    real = np.asarray(real, dtype=bool)
    predicted = np.asarray(predicted, dtype=np.float64)
    pos, neg = predicted[real], predicted[~real]
    if len(pos) == 0 or len(neg) == 0:
        return float("nan")
    ranks = _ranks(np.concatenate([pos, neg]))
    return float((ranks[: len(pos)].sum() - len(pos) * (len(pos) + 1) / 2) / (len(pos) * len(neg)))


def _ranks(x: np.ndarray) -> np.ndarray:
    """1-based ranks, ties given their mean rank."""
    order = np.argsort(x, kind="mergesort")
    ranks = np.empty(len(x))
    sorted_x = x[order]
    i = 0
    while i < len(x):
        j = i
        while j + 1 < len(x) and sorted_x[j + 1] == sorted_x[i]:
            j += 1
        ranks[order[i : j + 1]] = (i + j) / 2 + 1
        i = j + 1
    return ranks


def brier(real: np.ndarray, p: np.ndarray) -> float:
    """Mean squared difference between P(success) and the real outcome (0 best; 0.25: a coin)."""
    real = np.asarray(real, dtype=np.float64)
    return float(np.mean((np.asarray(p, dtype=np.float64) - real) ** 2)) if len(real) else float("nan")


def rank_shares(predicted: np.ndarray, groups: int) -> np.ndarray:
    """(n, groups): how much of each trial falls in each of ``groups`` equal shares of the trials
    ranked by ``predicted``, highest first. Ties share their places: a group of tied trials that
    straddles a boundary counts in each share by the part of its places that falls there, the
    average over every order of the ties (so no rule of row order decides a share)."""
    x = np.asarray(predicted, dtype=np.float64)
    n = len(x)
    out = np.zeros((n, groups))
    if n == 0:
        return out
    values, inverse = np.unique(-x, return_inverse=True)  # highest prediction first
    counts = np.bincount(inverse, minlength=len(values)).astype(np.float64)
    starts = np.concatenate([[0.0], np.cumsum(counts)[:-1]])
    edges = np.linspace(0.0, n, groups + 1)
    for v in range(len(values)):
        lo, hi = starts[v], starts[v] + counts[v]  # the tied group's places [lo, hi)
        overlap = np.clip(np.minimum(hi, edges[1:]) - np.maximum(lo, edges[:-1]), 0.0, None)
        out[inverse == v] = overlap / counts[v]
    return out


def top_fraction_precision(real: np.ndarray, predicted: np.ndarray, fraction: float = 0.2) -> float:
    """The real success rate of the ``fraction`` of trials ranked highest by ``predicted``; tied
    trials at the boundary count by the share of their places inside it (:func:`rank_shares`)."""
    real = np.asarray(real, dtype=np.float64)
    n = len(real)
    if n == 0:
        return float("nan")
    k = max(1, int(round(fraction * n)))
    x = np.asarray(predicted, dtype=np.float64)
    values, inverse = np.unique(-x, return_inverse=True)
    counts = np.bincount(inverse, minlength=len(values)).astype(np.float64)
    starts = np.concatenate([[0.0], np.cumsum(counts)[:-1]])
    inside = np.clip(np.minimum(starts + counts, k) - starts, 0.0, None) / counts  # per tied group
    weight = inside[inverse]
    return float((weight * real).sum() / weight.sum())


def fifths(real: np.ndarray, p: np.ndarray, groups: int = 5) -> list[ReliabilityBin]:
    """The trials in ``groups`` equal shares ranked by ``p`` (highest first; ties shared,
    :func:`rank_shares`): each share's mean ``p`` and real rate, its trials counted fractionally."""
    real = np.asarray(real, dtype=np.float64)
    p = np.asarray(p, dtype=np.float64)
    shares = rank_shares(p, groups)
    out = []
    for g in range(groups):
        w = shares[:, g]
        total = float(w.sum())
        mean_p = float((w * p).sum() / total) if total else float("nan")
        rate = float((w * real).sum() / total) if total else float("nan")
        lo, hi = (float(np.min(p[w > 0])), float(np.max(p[w > 0]))) if total else (float("nan"),) * 2
        out.append(ReliabilityBin(lo, hi, int(round(total)), mean_p, rate))
    return out


@dataclass(frozen=True)
class Measure:
    """One measure with its percentile bootstrap interval."""

    value: float
    low: float
    high: float

    def text(self, percent: bool = False, digits: int = 3) -> str:
        if not np.isfinite(self.value):
            return "n/a"
        if percent:
            return f"{100 * self.value:.1f} % [{100 * self.low:.0f}, {100 * self.high:.0f}]"
        return f"{self.value:.{digits}f} [{self.low:.{digits}f}, {self.high:.{digits}f}]"


def bootstrap(
    fn, real: np.ndarray, predicted: np.ndarray, samples: int = BOOTSTRAP_SAMPLES, seed: int = 0
) -> Measure:
    """``fn(real, predicted)`` with a percentile bootstrap interval over the trials."""
    real = np.asarray(real)
    predicted = np.asarray(predicted)
    n = len(real)
    value = float(fn(real, predicted))
    if n == 0:
        return Measure(value, float("nan"), float("nan"))
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(seed), n, 0x434F4E])))
    boot = np.array([fn(real[i], predicted[i]) for i in rng.integers(0, n, size=(samples, n))], dtype=float)
    boot = boot[np.isfinite(boot)]
    if len(boot) == 0:
        return Measure(value, float("nan"), float("nan"))
    alpha = (1 - CONFIDENCE) / 2
    return Measure(value, float(np.quantile(boot, alpha)), float(np.quantile(boot, 1 - alpha)))


@dataclass(frozen=True)
class ReliabilityBin:
    """Trials whose P(success) fell in [low, high): how many, their mean P, their real rate."""

    low: float
    high: float
    n: int
    mean_p: float
    real_rate: float


def reliability(real: np.ndarray, p: np.ndarray, bins: int = RELIABILITY_BINS) -> list[ReliabilityBin]:
    """The reliability table: equal-width bins of ``p`` (the last one closed at 1)."""
    real = np.asarray(real, dtype=np.float64)
    p = np.asarray(p, dtype=np.float64)
    edges = np.linspace(0.0, 1.0, bins + 1)
    which = np.clip(np.searchsorted(edges, p, side="right") - 1, 0, bins - 1)
    out = []
    for b in range(bins):
        mask = which == b
        n = int(mask.sum())
        out.append(
            ReliabilityBin(
                float(edges[b]),
                float(edges[b + 1]),
                n,
                float(p[mask].mean()) if n else float("nan"),
                float(real[mask].mean()) if n else float("nan"),
            )
        )
    return out


def reliability_png(
    curves: Sequence[tuple[str, Sequence[ReliabilityBin]]], title: str = "", size: int = 480
) -> bytes:
    """The reliability diagram as PNG bytes: for each named curve, the real success rate (y)
    against the mean predicted probability (x) of each non-empty bin, a dot's area growing with
    its trials; the diagonal is perfect calibration. Drawn with PIL."""
    from PIL import Image, ImageDraw

    margin = 48
    img = Image.new("RGB", (size, size), "white")
    draw = ImageDraw.Draw(img)
    inner = size - 2 * margin

    def xy(px: float, py: float) -> tuple[float, float]:
        return margin + px * inner, size - margin - py * inner

    draw.rectangle([xy(0, 1), xy(1, 0)], outline="black")
    for t in np.linspace(0, 1, 6):
        draw.line([xy(t, 0), (xy(t, 0)[0], xy(t, 0)[1] + 4)], fill="black")
        draw.line([xy(0, t), (xy(0, t)[0] - 4, xy(0, t)[1])], fill="black")
        draw.text((xy(t, 0)[0] - 8, xy(t, 0)[1] + 6), f"{t:.1f}", fill="black")
        draw.text((xy(0, t)[0] - 30, xy(0, t)[1] - 6), f"{t:.1f}", fill="black")
    draw.line([xy(0, 0), xy(1, 1)], fill=(160, 160, 160), width=1)
    draw.text((margin + inner / 2 - 60, size - 18), "predicted P(success)", fill="black")
    draw.text((4, 4), "real success rate", fill="black")
    if title:
        draw.text((margin, 20), title, fill="black")
    colours = [(31, 119, 180), (214, 39, 40), (44, 160, 44), (148, 103, 189)]
    for k, (name, bins) in enumerate(curves):
        colour = colours[k % len(colours)]
        points = [(b.mean_p, b.real_rate, b.n) for b in bins if b.n > 0]
        if len(points) > 1:
            draw.line([xy(px, py) for px, py, _ in points], fill=colour, width=2)
        total = max(1, sum(n for *_, n in points))
        for px, py, n in points:
            r = 3 + 12 * np.sqrt(n / total)
            cx, cy = xy(px, py)
            draw.ellipse([cx - r, cy - r, cx + r, cy + r], outline=colour, width=2)
        draw.text((margin + 8, margin + 8 + 14 * k), name, fill=colour)
    buf = io.BytesIO()
    img.save(buf, format="PNG")
    return buf.getvalue()


# ------------------------------------------------------------------------------------ thresholds


def best_threshold(score: np.ndarray, real: np.ndarray) -> float:
    """The score threshold (success: ``score >= t``) with the highest balanced accuracy on these
    trials; ties: the higher threshold (fewer false successes). 1.0 when there is nothing to
    tell apart."""
    score = np.asarray(score, dtype=np.float64)
    real = np.asarray(real, dtype=bool)
    best, best_t = -1.0, 1.0
    for t in np.unique(score):
        pred = score >= t
        rec = (pred & real).sum() / max(1, real.sum())
        spec = (~pred & ~real).sum() / max(1, (~real).sum())
        bal = (rec + spec) / 2 if real.any() and (~real).any() else float(real.any() == pred.all())
        if bal >= best:
            best, best_t = float(bal), float(t)
    return best_t


def cross_validated_decisions(
    score: np.ndarray, real: np.ndarray, objects: np.ndarray, folds: int = 5, seed: int = 0
) -> tuple[np.ndarray, list[float]]:
    """Held-out success calls: for each fold of objects, ``score >= t`` with ``t`` the
    :func:`best_threshold` of the other objects' trials. Returns the calls and each fold's ``t``."""
    objects = np.asarray(objects).astype(str)
    score, real = np.asarray(score, dtype=np.float64), np.asarray(real, dtype=bool)
    out = np.zeros(len(score), dtype=bool)
    thresholds = []
    for held_out in object_folds(objects, folds, seed):
        held = np.isin(objects, held_out)
        t = best_threshold(score[~held], real[~held])
        thresholds.append(t)
        out[held] = score[held] >= t
    return out, thresholds


def trials_mismatch(config, trials: int) -> str | None:
    """Why a run with ``--trials trials`` cannot use ``config``'s ``[confidence]`` (fitted at
    another K, or on perturbed trials shaken when this run's end at the lift, or the reverse), or
    None."""
    if config.confidence.method == "none":
        return None
    fitted = config.confidence.trials
    if fitted != trials:
        return f"its [confidence] maps the score of --trials {fitted}: run with --trials {fitted}"
    shaken = config.confidence.perturbed_shake
    if shaken != config.robust.shake:
        how = "shook" if shaken else "ended at the lift"
        return (
            f"its [confidence] maps scores whose perturbed trials {how}: "
            f"set [robust] shake = {'true' if shaken else 'false'}, or calibrate again"
        )
    return None
