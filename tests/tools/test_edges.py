"""The tools at their edges: bad input is one line and an exit code, never a traceback, never a
silent fallback; outputs are checked before any work; unfinished runs are refused or marked;
exports never mix datasets or remove what they did not write."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner
from helpers import synthetic_labels

from annotator.cli import main
from annotator.config import AnnotatorConfig
from annotator.store import MANIFEST_NAME, RunSpec, Store
from annotator.tools import common

SRC = "ab" * 32


def _run(*args, code: int) -> str:
    result = CliRunner().invoke(main, [str(a) for a in args])
    assert result.exit_code == code, result.output
    assert "Traceback" not in result.output
    return result.output


def _one_line_error(output: str) -> str:
    errors = [line for line in output.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1, output
    return errors[0]


def _unfinished_folder(folder: Path) -> Path:
    """A run's folder with object a merged and object b still in chunks (its run stopped)."""
    spec = RunSpec(0, 10, 1, None, 5, AnnotatorConfig().to_dict())
    store = Store(folder, spec)
    store.open()
    store.reconcile({"a": SRC, "b": SRC})
    whole = synthetic_labels("a")
    store.write_chunk("a", whole.iloc[:5], 0, SRC)
    store.write_chunk("a", whole.iloc[5:], 5, SRC)
    store.finish_object("a", SRC)
    store.write_chunk("b", synthetic_labels("b", 5), 0, SRC)
    store.close()
    return folder


# --- reading -----------------------------------------------------------------------------------------


def test_an_unfinished_run_is_told_apart_and_read_as_its_manifest_vouches(tmp_path: Path) -> None:
    folder = _unfinished_folder(tmp_path / "labels")
    pd.DataFrame({"mine": [1]}).to_parquet(folder / "mine.parquet")  # a user's file is not a label
    run = common.open_labels(folder)
    assert not run.finished and run.unfinished == ["b"]
    assert "1 of its objects not labelled yet (b)" in run.state()
    assert sorted(run.labels.groupby("object_id").size().items()) == [("a", 10), ("b", 5)]
    with pytest.raises(common.ToolError, match="pass --partial to export"):
        run.require_finished("export")


def test_a_chunk_removed_while_reading_is_read_again(tmp_path: Path, monkeypatch) -> None:
    from annotator.store.reader import LabelsFolder

    folder = _unfinished_folder(tmp_path / "labels")
    real = LabelsFolder.read
    calls = []

    def vanishing(self, names=None):
        calls.append(self.label_files())
        if len(calls) == 1:  # a merge removed a chunk between listing and reading
            raise FileNotFoundError(self.path / calls[-1][-1])
        return real(self, names)

    monkeypatch.setattr(LabelsFolder, "read", vanishing)
    assert len(common.open_labels(folder).labels) == 15 and len(calls) == 2
    monkeypatch.setattr(
        LabelsFolder, "read", lambda self, names=None: (_ for _ in ()).throw(FileNotFoundError())
    )
    with pytest.raises(common.ToolError, match="keep changing"):
        common.open_labels(folder)


@pytest.mark.parametrize("command", ["show", "report", "export", "replay"])
@pytest.mark.parametrize("content", [b"not parquet at all", b"PAR1" + bytes(100)])
def test_a_corrupt_label_file_is_one_line_for_every_tool(
    tmp_path: Path, command: str, content: bytes
) -> None:
    bad = tmp_path / "labels.parquet"
    bad.write_bytes(content)
    args = {
        "show": ["show", bad, "--object", "a", "--png", tmp_path / "s.png"],
        "report": ["report", bad, "--html", tmp_path / "r.html", "--pictures", 0],
        "export": ["export", bad, "--format", "graspgen", "--out", tmp_path / "e"],
        "replay": ["replay", bad, "--object", "a", "--grasp", 0],
    }[command]
    assert "not a readable label file" in _one_line_error(_run(*args, code=2))


def test_a_manifest_of_another_shape_is_one_line_for_the_tools(labelled, tmp_path: Path) -> None:
    folder = tmp_path / "labels"
    shutil.copytree(labelled.labels_dir, folder)
    data = json.loads((folder / MANIFEST_NAME).read_text())
    data["run"]["config"] = 1
    (folder / MANIFEST_NAME).write_text(json.dumps(data))
    for args in (
        ["report", folder, "--html", tmp_path / "r.html"],
        ["export", folder, "--format", "graspgen", "--out", tmp_path / "e"],
    ):
        assert "manifest.run.config" in _one_line_error(_run(*args, code=2))


