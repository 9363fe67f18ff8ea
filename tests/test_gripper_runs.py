"""A run binds its gripper: the manifest refuses another, every row names it, the tools use it.

Fast tests build label folders with the store (synthetic rows, no simulation); the slow ones run
``annotate --gripper panda`` on a box and read its labels back with the tools.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import h5py
import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner
from helpers import run_annotate, synthetic_labels

from annotator.cli import main
from annotator.config import AnnotatorConfig
from annotator.grippers import GripperFiles, gripper_dir, gripper_record, load_gripper
from annotator.store import MANIFEST_NAME, RunMismatchError, RunSpec, Store
from annotator.tools.common import ToolError, labelling_gripper

REPO = Path(__file__).resolve().parents[1]
SRC = "cd" * 32


def _spec(gripper: str | None = "rg2") -> RunSpec:
    record = gripper_record(load_gripper(gripper)) if gripper else None
    return RunSpec(0, 10, 1, None, 5, AnnotatorConfig().to_dict(), gripper=record)


def _folder(path: Path, gripper: str | None, folder: str | None = None) -> Path:
    """A finished labels folder of one object written by the store under ``gripper``'s run."""
    store = Store(path, _spec(gripper))
    store.open()
    if folder is not None:
        store.manifest.gripper_folder = folder
    rows = synthetic_labels("box").assign(gripper=gripper or "rg2")
    store.write_chunk("box", rows.iloc[:5], 0, SRC)
    store.write_chunk("box", rows.iloc[5:], 5, SRC)
    store.finish_object("box", SRC)
    store.close()
    return path


# --- the manifest binds the gripper ---------------------------------------------------------------


def test_another_gripper_into_the_same_folder_is_refused_naming_both(tmp_path: Path) -> None:
    _folder(tmp_path, "panda")
    with pytest.raises(RunMismatchError) as info:
        Store(tmp_path, _spec("rg2")).open()
    text = str(info.value)
    panda, rg2 = load_gripper("panda").digest[:12], load_gripper("rg2").digest[:12]
    assert f"gripper panda (digest {panda}) in the folder, rg2 (digest {rg2}) now" in text
    assert "--overwrite" in text and "\n" not in text
    store = Store(tmp_path, _spec("panda"))  # the same gripper resumes
    store.open()
    store.close()
    assert json.loads((tmp_path / MANIFEST_NAME).read_text())["run"]["gripper"]["name"] == "panda"


def test_a_folder_written_before_grippers_were_bound_is_not_resumed_silently(tmp_path: Path) -> None:
    _folder(tmp_path, None)  # no gripper in its run
    assert "gripper" not in json.loads((tmp_path / MANIFEST_NAME).read_text())["run"]
    with pytest.raises(RunMismatchError, match="gripper none recorded in the folder, rg2"):
        Store(tmp_path, _spec("rg2")).open()


def test_the_same_gripper_files_elsewhere_are_the_same_gripper(tmp_path: Path) -> None:
    copy = tmp_path / "my_panda"
    shutil.copytree(gripper_dir("panda"), copy)
    assert load_gripper(copy).digest == load_gripper("panda").digest


# --- the tools use the labels' gripper -------------------------------------------------------------


def test_tools_use_the_gripper_the_manifest_records(tmp_path: Path) -> None:
    labels = _folder(tmp_path / "labels", "panda")
    chosen = labelling_gripper(labels)
    assert chosen.description.name == "panda"
    assert "the labels' own" in chosen.line() and MANIFEST_NAME in chosen.line()
    told = labelling_gripper(labels, "robotiq_2f85")
    assert told.description.name == "robotiq_2f85"
    assert told.line() == "gripper: robotiq_2f85 (--gripper robotiq_2f85; the labels were made with panda)"


def test_a_label_file_without_manifest_names_its_gripper_in_a_column(tmp_path: Path) -> None:
    path = tmp_path / "labels.parquet"
    synthetic_labels("box").assign(gripper="robotiq_2f85").to_parquet(path)
    assert labelling_gripper(path).description.name == "robotiq_2f85"
    mixed = tmp_path / "mixed.parquet"
    rows = synthetic_labels("box")
    rows.assign(gripper=np.where(rows.grasp_id < 5, "rg2", "panda")).to_parquet(mixed)
    with pytest.raises(ToolError, match=r"labels of several grippers \(panda, rg2\); pass --gripper"):
        labelling_gripper(mixed)
    bare = tmp_path / "bare.parquet"
    synthetic_labels("box").to_parquet(bare)
    default = labelling_gripper(bare)
    assert default.description.name == "rg2" and "no gripper recorded" in default.line()


