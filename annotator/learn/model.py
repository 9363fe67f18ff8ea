"""Training: a logistic regression of the grasp features, in numpy and scipy.

A grasp's probability of being held is ``sigmoid(w . (x - mean) / scale + b)`` over the features
of :mod:`annotator.learn.features` and their pairwise products among the first
:data:`INTERACTIONS` (the counts and the grasp's geometry; a linear model alone cannot say "many
points between the pads *and* none in the pads"). Fitted by L-BFGS (scipy) on the cross-entropy
with an L2 penalty ``l2`` on ``w``, the two classes weighted to count equally (held grasps are a
few in ten of the labels). The model is an ``.npz`` file of plain arrays.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

INTERACTIONS = 18  # the scalar features (annotator.learn.features._SCALARS) enter in pairs too
L2 = 1.0  # the penalty on the standardised weights (chosen, not tuned)


def expand(X: np.ndarray) -> np.ndarray:
    """(n, F) features -> (n, F + k (k + 1) / 2) with the pairwise products of the first k =
    INTERACTIONS columns (squares included)."""
    head = X[:, :INTERACTIONS]
    i, j = np.triu_indices(head.shape[1])
    return np.concatenate([X, head[:, i] * head[:, j]], axis=1)


@dataclass(frozen=True)
class Model:
    """A fitted model: ``mean`` and ``scale`` (F',) of the expanded features, weights ``coef``
    (F',), ``intercept``, and the ``feature_names`` (F,) it was trained on."""

    mean: np.ndarray
    scale: np.ndarray
    coef: np.ndarray
    intercept: float
    feature_names: tuple[str, ...]

    def probability(self, X: np.ndarray) -> np.ndarray:
        """(n,) probability of a hold for features ``X`` (n, F)."""
        z = (expand(np.asarray(X, dtype=np.float64)) - self.mean) / self.scale @ self.coef + self.intercept
        return 1.0 / (1.0 + np.exp(-np.clip(z, -50, 50)))

    def save(self, path: str | Path) -> None:
        """The model at exactly ``path`` (an ``.npz`` of plain arrays; no suffix is added)."""
        with open(path, "wb") as fh:
            self._save(fh)

    def _save(self, fh) -> None:
        np.savez(
            fh,
            mean=self.mean,
            scale=self.scale,
            coef=self.coef,
            intercept=np.array(self.intercept),
            feature_names=np.array(self.feature_names),
        )


def train(X: np.ndarray, y: np.ndarray, *, l2: float = L2) -> Model:
    """Fit the model (module docstring) to features ``X`` (n, F) and outcomes ``y`` (n,) bool."""
    from scipy.optimize import minimize

    from annotator.learn.features import FEATURE_NAMES

    Z = expand(np.asarray(X, dtype=np.float64))
    y = np.asarray(y, dtype=np.float64)
    if not 0 < y.sum() < len(y):
        raise ValueError(f"training needs both outcomes: {int(y.sum())} held of {len(y)}")
    mean, scale = Z.mean(axis=0), Z.std(axis=0)
    scale[scale < 1e-12] = 1.0
    Z = (Z - mean) / scale
    weight = np.where(y > 0, 0.5 / y.mean(), 0.5 / (1 - y.mean()))

    def loss(theta: np.ndarray) -> tuple[float, np.ndarray]:
        w, b = theta[:-1], theta[-1]
        z = Z @ w + b
        p = 1.0 / (1.0 + np.exp(-np.clip(z, -50, 50)))
        ll = weight * (np.logaddexp(0.0, z) - y * z)
        g = weight * (p - y)
        n = len(y)
        value = ll.sum() / n + 0.5 * l2 * (w @ w) / n
        grad = np.append(Z.T @ g / n + l2 * w / n, g.sum() / n)
        return float(value), grad

    theta0 = np.zeros(Z.shape[1] + 1)
    result = minimize(loss, theta0, jac=True, method="L-BFGS-B", options={"maxiter": 2000})
    names = FEATURE_NAMES if len(FEATURE_NAMES) == X.shape[1] else tuple(f"f{i}" for i in range(X.shape[1]))
    return Model(mean, scale, result.x[:-1], float(result.x[-1]), tuple(names))


@lru_cache(maxsize=4)
def load_model(path: str | Path) -> Model:
    """The model saved at ``path`` (read once per process). ValueError (one line) for a file that
    is not a whole model of :meth:`Model.save` (truncated, another file, arrays of other shapes)."""
    try:
        with np.load(Path(path), allow_pickle=False) as data:
            model = Model(
                np.asarray(data["mean"], dtype=np.float64),
                np.asarray(data["scale"], dtype=np.float64),
                np.asarray(data["coef"], dtype=np.float64),
                float(data["intercept"]),
                tuple(str(n) for n in data["feature_names"]),
            )
    except FileNotFoundError:
        raise ValueError(f"{path}: no such model") from None
    except Exception as exc:  # zipfile, numpy and OS errors of a damaged file: many types
        raise ValueError(
            f"{path} is not a model of annotator learn train (damaged or truncated? {type(exc).__name__}: "
            f"{' '.join(str(exc).split())[:200]})"
        ) from None
    sizes = {len(model.mean), len(model.scale), len(model.coef)}
    if len(sizes) != 1 or not np.isfinite(np.concatenate([model.mean, model.scale, model.coef])).all():
        raise ValueError(f"{path} is not a model of annotator learn train (its arrays do not fit together)")
    return model


def auc(score: np.ndarray, y: np.ndarray) -> float:
    """The area under the ROC curve (the probability a held grasp scores above a failed one)."""
    from scipy.stats import rankdata

    y = np.asarray(y, dtype=bool)
    pos, neg = int(y.sum()), int((~y).sum())
    if not pos or not neg:
        return float("nan")
    ranks = rankdata(score)
    return float((ranks[y].sum() - pos * (pos + 1) / 2) / (pos * neg))
