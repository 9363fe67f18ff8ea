"""One way to write an output (annotator.store.outputs): a file a tool did not write, or one changed
since it wrote it, is never replaced unasked; two options never name one file; two commands never
write one file at once; a file is whole or absent."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from annotator.cli import main
from annotator.store import LockedError
from annotator.store.outputs import OutputRefusedError, Outputs, lock_name, mark_path, written_here


def _errors(result) -> list[str]:
    assert "Traceback" not in result.output
    return [line for line in result.output.splitlines() if line.startswith("Error:")]


def _run(*args, code: int) -> str:
    result = CliRunner().invoke(main, [str(a) for a in args])
    assert result.exit_code == code, result.output
    errors = _errors(result)
    assert len(errors) == (1 if code else 0), result.output
    return errors[0] if code else result.output


def test_an_output_is_replaced_only_when_the_tool_wrote_it_and_nobody_changed_it(tmp_path):
    path = tmp_path / "model.npz"
    path.write_bytes(b"the user's own")
    with pytest.raises(OutputRefusedError, match="exists and was not written by this tool; pass --overwrite"):
        Outputs.claim("test", {"--out": path})
    assert path.read_bytes() == b"the user's own"
    with Outputs.claim("test", {"--out": path}, overwrite=True) as outputs:
        assert outputs.write_bytes("--out", b"v1") == path
    assert written_here(path) and mark_path(path).exists() and not (tmp_path / lock_name(path)).exists()
    with Outputs.claim("test", {"--out": path}) as outputs:  # its own, unchanged: replaced unasked
        outputs.write_bytes("--out", b"v2")
    path.write_bytes(b"v2, edited by hand")
    with pytest.raises(OutputRefusedError, match="was written by this tool .* and has changed since"):
        Outputs.claim("test", {"--out": path})
    assert path.read_bytes() == b"v2, edited by hand"


def test_two_outputs_of_one_command_never_name_one_file(tmp_path):
    same = tmp_path / "calibrated.toml"
    with pytest.raises(OutputRefusedError, match="--write-config and --reliability name the same file"):
        Outputs.claim("test", {"--write-config": same, "--reliability": tmp_path / "." / "calibrated.toml"})
    assert not same.exists() and not list(tmp_path.iterdir())


def test_a_second_writer_of_one_file_is_refused_while_the_first_holds_it(tmp_path):
    path = tmp_path / "rounds.csv"
    with Outputs.claim("first", {"--out": path}):
        with pytest.raises(LockedError, match="is being written by another command"):
            Outputs.claim("second", {"--out": path})
        other = Outputs.claim("second", {"--out": tmp_path / "grasps.csv"})  # another file: fine
        other.release()
    with Outputs.claim("third", {"--out": path}):  # released: free again
        pass


def test_a_file_changed_while_the_command_ran_is_kept_and_the_output_goes_beside_it(tmp_path):
    path = tmp_path / "sheet.csv"
    with Outputs.claim("test", {"--out": path}) as outputs:
        path.write_text("the user's, written meanwhile")
        where = outputs.write_text("--out", "the tool's")
    assert path.read_text() == "the user's, written meanwhile"
    assert where == tmp_path / "sheet.new.csv" and where.read_text() == "the tool's" and written_here(where)


def test_a_write_that_fails_leaves_the_previous_file_whole(tmp_path):
    path = tmp_path / "model.npz"
    with Outputs.claim("test", {"--out": path}) as outputs:
        outputs.write_bytes("--out", b"v1")

        def half_then_fail(tmp: Path) -> None:
            tmp.write_bytes(b"half")
            raise OSError(28, "No space left on device")

        with pytest.raises(OSError, match="No space left on device"):
            outputs.write("--out", half_then_fail)
    assert path.read_bytes() == b"v1" and written_here(path)
    assert sorted(p.name for p in tmp_path.iterdir()) == [".model.npz.rg2-annotator", "model.npz"]


# --- the commands -----------------------------------------------------------------------------------------


@pytest.fixture
def real_csv(tmp_path) -> Path:
    path = tmp_path / "real.csv"
    path.write_text("object_id,grasp_id,real_success\nbox,0,1\nbox,1,0\ncan,0,1\ncan,1,0\n")
    return path


QUICK = [
    "--friction",
    "1.0",
    "--force",
    "40",
    "--severity",
    "1",
    "--folds",
    "0",
    "--trials",
    "1",
    "--workers",
    "1",
]


def test_calibrate_never_replaces_a_diagram_or_outcomes_it_did_not_write(labelled, tmp_path, real_csv):
    """--reliability and --outcomes replaced an existing file silently."""
    calibrate = ["calibrate", labelled.labels_dir, real_csv, "--objects", labelled.objects_dir, *QUICK]
    config = ["--write-config", tmp_path / "c.toml"]
    for option, name in (("--reliability", "diagram.png"), ("--outcomes", "outcomes.parquet")):
        mine = tmp_path / name
        mine.write_bytes(b"the user's own")
        line = _run(*calibrate, *config, option, mine, code=2)
        assert f"{option} {mine} exists and was not written by this tool; pass --overwrite" in line
        assert mine.read_bytes() == b"the user's own" and not (tmp_path / "c.toml").exists()


def test_calibrate_refuses_one_file_for_two_outputs(labelled, tmp_path, real_csv):
    """The diagram replaced the configuration, and "wrote" was said twice."""
    same = tmp_path / "c.toml"
    calibrate = ["calibrate", labelled.labels_dir, real_csv, "--objects", labelled.objects_dir, *QUICK]
    line = _run(*calibrate, "--write-config", same, "--reliability", same, code=2)
    assert "--write-config and --reliability name the same file" in line and not same.exists()


def test_calibrate_replaces_its_own_file_but_not_one_edited_since(labelled, tmp_path, real_csv):
    config = tmp_path / "c.toml"
    calibrate = ["calibrate", labelled.labels_dir, real_csv, "--objects", labelled.objects_dir, *QUICK]
    calibrate += ["--write-config", config, "--outcomes", tmp_path / "o.parquet"]
    first = _run(*calibrate, code=0)
    assert f"wrote {config}" in first and written_here(config) and written_here(tmp_path / "o.parquet")
    _run(*calibrate, code=0)  # its own files: replaced
    config.write_text(config.read_text() + "\n# my own note\n")
    line = _run(*calibrate, code=2)
    assert f"--write-config {config} was written by this tool" in line and "has changed since" in line
    assert config.read_text().endswith("# my own note\n")


def test_replay_never_replaces_a_gif_it_did_not_write(labelled, tmp_path):
    mine = tmp_path / "box.gif"
    mine.write_bytes(b"GIF89a the user's own")
    replay = [
        "replay",
        labelled.labels_dir,
        "--object",
        "box",
        "--grasp",
        0,
        "--objects",
        labelled.objects_dir,
    ]
    line = _run(*replay, "--gif", mine, code=2)
    assert f"--gif {mine} exists and was not written by this tool" in line
    assert mine.read_bytes() == b"GIF89a the user's own"


def test_a_second_clutter_removal_on_one_out_is_refused_naming_the_first(convex_objects, tmp_path):
    """Both said they wrote it; the second replaced the first."""
    from annotator.store.lock import RunLock

    out = tmp_path / "cr"
    out.mkdir()
    first = RunLock(out)
    first.acquire()  # another clutter-removal writing there now
    try:
        args = ["clutter-removal", "--objects", convex_objects, "--rounds", 1, "--policy", "random"]
        line = _run(*args, "--out", out, "--workers", 1, code=2)
        assert f"{out} is in use by another run (pid" in line and "clutter-removal" not in line.split("(")[0]
    finally:
        first.release()
    assert not (out / "rounds.csv").exists()


def test_an_export_goes_through_the_one_writer_locked_whole_and_recorded(labelled, tmp_path):
    """export wrote its meshes and splits in place (trimesh's own write, ``write_text``) and took no
    lock: a second export into one --out interleaved with the first. Now the folder is locked for
    the export (a second is refused naming the first), every file is a temporary file renamed,
    and _export.json records each file's SHA-256; no mark, lock or temporary file is left among
    the files the learners' readers list. --overwrite replaces an earlier export."""
    import json

    from annotator.store.outputs import file_sha256
    from annotator.tools.export import ExportFolder

    out = tmp_path / "export"
    export = [
        "export",
        labelled.labels_dir,
        "--format",
        "graspgen",
        "--out",
        out,
        "--objects",
        labelled.objects_dir,
    ]
    with ExportFolder.open(out, overwrite=False):  # another export writing there now
        line = _run(*export, code=2)
        assert f"--out {out} is being written by another command (pid" in line
        assert [p.name for p in out.iterdir()] == [".export.rg2-annotator.lock"]
    _run(*export, code=0)
    record = json.loads((out / "_export.json").read_text())
    files = sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file())
    assert record["files"] == [f for f in files if f != "_export.json"] and record["files"]
    assert record["sha256"] == {name: file_sha256(out / name) for name in record["files"]}
    assert any(f.startswith("meshes/") for f in files) and "splits/train.txt" in files
    line = _run(*export, code=2)
    assert "holds an earlier export; pass --overwrite" in line
    (out / "splits" / "train.txt").write_text("edited")
    _run(*export, "--overwrite", code=0)  # the earlier export's files replaced
    assert json.loads((out / "_export.json").read_text())["sha256"] == record["sha256"]


def test_a_file_of_an_export_is_whole_or_absent(tmp_path):
    """A write that fails (a full disk) leaves no part of the file and no temporary file, and the
    folder is free again when the export ends."""
    from annotator.tools.common import OutputToolError
    from annotator.tools.export import ExportFolder

    def half_then_fail(tmp: Path) -> None:
        tmp.write_text("half a mesh")
        raise OSError(28, "No space left on device")

    out = tmp_path / "export"
    with ExportFolder.open(out, overwrite=False) as folder:
        folder.write("meshes/a.obj", lambda tmp: tmp.write_text("v 0 0 0\n"))
        with pytest.raises(OutputToolError, match="No space left on device"):
            folder.write("meshes/b.obj", half_then_fail)
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*")) == ["meshes", "meshes/a.obj"]
    ExportFolder.open(out, overwrite=False).release()  # unlocked
