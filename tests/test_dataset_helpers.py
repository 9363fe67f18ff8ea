"""Dataset helpers of the reader module: balance, score filter, grasp distance, near-duplicates."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

import annotator.dataset as ds


def _table(T: np.ndarray, object_id: str = "obj", success=None, score=None) -> pd.DataFrame:
    n = len(T)
    df = ds.pose_columns(T)
    df.insert(0, "object_id", object_id)
    df.insert(1, "grasp_id", np.arange(n, dtype=np.int64))
    success = np.zeros(n, bool) if success is None else np.asarray(success, bool)
    df["width"] = 0.04
    df["success"] = success
    df["outcome"] = np.where(success, "success", "slipped_shake")
    df["score"] = success.astype(float) if score is None else np.asarray(score, float)
    df["object_scale"] = 1.0
    df["mesh_sha256"] = "ab" * 32
    df["seed"] = np.int64(0)
    return ds.validate_labels(df)


def _poses(rotations: Rotation, positions: np.ndarray) -> np.ndarray:
    T = np.tile(np.eye(4), (len(positions), 1, 1))
    T[:, :3, :3] = rotations.as_matrix()
    T[:, :3, 3] = positions
    return T


def _random_table(n: int, object_id: str, p_success: float, seed: int) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    T = _poses(Rotation.random(n, random_state=seed), rng.uniform(-0.05, 0.05, (n, 3)))
    return _table(T, object_id, success=rng.random(n) < p_success)


def test_balance_outcomes_per_object_and_order_independent() -> None:
    df = pd.concat(
        [_random_table(40, "a", 0.2, 1), _random_table(30, "b", 0.8, 2), _random_table(10, "c", 0.0, 3)]
    )
    out = ds.balance_outcomes(df, seed=5)
    counts = out.groupby(["object_id", "success"]).size()
    for oid in ("a", "b"):
        n_min = min(df[(df.object_id == oid)].success.sum(), (~df[(df.object_id == oid)].success).sum())
        assert counts[(oid, True)] == counts[(oid, False)] == n_min > 0
    assert "c" not in set(out.object_id)  # no successes: nothing to balance against
    # rows are kept whole, and the choice depends on the seed, not on the row order
    shuffled = ds.balance_outcomes(df.sample(frac=1.0, random_state=7), seed=5)
    pd.testing.assert_frame_equal(out, shuffled)
    assert set(out.itertuples(index=False)) <= set(df.itertuples(index=False))
    other = ds.balance_outcomes(df, seed=6)
    assert not out[["object_id", "grasp_id"]].equals(other[["object_id", "grasp_id"]])
    # over the whole table instead: one class count
    whole = ds.balance_outcomes(df, seed=5, per_object=False)
    assert whole.success.sum() == (~whole.success).sum() == min(df.success.sum(), (~df.success).sum())


def test_filter_by_score() -> None:
    df = _random_table(20, "a", 0.5, 0)
    df["score"] = np.linspace(0.0, 1.0, 20)
    out = ds.filter_by_score(df, 0.5)
    assert (out.score >= 0.5).all() and len(out) == int((df.score >= 0.5).sum()) == 10
    assert len(ds.filter_by_score(df, 0.0)) == 20
    with pytest.raises(ValueError, match="min_score"):
        ds.filter_by_score(df, 1.5)


def test_grasp_distance_against_scipy_and_symmetry() -> None:
    rng = np.random.default_rng(0)
    Ra, Rb = Rotation.random(7, random_state=1), Rotation.random(5, random_state=2)
    A, B = _poses(Ra, rng.normal(0, 0.05, (7, 3))), _poses(Rb, rng.normal(0, 0.05, (5, 3)))
    d = ds.grasp_distance(A, B, symmetric=False)
    assert d.shape == (7, 5)
    for i in range(7):
        for j in range(5):
            angle = (Ra[i].inv() * Rb[j]).magnitude()
            want = np.linalg.norm(A[i, :3, 3] - B[j, :3, 3]) + ds.ROTATION_LENGTH * angle
            assert d[i, j] == pytest.approx(want, abs=1e-9)
    # the RG2 turned 180 degrees about its approach axis (TCP z) is the same grasp ...
    flipped = A.copy()
    flipped[:, :3, :3] = A[:, :3, :3] @ ds.RG2_SYMMETRY
    assert np.allclose(np.diag(ds.grasp_distance(A, flipped)), 0.0, atol=1e-6)
    assert np.all(np.diag(ds.grasp_distance(A, flipped, symmetric=False)) > 0.17)  # pi x 55 mm
    # ... but turned 180 degrees about the closing axis (x) it approaches from the other side
    other = A.copy()
    other[:, :3, :3] = A[:, :3, :3] @ np.diag([1.0, -1.0, -1.0])
    assert np.allclose(np.diag(ds.grasp_distance(A, other)), ds.ROTATION_LENGTH * np.pi)
    # and 90 degrees about z is as far as it gets with the symmetry
    quarter = A.copy()
    quarter[:, :3, :3] = A[:, :3, :3] @ Rotation.from_euler("z", 90, degrees=True).as_matrix()
    assert np.allclose(np.diag(ds.grasp_distance(A, quarter)), ds.ROTATION_LENGTH * np.pi / 2)
    assert np.ndim(ds.grasp_distance(A[0], B[0])) == 0 and ds.grasp_distance(A[0], B).shape == (5,)


def test_drop_near_duplicates_keeps_one_per_cluster_best_first() -> None:
    rng = np.random.default_rng(3)
    centres = _poses(Rotation.random(6, random_state=4), rng.uniform(-0.1, 0.1, (6, 3)))
    # 6 well separated grasps, each with 4 near copies: 2 mm / 2 degrees off, half of them turned
    # 180 degrees about the approach axis (the same RG2 grasp)
    T, cluster = [], []
    for c in range(6):
        for k in range(5):
            jitter = Rotation.from_rotvec(rng.normal(0, np.radians(1.0), 3)).as_matrix()
            turn = ds.RG2_SYMMETRY if k % 2 else np.eye(3)
            pose = centres[c].copy()
            pose[:3, :3] = centres[c][:3, :3] @ jitter @ turn
            pose[:3, 3] += rng.normal(0, 0.001, 3) if k else 0.0
            T.append(pose)
            cluster.append(c)
    T, cluster = np.array(T), np.array(cluster)
    assert ds.grasp_distance(centres, centres)[~np.eye(6, dtype=bool)].min() > 0.05  # separated
    score = rng.uniform(0.1, 0.9, len(T))
    best = [int(np.flatnonzero(cluster == c)[np.argmax(score[cluster == c])]) for c in range(6)]
    df = _table(T, "a", success=np.ones(len(T), bool), score=score)
    out = ds.drop_near_duplicates(df, min_distance=0.015)
    assert sorted(out.grasp_id) == sorted(best)  # one per cluster, the best scored one
    # without the symmetry the turned copies would look like different grasps
    unsym = ds.grasp_distance(T, T, symmetric=False)
    assert (unsym[cluster[:, None] == cluster[None, :]] > 0.1).any()
    # a failure at a success's pose is kept unless asked otherwise; other objects never interact
    mixed = df.copy()
    mixed.loc[mixed.grasp_id == best[0], ["success", "outcome"]] = [False, "slipped_lift"]
    both = pd.concat([mixed, _table(T, "b", success=np.ones(len(T), bool), score=score)])
    assert len(ds.drop_near_duplicates(both, 0.015)) == 6 + 7 + 0  # b: 6, a: 6 + the failure
    assert len(ds.drop_near_duplicates(both, 0.015, same_success_only=False)) == 12
    assert len(ds.drop_near_duplicates(df, min_distance=0.0)) == len(df)
