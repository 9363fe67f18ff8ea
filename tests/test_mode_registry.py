"""Adding a mode is what docs/architecture.md says it is: a mode that lives in this file alone (its
record, its rows' columns, its strategy) labels end to end through the one runner, the workers and
the store, and the records the package ships say what they always said to the manifest."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pandas as pd
import pytest

from annotator.config import AnnotatorConfig
from annotator.dataset import load_labels
from annotator.geometry import Transform
from annotator.label_table import mode_errors
from annotator.objects import ObjectModel
from annotator.pipeline.loaded import GraspSetup
from annotator.pipeline.modes import (
    REGISTRY,
    CellMode,
    FloatingMode,
    Mode,
    RestingMode,
    SceneMode,
    bound_mode,
    register,
    resting,
)
from annotator.pipeline.object_job import ObjectOptions
from annotator.pipeline.object_modes import FloatingLabeller
from annotator.pipeline.run import RunOptions, UsageError, run
from annotator.schema import FLOAT64, ColumnGroup, declare_mode
from annotator.trial import GraspTrial

SAMPLES = Path(__file__).resolve().parent.parent / "objects"

# --- the mode: every grasp run ``offset`` m back along its approach, as an execution error would ----

SHIFTED_COLUMNS = declare_mode(
    "shifted",
    (ColumnGroup(("approach_offset",), FLOAT64, "m", "TCP", "how far back along its approach a grasp ran"),),
)


@register
@dataclass(frozen=True)
class ShiftedMode(Mode):
    """The floating gripper, each grasp run ``offset`` m back along its approach (TCP -z)."""

    name: ClassVar[str] = "shifted"
    rows: ClassVar[str] = "shifted"
    strategy: ClassVar[str] = f"{__name__}:ShiftedLabeller"
    offset: float = 0.0

    def binds(self) -> dict[str, Any]:
        return {"shifted": {"offset": float(self.offset)}}

    def flags(self) -> str:
        return f"--shifted {self.offset}"


class ShiftedLabeller(FloatingLabeller):
    """The floating mode's world; the object placed as a :class:`ShiftedObject`."""

    def place(self, model: ObjectModel, uid: int) -> ShiftedObject:
        assert isinstance(self.mode, ShiftedMode)
        self.world.set_gravity(False)
        return ShiftedObject(GraspTrial(self.world, self.hand, uid, self.config), self.mode.offset)


class ShiftedObject:
    """A floating object whose grasps run ``offset`` m back along their approach."""

    def __init__(self, trial: GraspTrial, offset: float) -> None:
        self.trial, self.offset = trial, offset

    def setup(self, T: Transform, width: float, grasp_id: int, placement, rest) -> GraspSetup:
        back = Transform([0.0, 0.0, -self.offset], [0.0, 0.0, 0.0, 1.0])
        pose = T if self.offset == 0.0 else T * back
        return GraspSetup(self.trial, pose, lambda: {"approach_offset": self.offset})

    def release(self) -> None:
        self.trial.close()


# --- the tests -------------------------------------------------------------------------------------------


def _box(tmp_path: Path) -> Path:
    folder = tmp_path / "objects"
    folder.mkdir()
    (folder / "box.obj").write_bytes((SAMPLES / "box.obj").read_bytes())
    return folder


def _run(objects: Path, out: Path, own: ObjectOptions) -> pd.DataFrame:
    run(RunOptions(objects, 20, out_dir=out, workers=1, quiet=True), AnnotatorConfig(), own)
    return load_labels(out).sort_values("grasp_id", ignore_index=True)


@pytest.mark.slow
def test_a_mode_in_one_file_labels_end_to_end(tmp_path):
    objects = _box(tmp_path)
    floating = _run(objects, tmp_path / "floating", ObjectOptions())
    same = _run(objects, tmp_path / "shifted0", ObjectOptions(mode=ShiftedMode(0.0)))
    back = _run(objects, tmp_path / "shifted10", ObjectOptions(mode=ShiftedMode(0.10)))
    assert mode_errors(same, "shifted") == [] and mode_errors(back, "shifted") == []
    assert list(same.columns) == list(SHIFTED_COLUMNS)
    # no offset: the floating mode's trials, bit for bit; 10 cm back, the pads close on nothing
    pd.testing.assert_frame_equal(same[list(floating.columns)], floating, check_exact=True)
    assert (same["approach_offset"] == 0.0).all() and (back["approach_offset"] == 0.10).all()
    assert floating["success"].sum() >= 5 and back["success"].sum() < floating["success"].sum()
    assert (back["outcome"] == "no_contact").sum() > (floating["outcome"] == "no_contact").sum()
    manifest = json.loads((tmp_path / "shifted10" / "_manifest.json").read_text())
    assert manifest["run"]["inputs"] == {"shifted": {"offset": 0.10}}
    # a folder of one mode never resumes as another
    with pytest.raises(UsageError):
        _run(objects, tmp_path / "shifted10", ObjectOptions(mode=ShiftedMode(0.0)))


def test_the_shipped_records_bind_what_runs_always_bound():
    """The manifest's inputs of each mode, as folders made before the records keep them, and read
    back (:func:`bound_mode`) as the record that wrote them."""
    assert FloatingMode().binds() == {}
    assert CellMode(2).binds() == {"cell": {"views": 2}}
    assert RestingMode().binds() == {"resting": True}  # "object", as folders before "table" bind it
    assert RestingMode("table").binds() == {"resting": "table"}
    for mode in (FloatingMode(), CellMode(0), CellMode(3), RestingMode(), RestingMode("table")):
        assert bound_mode(mode.binds()) == mode
    assert bound_mode({"scenes": {"cell": True, "views": 0}}) == SceneMode(cell=True)
    assert resting(False) == FloatingMode() and resting(True) == RestingMode("object")
    assert resting("table") == RestingMode("table")
    with pytest.raises(ValueError, match="choose from"):
        RestingMode("floor")


def test_the_registry_names_each_mode_once_with_its_rows_and_strategy():
    shipped = {"floating": "object", "cell": "cell", "resting": "resting", "scene": "scene"}
    assert {name: REGISTRY[name].rows for name in shipped} == shipped
    assert REGISTRY["shifted"] is ShiftedMode
    assert SceneMode(cell=True).row_mode() == "scene_cell" and CellMode(4).world() == CellMode(0).world()
    with pytest.raises(ValueError, match="registered already"):

        @register
        @dataclass(frozen=True)
        class Floating(Mode):
            name: ClassVar[str] = "floating"

    for name, record in REGISTRY.items():
        module, _, attr = record.strategy.partition(":")
        assert module and attr, name


def test_a_job_refuses_a_mode_it_cannot_run(tmp_path):
    objects = _box(tmp_path)
    options = RunOptions(objects, 5, out_dir=tmp_path / "out", workers=1, quiet=True)
    with pytest.raises(UsageError, match="given grasps only"):
        run(options, AnnotatorConfig(), ObjectOptions(mode=RestingMode()))
    with pytest.raises(UsageError, match="labels scenes, not objects"):
        run(options, AnnotatorConfig(), ObjectOptions(mode=SceneMode()))
    assert not np.any([p.exists() for p in (tmp_path / "out",)])