def test_a_users_gripper_is_found_where_the_run_read_it_and_only_if_unchanged(tmp_path: Path) -> None:
    mine = tmp_path / "my_panda"
    shutil.copytree(gripper_dir("panda"), mine)
    labels = _folder(tmp_path / "labels", "panda", folder=str(mine))
    chosen = labelling_gripper(labels)
    assert chosen.description.folder == mine and str(mine) in chosen.line()
    toml = mine / "gripper.toml"
    toml.write_text(toml.read_text().replace("lateral_friction = 1.0", "lateral_friction = 0.5"))
    with pytest.raises(ToolError, match="no longer there or has changed; pass --gripper DIR"):
        labelling_gripper(labels)
    shutil.rmtree(mine)
    with pytest.raises(ToolError, match="pass --gripper DIR"):
        labelling_gripper(labels)


def test_a_bad_gripper_option_is_one_line(tmp_path: Path) -> None:
    result = CliRunner().invoke(
        main, ["evaluate", str(tmp_path / "g.csv"), "--objects", str(tmp_path), "--out", str(tmp_path / "o")]
    )
    assert result.exit_code == 2  # no grasps file: one line, before any gripper
    (tmp_path / "g.csv").write_text("object_id,x,y,z,qx,qy,qz,qw\nbox,0,0,0,0,0,0,1\n")
    args = ["evaluate", str(tmp_path / "g.csv"), "--objects", str(tmp_path), "--out", str(tmp_path / "o")]
    result = CliRunner().invoke(main, [*args, "--gripper", "hand_of_god"])
    assert result.exit_code == 2 and "no gripper 'hand_of_god'" in result.output
    assert "Traceback" not in result.output


# --- a cluster's workers get the gripper's files ------------------------------------------------------


def test_gripper_files_carry_exactly_the_digested_files(tmp_path: Path) -> None:
    mine = tmp_path / "my_panda"
    shutil.copytree(gripper_dir("panda"), mine)
    (mine / "notes.txt").write_text("not part of the gripper")
    files = GripperFiles.of(load_gripper(mine))
    assert [name for name, _ in files.files] == ["gripper.toml", "panda.urdf"]
    shutil.rmtree(mine)  # the worker's machine does not have the folder
    unpacked = files.unpack(tmp_path / "cache")
    assert unpacked.digest == files.digest == load_gripper("panda").digest
    assert unpacked.folder == tmp_path / "cache" / "grippers" / files.digest
    assert files.unpack(tmp_path / "cache").folder == unpacked.folder  # once per digest
    (unpacked.folder / "gripper.toml").write_text(
        (unpacked.folder / "gripper.toml").read_text().replace("default = 70.0", "default = 60.0")
    )
    with pytest.raises(ValueError, match="not the run's 'panda'"):
        files.unpack(tmp_path / "cache")


# --- end to end: annotate --gripper panda and the tools on its labels -----------------------------------


@pytest.fixture(scope="module")
def panda_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("panda_run")
    objects = root / "objects"
    objects.mkdir()
    shutil.copy(REPO / "objects" / "box.obj", objects)
    out = root / "labels"
    run_annotate(
        "--objects", objects, "--n", 12, "--out", out, "--workers", 1, "--gripper", "panda", "--quiet"
    )
    return objects, out


@pytest.mark.slow
def test_annotate_records_the_gripper_per_row_and_in_the_run(panda_run, tmp_path: Path) -> None:
    objects, out = panda_run
    labels = pd.read_parquet(out)
    assert labels["gripper"].tolist() == ["panda"] * 12
    assert labels["success"].any()
    assert (labels["width"] <= 0.080 + 1e-6).all()  # the Panda's stroke, not the RG2's 110 mm
    run = json.loads((out / MANIFEST_NAME).read_text())["run"]
    assert run["gripper"] == gripper_record(load_gripper("panda"))
    again = run_annotate("--objects", objects, "--n", 12, "--out", out, "--workers", 1, "--quiet", check=2)
    assert "gripper panda (digest" in again.output and "rg2 (digest" in again.output


