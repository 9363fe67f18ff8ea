"""Inputs that would mislead a tool are refused in one line, exit 2: a table naming a column twice
(pandas would quietly use the first and rename the second ``x.1``), and scene labels, where
(object_id, grasp_id) repeats across scenes, given to a tool that needs it to name one label."""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd
import pytest
from click.testing import CliRunner
from helpers import synthetic_labels

from annotator.cli import main
from annotator.tools.common import ToolError, one_row_per_grasp, read_table

REPO = Path(__file__).resolve().parents[2]


def _run(*args, code: int) -> str:
    result = CliRunner().invoke(main, [str(a) for a in args])
    assert result.exit_code == code, result.output
    assert "Traceback" not in result.output
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1, result.output
    return errors[0]


@pytest.fixture
def objects(tmp_path) -> Path:
    folder = tmp_path / "objects"
    folder.mkdir()
    shutil.copy(REPO / "objects" / "box.obj", folder)
    return folder


def _scene_labels(path: Path) -> Path:
    """Two scenes' labels of the same object: grasp ids 0..4 in each."""
    rows = pd.concat(
        [synthetic_labels("box", 5, seed=s).assign(scene_id=s) for s in (0, 1)], ignore_index=True
    )
    rows.to_parquet(path)
    return path


def test_a_grasps_csv_naming_x_twice_is_refused_by_evaluate(tmp_path, objects):
    grasps = tmp_path / "g.csv"
    grasps.write_text("object_id,x,y,z,qx,qy,qz,qw,x\nbox,0.5,0,0,0,0,0,1,0\n")  # a stale x, then the new one
    line = _run("evaluate", grasps, "--objects", objects, "--out", tmp_path / "o", code=2)
    assert "column 'x' appears 2 times" in line and not (tmp_path / "o").exists()


def test_a_parquet_grasps_table_naming_a_column_twice_is_refused(tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = tmp_path / "g.parquet"
    columns = [pa.array(["box"]), pa.array([0.0]), pa.array([1.0])]
    pq.write_table(pa.table(columns, names=["object_id", "x", "x"]), path)
    with pytest.raises(ToolError, match="column 'x' appears 2 times"):
        read_table(path, "grasps file")


def test_a_real_trials_csv_naming_real_success_twice_is_refused_by_calibrate(tmp_path, objects):
    labels = tmp_path / "labels.parquet"
    synthetic_labels("box", 5).to_parquet(labels)
    real = tmp_path / "real.csv"
    real.write_text("object_id,grasp_id,real_success,real_success\nbox,0,0,1\nbox,1,0,1\n")
    config = tmp_path / "c.toml"
    line = _run("calibrate", labels, real, "--objects", objects, "--write-config", config, code=2)
    assert "column 'real_success' appears 2 times" in line and not config.exists()


def test_scene_labels_need_a_scene_for_calibrate_and_replay(tmp_path, objects):
    labels = _scene_labels(tmp_path / "scenes.parquet")
    real = tmp_path / "real.csv"
    real.write_text("object_id,grasp_id,real_success\nbox,0,1\nbox,1,0\n")
    config = tmp_path / "c.toml"
    line = _run("calibrate", labels, real, "--objects", objects, "--write-config", config, code=2)
    assert "object 'box' grasp 0 is labelled in 2 scenes; name one with --scene N" in line
    line = _run("replay", labels, "--object", "box", "--grasp", "3", "--objects", objects, code=2)
    assert "object 'box' grasp 0 is labelled in 2 scenes; name one with --scene N" in line
    line = _run("replay", labels, "--object", "box", "--grasp", 3, "--objects", objects, "--scene", 7, code=2)
    assert "has no scene 7; its scenes: 0, 1" in line


def test_a_named_scene_gives_one_row_per_grasp(tmp_path):
    labels = pd.read_parquet(_scene_labels(tmp_path / "scenes.parquet"))
    rows = one_row_per_grasp(labels, "scenes.parquet", 1)
    assert rows["scene_id"].eq(1).all() and rows["grasp_id"].tolist() == [0, 1, 2, 3, 4]
    objects_only = labels[labels["scene_id"] == 0].drop(columns="scene_id")
    assert one_row_per_grasp(objects_only, "labels", None).equals(objects_only)
    with pytest.raises(ToolError, match="not scene labels"):
        one_row_per_grasp(objects_only, "labels", 0)


@pytest.mark.parametrize("option", [["--per-scene", "3"], ["--arrangement", "packed"]])
def test_scene_options_without_scenes_are_refused(tmp_path, objects, option):
    line = _run("annotate", "--objects", objects, "--n", 2, "--out", tmp_path / "o", *option, code=2)
    assert f"{option[0]} shapes the scenes of --scenes N: it needs --scenes" in line
    assert not (tmp_path / "o").exists()


# --- a user's file is never replaced unasked ---------------------------------------------------------


def test_calibrate_never_replaces_a_calibrated_toml_it_did_not_write(tmp_path, objects, monkeypatch):
    monkeypatch.chdir(tmp_path)
    labels = tmp_path / "labels.parquet"
    synthetic_labels("box", 5).to_parquet(labels)
    real = tmp_path / "real.csv"
    real.write_text("object_id,grasp_id,real_success\nbox,0,1\nbox,1,0\n")
    mine = tmp_path / "calibrated.toml"  # the default --write-config, a user's own file
    mine.write_text("[physics]\n# my hand-tuned friction\n")
    line = _run("calibrate", labels, real, "--objects", objects, code=2)
    assert "--write-config calibrated.toml exists and was not written by this tool; pass --overwrite" in line
    assert mine.read_text() == "[physics]\n# my hand-tuned friction\n"


def test_show_and_report_replace_only_pictures_and_pages_they_wrote(labelled, tmp_path):
    from annotator.store.outputs import written_here

    sheet, overview, page = tmp_path / "sheet.png", tmp_path / "sheet-overview.png", tmp_path / "r.html"
    show = ["show", labelled.labels_dir, "--object", "box", "--objects", labelled.objects_dir, "--png", sheet]
    report = ["report", labelled.labels_dir, "--objects", labelled.objects_dir, "--pictures", 0]
    report += ["--html", page]
    sheet.write_bytes(b"\x89PNG my holiday picture")
    page.write_text("<html>my notes</html>")
    assert "--png " + str(sheet) + " exists and was not written by this tool; pass --overwrite" in _run(
        *show, code=2
    )
    assert "exists and was not written by this tool; pass --overwrite" in _run(*report, code=2)
    assert sheet.read_bytes() == b"\x89PNG my holiday picture" and not overview.exists()
    assert page.read_text() == "<html>my notes</html>"
    for args in (show, report):
        CliRunner().invoke(main, [str(a) for a in [*args, "--overwrite"]], catch_exceptions=False)
    assert written_here(sheet) and written_here(overview) and written_here(page)
    for args in (show, report):  # their own files are replaced without asking
        result = CliRunner().invoke(main, [str(a) for a in args])
        assert result.exit_code == 0, result.output
    # a page the user edited since is theirs now
    page.write_text(page.read_text() + "<!-- my note -->")
    assert "--html " + str(page) + " was written by this tool" in _run(*report, code=2)
    assert page.read_text().endswith("<!-- my note -->")


def test_a_folder_of_parquet_files_is_read_as_one_table(tmp_path):
    folder = tmp_path / "grasps"
    folder.mkdir()
    for k in (0, 1):
        synthetic_labels(f"o{k}", 3).to_parquet(folder / f"part{k}.parquet")
    assert len(read_table(folder, "grasps file")) == 6