# --- outputs checked before any work ------------------------------------------------------------------


@pytest.mark.parametrize("command", ["show", "report", "export", "replay", "calibrate"])
def test_an_output_that_cannot_be_written_is_exit_3_before_any_work(
    labelled, tmp_path: Path, command
) -> None:
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    where = blocker / "sub" / "out"  # a folder cannot be made under a file
    real = tmp_path / "real.csv"
    real.write_text("object_id,grasp_id,real_success\nbox,0,1\n")
    labels, objects = labelled.labels_dir, labelled.objects_dir
    args = {
        "show": ["show", labels, "--object", "box", "--png", where / "s.png"],
        "report": ["report", labels, "--html", where / "r.html"],
        "export": ["export", labels, "--format", "graspgen", "--out", where],
        "replay": [
            "replay",
            labels,
            "--object",
            "box",
            "--grasp",
            0,
            "--objects",
            objects,
            "--gif",
            where / "g.gif",
        ],
        "calibrate": ["calibrate", labels, real, "--objects", objects, "--write-config", where / "c.toml"],
    }[command]
    line = _one_line_error(_run(*args, code=3))
    assert "cannot be written" in line and str(blocker) in line


# --- exports never mix datasets --------------------------------------------------------------------


def test_an_export_into_an_earlier_one_is_refused_and_overwrite_removes_only_its_files(
    labelled, tmp_path: Path
) -> None:
    out = tmp_path / "export"
    labels = labelled.labels_dir
    _run("export", labels, "--format", "graspgen", "--out", out, "--object", "box", "--object", "can", code=0)
    (out / "my_notes.txt").write_text("mine")
    line = _one_line_error(
        _run("export", labels, "--format", "graspgen", "--out", out, "--object", "box", code=2)
    )
    assert "holds an earlier export" in line and "--overwrite" in line
    _run("export", labels, "--format", "graspgen", "--out", out, "--object", "box", "--overwrite", code=0)
    assert (out / "my_notes.txt").read_text() == "mine"
    grasps = sorted(p.name for p in (out / "grasps").iterdir())
    assert len(grasps) == 1 and grasps[0].startswith("box")
    splits = (out / "splits" / "train.txt").read_text() + (out / "splits" / "valid.txt").read_text()
    assert "can" not in splits and "box" in splits
    assert json.loads((out / "_export.json").read_text())["files"] == sorted(
        str(p.relative_to(out))
        for p in out.rglob("*")
        if p.is_file() and p.name not in ("_export.json", "my_notes.txt")
    )


def test_an_export_never_replaces_a_file_it_did_not_write(labelled, tmp_path: Path) -> None:
    out = tmp_path / "export"
    (out / "meshes").mkdir(parents=True)
    from annotator.tools.export import object_stem

    mine = out / "meshes" / f"{object_stem('box')}.obj"
    mine.write_text("my own mesh")
    line = _one_line_error(_run("export", labelled.labels_dir, "--format", "graspgen", "--out", out, code=2))
    assert "was not written by an export" in line and mine.read_text() == "my own mesh"


def test_export_refuses_an_unfinished_run_unless_partial_and_report_marks_it(tmp_path: Path) -> None:
    folder = _unfinished_folder(tmp_path / "labels")
    line = _one_line_error(_run("export", folder, "--format", "graspgen", "--out", tmp_path / "e", code=2))
    assert "unfinished" in line and "--partial" in line
    output = _run("report", folder, "--html", tmp_path / "r.html", "--pictures", 0, code=0)
    assert "the labels' run is unfinished" in output
    assert "This run is unfinished" in (tmp_path / "r.html").read_text()


# --- values that are not what they say ------------------------------------------------------------


def test_evaluate_names_a_row_with_an_invalid_commanded_grasp(labelled, tmp_path: Path) -> None:
    """Before, one bad cmd_qw dropped the commanded grasps of every row, silently."""
    table = labelled.df.copy()
    table.loc[3, "cmd_qw"] = 0.5
    grasps = tmp_path / "grasps.parquet"
    table.to_parquet(grasps)
    line = _one_line_error(
        _run("evaluate", grasps, "--objects", labelled.objects_dir, "--out", tmp_path / "ev", code=2)
    )
    assert "row 3: commanded quaternion" in line


