"""The label schema: every column of every mode declared once, the docs' tables made from it, the
row builder holding every producer to its mode's columns, real rows of the mode's dtypes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from annotator import schema
from annotator.config import AnnotatorConfig
from annotator.dataset import COLUMNS, Outcome, mode_errors
from annotator.geometry import Transform
from annotator.label_row import TrialsResult, label_row

DOCS = Path(__file__).resolve().parent.parent / "docs"
SAMPLES = Path(__file__).resolve().parent.parent / "objects"

# the sixteen columns load_labels has always checked, in their order (the Arrow writer puts them first)
LEGACY_REQUIRED = (
    "object_id grasp_id x y z qx qy qz qw width success outcome score object_scale mesh_sha256 seed"
).split()


def test_the_required_columns_are_the_sixteen_of_the_contract():
    assert list(schema.REQUIRED) == LEGACY_REQUIRED
    assert COLUMNS == schema.REQUIRED
    assert list(schema.MODES["object"][:16]) == LEGACY_REQUIRED


def test_every_mode_column_is_declared_once_and_every_declared_column_is_used():
    used = {c for names in schema.MODES.values() for c in names}
    # a mode's columns, and the optional ones after them (with a calibration)
    assert used | set(schema.CONFIDENCE_COLUMNS) == set(schema.COLUMNS)
    assert not used & set(schema.CONFIDENCE_COLUMNS)
    for mode, names in schema.MODES.items():
        assert len(set(names)) == len(names), mode
        assert [c.name for c in schema.columns_of(mode)] == list(names)
        assert set(LEGACY_REQUIRED) <= set(names), mode
    assert schema.MODES["capture"] == schema.MODES["object"] == schema.MODES["evaluate"]
    assert len(schema.MODES["object"]) == 32
    with pytest.raises(KeyError, match="unknown label mode"):
        schema.columns_of("nope")


def test_docs_labels_tables_are_the_schema():
    """docs/labels.md shows each section's table exactly as the schema makes it (regenerate with
    ``python -m annotator.schema docs/labels.md``): every column with its dtype, unit and
    frame, and no documented column that the schema lacks."""
    text = (DOCS / "labels.md").read_text()
    sections = schema.doc_sections(text)
    assert set(sections) == set(schema.DOC_SECTIONS)
    for name, table in sections.items():
        assert table == schema.markdown_table(name), f"docs/labels.md section {name} differs from the schema"
    documented = set()
    for table in sections.values():
        for line in table.splitlines()[2:]:
            cell = line.split("|")[1]
            documented |= {part.strip("` ") for part in cell.replace("…", ",").split(",")}
    declared = set(schema.COLUMNS)
    assert {d for d in documented if d not in declared} <= {
        f"{p}{q}" for p in ("", "cmd_", "obj_", "rest_", "table_tcp_") for q in ("qy", "qz")
    } | {f"q_grasp_{i}" for i in range(1, 5)}  # a group's middle columns are written with "…"
    assert documented <= declared


def test_a_changed_table_is_caught():
    text = (DOCS / "labels.md").read_text().replace("| `slip` | float64 | m |", "| `slip` | float32 | m |")
    assert schema.doc_sections(text)["object"] != schema.markdown_table("object")
    assert schema.doc_sections(schema.render_docs(text))["object"] == schema.markdown_table("object")


class _Model:
    scale = 1.0
    mesh_sha256 = "ab" * 32
    mass = 0.1

    class collision_error:  # noqa: N801 - stands for the model's record
        mean = 0.0001
        max = 0.001


def _row(mode: str, extra=None) -> dict:
    T = Transform([0.01, 0.0, 0.02], [0.0, 0.0, -0.7071067811865476, -0.7071067811865476])
    result = TrialsResult(Outcome.SUCCESS, T, 0.03, 1200, 0.001, 1)
    return label_row(
        mode,
        object_id="box",
        grasp_id=3,
        result=result,
        trials=1,
        T_cmd=T,
        cmd_width=0.031,
        model=_Model,
        seed=7,
        gripper="rg2",
        extra=extra,
    )


def test_the_row_builder_orders_a_mode_and_refuses_other_columns():
    row = _row("object")
    assert list(row) == list(schema.MODES["object"])
    assert row["qw"] >= 0 and row["cmd_qw"] < 0  # the label's quaternion canonical, the command as given
    assert row["success"] is True and row["score"] == 1.0
    with pytest.raises(ValueError, match="missing columns"):
        _row("cell")
    with pytest.raises(ValueError, match="not of the mode"):
        _row("object", {"antipodal": 1.0})
    assert mode_errors(pd.DataFrame([row]), "object") == []
    assert mode_errors(pd.DataFrame([row]).drop(columns="slip"), "object") != []
    bad = pd.DataFrame([row]).astype({"seed": np.float64})
    assert mode_errors(bad, "object") == ["seed: float64 (want int64)"]


def test_worker_rows_are_the_object_mode(tmp_path):
    """Real rows from a worker: exactly the object mode's columns, in order, with their dtypes."""
    from annotator.objects import discover_objects
    from annotator.pipeline import worker

    config = AnnotatorConfig()
    (source,) = [s for s in discover_objects(SAMPLES) if s.object_id == "box"]
    task = worker.SpanTask(span=worker.Span("box", source, None, 0, 4), config=config, seed=0, n=4)
    rows = worker.label_span(task).rows
    assert mode_errors(rows, "object") == []
