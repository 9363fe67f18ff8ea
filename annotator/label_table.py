"""A label table checked against the label contract: the required columns with their dtypes
(:data:`annotator.schema.REQUIRED`), their values (outcomes, unit quaternions, finite numbers,
unique grasp ids) and a whole table against one mode's columns.

Below the store (which checks every table before it writes it) and the dataset reader (which
re-exports these names), with pandas and NumPy only.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from annotator.outcome import OUTCOMES, Outcome
from annotator.schema import REQUIRED, STRING, columns_of

# Required columns in order, with their pandas dtype names: those of the label schema every table
# has (annotator.schema, which declares every column of every mode; docs/labels.md).
COLUMNS: dict[str, str] = dict(REQUIRED)
POSE_COLUMNS: tuple[str, ...] = ("x", "y", "z", "qx", "qy", "qz", "qw")
# pandas' default dtype for text: ``str`` in pandas >= 3, ``object`` before; what read_parquet gives.
_TEXT_DTYPE = pd.Series(["text"]).dtype

# A quaternion further than this from unit norm is a bug upstream, not float noise.
_QUAT_NORM_TOL = 1e-6


class SchemaError(ValueError):
    """A label table does not match the label contract (docs/labels.md)."""


# --------------------------------------------------------------------------------------- schema


def _check_dtype(name: str, series: pd.Series, want: str) -> str | None:
    """Why ``series`` cannot be stored as ``want``, or None if it can."""
    dtype = series.dtype
    if want == STRING:
        if not pd.api.types.is_string_dtype(dtype) or (
            pd.api.types.is_object_dtype(dtype) and not series.map(lambda v: isinstance(v, str)).all()
        ):
            return f"{name}: {dtype} (want string)"
        if series.isna().any():
            return f"{name}: contains missing values (want string)"
    elif want == "int64":
        if not pd.api.types.is_integer_dtype(dtype) or pd.api.types.is_bool_dtype(dtype):
            return f"{name}: {dtype} (want int64)"
        if series.isna().any():
            return f"{name}: contains missing values (want int64)"
    elif want == "float64":
        if not pd.api.types.is_float_dtype(dtype):
            return f"{name}: {dtype} (want float64)"
    elif want == "bool":
        if not pd.api.types.is_bool_dtype(dtype) or series.isna().any():
            return f"{name}: {dtype} (want bool without missing values)"
    return None


def mode_errors(df: pd.DataFrame, mode: str) -> list[str]:
    """What keeps ``df`` from being a table of ``mode``'s rows (:data:`annotator.schema.MODES`):
    its columns not exactly the mode's in their order, and every column off its declared dtype
    (missing values allowed in float columns only). Empty when it is one."""
    columns = columns_of(mode)
    names = [c.name for c in columns]
    if list(df.columns) != names:
        missing = [n for n in names if n not in df.columns]
        unknown = [c for c in df.columns if c not in names]
        return [f"columns of a {mode} table: missing {missing}, not of the mode {unknown}, or out of order"]
    return [msg for c in columns if (msg := _check_dtype(c.name, df[c.name], c.dtype)) is not None]


def validate_labels(df: pd.DataFrame) -> pd.DataFrame:
    """Check the required columns, dtypes and values; return a copy with exact dtypes.

    Integer columns of other widths become int64, float32 becomes float64, strings become
    pandas' string dtype. Raises :class:`SchemaError` naming every missing column and every
    wrong dtype at once, or the first value that breaks the contract.
    """
    missing = [c for c in COLUMNS if c not in df.columns]
    if missing:
        raise SchemaError(f"label table is missing required column(s) {missing}; have {list(df.columns)}")
    wrong = [msg for c, want in COLUMNS.items() if (msg := _check_dtype(c, df[c], want)) is not None]
    if wrong:
        raise SchemaError("label table has wrong dtype(s): " + "; ".join(wrong))
    out = df.copy()
    for c, want in COLUMNS.items():
        target = _TEXT_DTYPE if want == STRING else np.dtype(want)
        if out[c].dtype != target:  # converting a column that is already right costs ~1 ms
            out[c] = out[c].astype(target)
    outcome = out["outcome"].to_numpy(dtype=object)
    bad_outcome = sorted(set(outcome.tolist()) - set(OUTCOMES))
    if bad_outcome:
        raise SchemaError(f"outcome has unknown value(s) {bad_outcome}; allowed: {list(OUTCOMES)}")
    if not np.array_equal(out["success"].to_numpy(), outcome == Outcome.SUCCESS.label):
        raise SchemaError("success must be True exactly where outcome == 'success'")
    values = np.column_stack([out[c].to_numpy() for c in (*POSE_COLUMNS, "width", "score", "object_scale")])
    if not np.isfinite(values).all():
        raise SchemaError("pose, width, score and object_scale must be finite")
    norm = np.linalg.norm(values[:, 3:7], axis=1)
    if np.any(np.abs(norm - 1.0) > _QUAT_NORM_TOL):
        raise SchemaError(
            f"quaternions must be unit (xyzw); worst norm {norm[np.argmax(np.abs(norm - 1))]!r}"
        )
    score = values[:, 8]
    if ((score < 0) | (score > 1)).any():
        raise SchemaError("score must lie in [0, 1]")
    unit = "scene_id" if "scene_id" in out.columns else "object_id"  # scene labels number per scene
    keys = pd.MultiIndex.from_arrays([out[unit].to_numpy(dtype=object), out["grasp_id"].to_numpy()])
    if keys.has_duplicates:
        raise SchemaError(f"({unit}, grasp_id) must be unique")
    return out
