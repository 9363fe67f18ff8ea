"""The one builder of a label row: every producer (the object worker, the scene worker, the capture
key) hands it what a candidate's trials gave and gets the row of its mode, in the mode's column
order (:data:`annotator.schema.MODES`).

The values keep the types they always had (Python floats, ints and bools, NumPy floats where the
model holds them), so that ``pandas.DataFrame(rows)`` gives the same table bit for bit.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from annotator.geometry import Transform
from annotator.outcome import Outcome, Stage
from annotator.schema import MODES, REASON_COLUMNS


@dataclass(frozen=True)
class TrialsResult:
    """What one candidate's K trials gave: trial 0's ``outcome``, the TCP pose ``T_label`` (object
    mesh frame) and pad ``width`` (m) at the end of its closing and its ``slip`` (m); the physics
    ``steps`` of all K trials; how many trials ``held``; trial 0's kinematic ``check`` (a
    :class:`annotator.trial.CollisionCheck`; None after an error or where no trial ran)."""

    outcome: Outcome
    T_label: Transform
    width: float
    steps: int
    slip: float
    held: int
    check: Any = None
    success: bool | None = None  # trial 0 held through the gate; None: outcome is success
    stages: str = ""  # how far each trial held, one Stage digit per trial (KTrials.stages)


class LabelledObject(Protocol):
    """What a row says about the object it grasps (an :class:`annotator.objects.ObjectModel`)."""

    @property
    def scale(self) -> float: ...

    @property
    def mesh_sha256(self) -> str: ...

    @property
    def mass(self) -> float: ...

    @property
    def collision_error(self) -> Any:
        """Its collision error record (``mean``, ``max``: m)."""
        ...


def canonical(q: np.ndarray) -> np.ndarray:
    """The quaternion ``q`` (xyzw) with ``w >= 0`` (the same rotation)."""
    return -q if q[3] < 0 else q


def label_row(
    mode: str,
    *,
    object_id: str,
    grasp_id: int,
    result: TrialsResult,
    trials: int,
    T_cmd: Transform,
    cmd_width: float,
    model: LabelledObject,
    seed: int,
    gripper: str,
    extra: Mapping[str, Any] | None = None,
    reasons: Mapping[str, str] | None = None,
    p_success: float | None = None,
) -> dict[str, Any]:
    """One label row of ``mode``: the object columns from the trials' ``result`` (of ``trials``
    trials), the commanded grasp ``T_cmd`` (object mesh frame) at ``cmd_width`` (m), the object
    ``model`` and the run's ``seed``, plus the mode's own columns ``extra``; ordered as the mode's
    columns. After them, with a calibration, ``p_success`` (the probability that the real grasp
    holds: :data:`annotator.schema.CONFIDENCE_COLUMNS`), then a given grasp's ``reasons``
    (:data:`annotator.schema.REASON_COLUMNS`: why a collision is one). Raises ValueError when the
    columns are not exactly the mode's."""
    row: dict[str, Any] = {
        "object_id": object_id,
        "grasp_id": grasp_id,
        **dict(zip(("x", "y", "z"), result.T_label.pos.tolist(), strict=True)),
        **dict(zip(("qx", "qy", "qz", "qw"), canonical(result.T_label.quat).tolist(), strict=True)),
        "width": result.width,
        "success": result.outcome == Outcome.SUCCESS if result.success is None else bool(result.success),
        "outcome": result.outcome.label,
        "score": result.held / trials,
        "stage": Stage(int(result.stages[0])).label if result.stages else Stage.NONE.label,
        "trial_stages": result.stages,
        "object_scale": model.scale,
        "mesh_sha256": model.mesh_sha256,
        "seed": seed,
        "sim_steps": result.steps,
        "slip": result.slip,
        "object_mass": model.mass,
        # the commanded grasp: the TCP pose the gripper was placed at before closing (quaternion as
        # simulated, not sign-canonicalised) and the expected chord the close started from;
        # ``evaluate`` replays a label exactly from these
        **dict(zip(("cmd_x", "cmd_y", "cmd_z"), T_cmd.pos.tolist(), strict=True)),
        **dict(zip(("cmd_qx", "cmd_qy", "cmd_qz", "cmd_qw"), T_cmd.quat.tolist(), strict=True)),
        "cmd_width": cmd_width,
        "collision_error": model.collision_error.max,
        "collision_error_mean": model.collision_error.mean,
        "gripper": gripper,
    }
    if extra:
        row.update(extra)
    names = MODES[mode]
    if len(row) != len(names) or not all(n in row for n in names):
        missing = [n for n in names if n not in row]
        unknown = [n for n in row if n not in names]
        raise ValueError(f"a {mode} row: missing columns {missing}, columns not of the mode {unknown}")
    out = {n: row[n] for n in names}
    if p_success is not None:
        out["p_success"] = float(p_success)
    if reasons is not None:
        if tuple(reasons) != REASON_COLUMNS:
            raise ValueError(f"a {mode} row's reasons: {tuple(reasons)}, expected {REASON_COLUMNS}")
        out.update(reasons)
    return out