@pytest.mark.slow
def test_tools_on_panda_labels_simulate_and_draw_the_panda(panda_run, tmp_path: Path) -> None:
    objects, out = panda_run
    labels = pd.read_parquet(out).sort_values("grasp_id", ignore_index=True)
    # evaluate replays the labels with their own gripper: the same outcomes, bit for bit
    ev = tmp_path / "ev"
    result = CliRunner().invoke(
        main, ["evaluate", str(out), "--objects", str(objects), "--out", str(ev), "--workers", "1", "-q"]
    )
    assert result.exit_code == 0, result.output
    assert "gripper: panda (the labels' own" in result.output
    replayed = pd.read_parquet(ev).sort_values("grasp_id", ignore_index=True)
    assert replayed["outcome"].tolist() == labels["outcome"].tolist()
    assert replayed["gripper"].eq("panda").all()
    # show draws it and says so; export writes the Panda's type and base frame
    result = CliRunner().invoke(
        main,
        ["show", str(out), "--object", "box", "--objects", str(objects), "--png", str(tmp_path / "s.png")],
    )
    assert result.exit_code == 0 and "gripper: panda" in result.output, result.output
    exported = tmp_path / "acronym"
    args = ["export", str(out), "--format", "acronym", "--objects", str(objects), "--out", str(exported)]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    (h5,) = exported.glob("box-*.h5")
    with h5py.File(h5) as f:
        assert f["gripper/type"][()].decode() == "franka_panda"
        T = f["grasps/transforms"][()]
    # the exported base poses are the Panda's: its TCP is 103.65 mm along the base's z
    tcp = T @ np.array([0.0, 0.0, 0.10365, 1.0])
    np.testing.assert_allclose(tcp[:, :3], labels[["x", "y", "z"]].to_numpy(), atol=2e-4)


@pytest.mark.slow
@pytest.mark.cluster
def test_a_users_gripper_on_a_dask_cluster_gives_the_local_labels(panda_run, tmp_path, monkeypatch) -> None:
    """The cluster's workers simulate the gripper from the files the run sends them (unpacked into
    their cache by digest), so a user's folder need not exist where they run."""
    distributed = pytest.importorskip("dask.distributed")
    objects, local = panda_run
    mine = tmp_path / "my_panda"
    shutil.copytree(gripper_dir("panda"), mine)
    cache = tmp_path / "cache"
    monkeypatch.setenv("RG2_CACHE_DIR", str(cache))  # the workers' cache (they inherit the environment)
    out = tmp_path / "dask"
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        run_annotate(
            "--objects",
            objects,
            "--n",
            12,
            "--gripper",
            mine,
            "--scheduler",
            cluster.scheduler_address,
            "--out",
            out,
            "--quiet",
        )
    digest = load_gripper(mine).digest
    assert (cache / "grippers" / digest / "gripper.toml").is_file()
    key = ["object_id", "grasp_id"]
    pd.testing.assert_frame_equal(
        pd.read_parquet(out).sort_values(key, ignore_index=True),
        pd.read_parquet(local).sort_values(key, ignore_index=True),
        check_exact=True,
    )
    assert json.loads((out / MANIFEST_NAME).read_text())["gripper_folder"] == str(mine.resolve())


@pytest.mark.slow
def test_a_worker_keeps_its_objects_across_configurations_with_the_same_labels(tmp_path: Path) -> None:
    """A calibration grid changes the gripper's and the protocol's numbers from task to task; a
    worker keeps the objects it loaded, and its rows are those of a fresh worker."""
    from annotator.objects import discover_objects
    from annotator.pipeline import worker
    from annotator.pipeline.tasks import Span, SpanTask

    folder = tmp_path / "objects"
    folder.mkdir()
    shutil.copy(REPO / "objects" / "box.obj", folder)
    (source,) = discover_objects(folder)
    base = AnnotatorConfig()
    other = AnnotatorConfig.from_dict(
        {"gripper": {"pad_lateral_friction": 0.4}, "protocol": {"shake_angle": 0.5}}
    )

    def task(config):
        return SpanTask(
            span=Span("box", source, None, 0, 6),
            config=config,
            seed=0,
            n=6,
            gripper=load_gripper("panda"),
        )

    reused = worker.WorkerState()
    reused.label(task(base))
    model = reused.strategy.current.model
    second = reused.label(task(other))
    assert reused.strategy.current.model is model  # not loaded again
    fresh = worker.WorkerState().label(task(other))
    pd.testing.assert_frame_equal(second.rows, fresh.rows, check_exact=True)
