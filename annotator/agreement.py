"""Agreement of simulated with real outcomes: accuracy, balanced accuracy, precision, recall and
F1 of "success", each with a percentile bootstrap interval over the trials.

What ``annotator calibrate`` ranks its settings by, what ``annotator evaluate --real`` prints for
every stage, and what ``bench.real_trials`` reports (docs/real_trials.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

BOOTSTRAP_SAMPLES = 2000
CONFIDENCE = 0.95  # of the percentile bootstrap intervals


@dataclass(frozen=True)
class Agreement:
    """Agreement of simulated with real outcomes; each statistic with its (low, high) interval.

    Positive is "success". ``nan`` where undefined (no simulated successes for precision, no real
    ones for recall, neither for F1). ``balanced``: the mean of recall and specificity.
    """

    n: int
    accuracy: float
    precision: float
    recall: float
    balanced: float
    accuracy_ci: tuple[float, float]
    precision_ci: tuple[float, float]
    recall_ci: tuple[float, float]
    balanced_ci: tuple[float, float] = (float("nan"), float("nan"))
    f1: float = float("nan")
    f1_ci: tuple[float, float] = (float("nan"), float("nan"))

    def value(self, name: str) -> float:
        """A statistic by name (``accuracy``, ``balanced``, ``precision``, ``recall``, ``f1``)."""
        return float(getattr(self, name))

    def interval(self, name: str) -> tuple[float, float]:
        return getattr(self, f"{name}_ci")


STATISTICS = ("accuracy", "precision", "recall", "balanced", "f1")  # the columns of _rates


def _rates(real: np.ndarray, sim: np.ndarray) -> np.ndarray:
    """(..., 5) accuracy, precision, recall, balanced accuracy, F1 over the last axis of bool arrays."""
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
        f1 = 2 * tp / (2 * tp + fp + fn)
    return np.stack(np.broadcast_arrays(acc, prec, rec, bal, f1), axis=-1)


def agreement(
    real: np.ndarray, sim: np.ndarray, samples: int = BOOTSTRAP_SAMPLES, seed: int = 0
) -> Agreement:
    """Statistics of ``sim`` against ``real`` (bool (n,)) with percentile bootstrap intervals.

    The resampling indices depend only on ``seed`` and ``n`` (the same for every setting, so
    settings are compared on the same resamples).
    """
    real, sim = np.asarray(real, bool), np.asarray(sim, bool)
    n = len(real)
    k = len(STATISTICS)
    point = _rates(real, sim)
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(seed), n, 0x43414C])))
    idx = rng.integers(0, n, size=(samples, n))
    boot = _rates(real[idx], sim[idx])
    alpha = (1 - CONFIDENCE) / 2
    lo, hi = np.full(k, np.nan), np.full(k, np.nan)
    defined = ~np.all(np.isnan(boot), axis=0) if n else np.zeros(k, bool)  # e.g. precision, no successes
    if defined.any():
        lo[defined] = np.nanquantile(boot[:, defined], alpha, axis=0)
        hi[defined] = np.nanquantile(boot[:, defined], 1 - alpha, axis=0)
    ci = [(float(lo[i]), float(hi[i])) for i in range(k)]
    acc, prec, rec, bal, f1 = (float(v) for v in point)
    return Agreement(n, acc, prec, rec, bal, ci[0], ci[1], ci[2], ci[3], f1, ci[4])


def agreement_text(
    a: Agreement, names: tuple[str, ...] = ("accuracy", "balanced", "precision", "recall")
) -> str:
    """``accuracy 80.0 % [70, 88], balanced 75.1 % [..]`` over the named statistics."""
    parts = []
    for name in names:
        v, (lo, hi) = a.value(name), a.interval(name)
        parts.append(
            f"{name} n/a"
            if not np.isfinite(v)
            else f"{name} {100 * v:.1f} % [{100 * lo:.0f}, {100 * hi:.0f}]"
        )
    return ", ".join(parts)