@pytest.mark.parametrize("scale", ["0", "-1", "nan", "inf"])
def test_evaluate_refuses_a_scale_that_is_not_a_positive_number(labelled, tmp_path: Path, scale) -> None:
    output = _run(
        "evaluate",
        labelled.labels_dir,
        "--objects",
        labelled.objects_dir,
        "--out",
        tmp_path / "ev",
        "--scale",
        scale,
        code=2,
    )
    assert "--scale" in output and "must be a finite number > 0" in output


def test_calibrate_refuses_a_fractional_grasp_id_and_an_int64_overflowing_seed(
    labelled, tmp_path: Path
) -> None:
    real = tmp_path / "real.csv"
    real.write_text("object_id,grasp_id,real_success\nbox,9.5,1\n")
    args = [
        "calibrate",
        labelled.labels_dir,
        real,
        "--objects",
        labelled.objects_dir,
        "--write-config",
        tmp_path / "c.toml",
    ]
    assert "row 0: grasp_id 9.5 is not a non-negative integer" in _one_line_error(_run(*args, code=2))
    real.write_text("object_id,grasp_id,real_success\nbox,9,1\n")
    output = _run(*args, "--seed", 2**63, code=2)
    assert "--seed" in output and "9223372036854775808 is not in the range" in output
    assert not (tmp_path / "c.toml").exists()


def test_the_tools_use_the_configuration_the_labels_were_made_with_and_say_so(
    labelled, tmp_path: Path
) -> None:
    folder = tmp_path / "labels"
    shutil.copytree(labelled.labels_dir, folder)
    data = json.loads((folder / MANIFEST_NAME).read_text())
    data["run"]["config"]["gripper"]["pad_lateral_friction"] = 0.2
    (folder / MANIFEST_NAME).write_text(json.dumps(data))
    chosen = common.labelling_config(folder)
    assert chosen.config.gripper.pad_lateral_friction == 0.2 and "the labels' own" in chosen.line()
    cfg = tmp_path / "c.toml"
    cfg.write_text("[gripper]\npad_lateral_friction = 0.7\n")
    told = common.labelling_config(folder, cfg)
    assert told.config.gripper.pad_lateral_friction == 0.7 and f"--config {cfg}" in told.line()
    assert "the defaults" in common.labelling_config(tmp_path / "nowhere.parquet").line()
    output = _run(
        "replay", folder, "--object", "box", "--grasp", 0, "--objects", labelled.objects_dir, code=0
    )
    assert output.splitlines()[0] == f"configuration: the labels' own ({folder / MANIFEST_NAME})"
    assert np.isfinite(chosen.config.physics.time_step)


@pytest.mark.parametrize("command", ["replay", "show"])
@pytest.mark.parametrize("grasp", ["-1", str(2**63)])
def test_a_grasp_id_no_label_can_have_is_one_line_before_the_labels_are_read(command, grasp, tmp_path):
    """``--grasp`` takes a label's grasp_id (int64, never negative): -1 or 2^63 is refused naming the
    option, before any reading (2^63 overflowed the comparison with the labels' int64 column)."""
    extra = ["--object", "box"] if command == "replay" else []
    error = _one_line_error(_run(command, tmp_path, *extra, "--grasp", grasp, code=2))
    assert "'--grasp'" in error and f"{grasp} is not in the range" in error


def test_every_number_a_command_takes_has_a_range():
    """Every integer or real option and argument of every command is a click.IntRange or
    FloatRange, or is checked by its callback (``--scale``: positive and finite)."""
    import click

    from annotator.cli.annotate import annotate_command

    def params(command, path):
        if isinstance(command, click.Group):
            for name, sub in command.commands.items():
                yield from params(sub, [*path, name])
        else:
            for param in command.params:
                yield " ".join(path), param

    unbounded = [
        f"{path} {param.name}"
        for path, param in [*params(main, ["annotator"]), *params(annotate_command, ["annotate"])]
        if isinstance(param.type, (click.types.IntParamType, click.types.FloatParamType))
        and not isinstance(param.type, (click.IntRange, click.FloatRange))
        and param.callback is None
    ]
    assert not unbounded
