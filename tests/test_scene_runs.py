"""``annotate --scenes``: scenes as units of work, bit for bit on any worker layout, resumed mid-scene.

A pile of the concave sample objects (CoACD parts: the bowl has dozens), whose trials are the
hardest to keep deterministic (Bullet's contact memory across restoreState, docs/decisions/0006).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from helpers import QUICK_VIEWS, run_annotate
from scene_helpers import CONCAVE, REPO

from annotator.config import AnnotatorConfig
from annotator.dataset import keyed_rng, load_scenes, scene_labels
from annotator.objects import discover_objects
from annotator.pipeline import scene_mode, worker
from annotator.pipeline.scene_job import SCENE_CHUNK_SIZE, plan_scene_spans
from annotator.scenes import records as scene_records
from annotator.scenes.arrange import draw_objects
from annotator.scenes.labels import SCENE_LABEL_COLUMNS
from annotator.store import MANIFEST_NAME

N = 2 * SCENE_CHUNK_SIZE  # two spans per scene


@pytest.fixture(scope="module")
def concave(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("concave")
    for name in CONCAVE:
        shutil.copy(REPO / "objects" / name, folder)
    return folder


# The runs compared below: two scenes of 3 or 4 objects, two spans each, one quick view.
SCENE_ARGS = ("--scenes", 2, "--per-scene", "3-4", "--n", N, "--views", 1)


@pytest.fixture(scope="module")
def views_config(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("scene-config") / "views.toml"
    path.write_text(QUICK_VIEWS)
    return path


@pytest.fixture(scope="module")
def reference(concave, views_config, tmp_path_factory) -> Path:
    """The labels every other layout must give: the scenes of SCENE_ARGS with one local worker,
    uninterrupted (labelled once for the tests of this module that compare with it)."""
    out = tmp_path_factory.mktemp("reference") / "labels"
    run_annotate(
        "--objects", concave, "--out", out, "--workers", 1, "--quiet", *SCENE_ARGS, "--config", views_config
    )
    return out


def _labels(out: Path) -> pd.DataFrame:
    return pd.read_parquet(out).sort_values(["scene_id", "grasp_id"]).reset_index(drop=True)


def _artifacts(out: Path) -> dict[str, str]:
    return {
        str(p.relative_to(out)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted((out / "_views").rglob("*"))
        if p.is_file()
    }


def test_spans_plan_each_scenes_first_span_ahead():
    todo = [(0, frozenset()), (1, frozenset({(0, 40)})), (2, frozenset())]
    spans = [(s.scene_id, s.start) for s in plan_scene_spans(todo, 120, 40, ahead=2)]
    assert spans == [(0, 0), (1, 40), (0, 40), (0, 80), (2, 0), (1, 80), (2, 40), (2, 80)]
    assert len(set(spans)) == len(spans)


def test_bad_scene_options_are_one_line(concave, tmp_path):
    for args, text in (
        (["--per-scene", "0"], "--per-scene"),
        (["--per-scene", "5-3"], "--per-scene"),
        (["--per-scene", "x"], "--per-scene"),
    ):
        result = run_annotate("--objects", concave, "--scenes", 1, "--out", tmp_path / "o", *args, check=2)
        assert text in result.output and "Traceback" not in result.output
    result = run_annotate("--objects", concave, "--out", tmp_path / "o", check=2)
    assert "--n" in result.output
    result = run_annotate(
        "--objects", concave, "--scenes", 1, "--gripper", "no_such_gripper", "--out", tmp_path / "p", check=2
    )
    assert "--gripper" in result.output and "Traceback" not in result.output
    assert not (tmp_path / "p").exists()


def test_scenes_with_another_gripper_label_with_it_and_bind_it(convex_objects, tmp_path):
    """``--scenes --gripper panda``: every row is the Panda's (widths within its 80 mm stroke), the
    manifest binds it, a re-run resumes, and the same folder refuses another gripper; an RG2 scene
    run binds no gripper, as before grippers were data."""
    out = tmp_path / "panda"
    args = ["--objects", convex_objects, "--scenes", 1, "--per-scene", 2, "--n", 20, "--workers", 1]
    run_annotate(*args, "--gripper", "panda", "--out", out)
    labels = pd.read_parquet(out)
    assert len(labels) == 20 and set(labels["gripper"]) == {"panda"} and labels["width"].max() <= 0.0801
    manifest = json.loads((out / "_manifest.json").read_text())
    assert manifest["run"]["gripper"]["name"] == "panda"
    again = run_annotate(*args, "--gripper", "panda", "--out", out)
    assert "1 done earlier" in again.output
    other = run_annotate(*args, "--out", out, check=2)
    assert "gripper panda" in other.output
    rg2 = tmp_path / "rg2"
    run_annotate(*args, "--out", rg2)
    assert "gripper" not in json.loads((rg2 / "_manifest.json").read_text())["run"]


@pytest.mark.slow
def test_scene_spans_do_not_depend_on_the_order_or_the_worker(concave):
    """A scene's spans dealt in either order to a fresh worker, or with the scene's record given
    (as the main process passes it once the first span is back), give the same rows and the same
    scene file."""
    pool = tuple(discover_objects(concave))
    job = worker.SceneRequest(pool, None, "pile", 4, 4, N, seed=0)
    config = AnnotatorConfig()
    spans = [worker.SceneSpan(1, a, a + SCENE_CHUNK_SIZE) for a in range(0, N, SCENE_CHUNK_SIZE)]

    def run(order, record=None):
        worker.worker_state().close()
        worker._State.instance = None
        frames, files = [], {}
        for k in order:
            result = worker.label_span(
                worker.SceneTask(span=spans[k], request=job, config=config, record=record)
            )
            assert result.error is None, result.error
            frames.append(result.rows)
            files.update(result.artifacts or {})
        rows = pd.concat(frames).sort_values("grasp_id").reset_index(drop=True)
        return rows, files

    forward, files = run([0, 1])
    assert set(SCENE_LABEL_COLUMNS) <= set(forward.columns)
    assert forward["grasp_id"].tolist() == list(range(N))
    assert (forward["outcome"] != "collision").sum() >= 3  # physics ran, not only kinematic checks
    backward, files_back = run([1, 0])
    pd.testing.assert_frame_equal(backward, forward, check_exact=True)
    assert files_back == files
    record = scene_mode.record_from_artifact(files[scene_mode.SCENE_FILE])
    given, _ = run([1, 0], record)
    pd.testing.assert_frame_equal(given, forward, check_exact=True)
    worker.worker_state().close()
    worker._State.instance = None


@pytest.mark.slow
def test_a_file_that_cannot_be_read_is_left_out_of_the_scenes_and_named(concave, tmp_path):
    """One file in the folder that is no mesh (random bytes named .stl): the scenes draw from the
    other objects and are labelled, the summary names the file and why, and the run ends with
    exit 1 (some failed), not with every scene refused."""
    objs = tmp_path / "objs"
    shutil.copytree(concave, objs)
    (objs / "broken.stl").write_bytes(np.random.default_rng(0).bytes(2000))
    out = tmp_path / "labels"
    args = ["--scenes", 2, "--per-scene", 2, "--n", SCENE_CHUNK_SIZE, "--workers", 1]
    result = run_annotate("--objects", objs, "--out", out, *args, check=1)
    assert "broken" in result.output and "not an STL mesh" in result.output
    labels = _labels(out)
    assert sorted(labels["scene_id"].unique()) == [0, 1]
    assert labels.groupby("scene_id").size().tolist() == [SCENE_CHUNK_SIZE, SCENE_CHUNK_SIZE]
    assert "broken" not in set(labels["object_id"])
    assert "broken" in json.loads((out / MANIFEST_NAME).read_text())["objects_failed"]


# One triangle: an OBJ of the right size and header (the main process's checks pass) that no
# worker can load (degenerate: nothing to weigh or grasp).
ONE_TRIANGLE = "v 0 0 0\nv 0.05 0 0\nv 0 0.05 0\nf 1 2 3\n"


@pytest.mark.slow
def test_an_object_no_worker_can_load_fails_only_the_scenes_that_draw_it_named_once(tmp_path):
    """A degenerate mesh in the folder of a scene run: the scene that draws it fails, the object is
    named once (one line in the summary, one entry in the manifest, listing the scene), the other
    scene is labelled, and a re-run resumes it and fails the same scene again."""
    objs = tmp_path / "objs"
    objs.mkdir()
    shutil.copy(REPO / "objects" / "box.obj", objs)  # boxes stay on the table (a can may roll off)
    (objs / "flat.obj").write_text(ONE_TRIANGLE)
    pool = ["box", "flat"]

    def draws_flat(seed: int, scene: int) -> bool:
        spec = scene_records.SceneSpec(scene, seed, "pile", 2, 2)
        return "flat" in draw_objects(spec, pool, keyed_rng("scene", seed, scene))

    seed = next(s for s in range(100) if draws_flat(s, 0) and not draws_flat(s, 1))
    out = tmp_path / "labels"
    args = ["--objects", objs, "--out", out, "--scenes", 2, "--per-scene", 2, "--n", 5, "--seed", seed]
    for attempt in range(2):  # the run, then its re-run
        result = run_annotate(*args, "--workers", 1, check=1)
        failed = [line for line in result.output.splitlines() if "FAILED" in line]
        assert len(failed) == 1 and failed[0].startswith("flat "), result.output
        assert "degenerate mesh" in failed[0] and "scene_000000" in failed[0]
        (done,) = [line for line in result.output.splitlines() if line.startswith("scene_000001 ")]
        assert done.endswith("earlier") == (attempt == 1), result.output
        manifest = json.loads((out / MANIFEST_NAME).read_text())
        assert sorted(manifest["objects_failed"]) == ["flat", "scene_000000"]
        assert "flat" in manifest["objects_failed"]["scene_000000"]
        assert list(manifest["objects_done"]) == ["scene_000001"]
        labels = _labels(out)
        assert labels["scene_id"].tolist() == [1] * 5 and "flat" not in set(labels["object_id"])


@pytest.mark.slow
def test_scene_labels_and_views_are_identical_on_any_worker_count(concave, views_config, reference, tmp_path):
    """Two workers give the one-worker run's labels and view files, bit for bit; the loaders read
    the scene table and a scene's labels back from the run."""
    two = tmp_path / "w2"
    run_annotate(
        "--objects", concave, "--out", two, "--workers", 2, "--quiet", *SCENE_ARGS, "--config", views_config
    )
    labels = _labels(reference)
    pd.testing.assert_frame_equal(_labels(two), labels, check_exact=True)
    assert _artifacts(reference) and _artifacts(two) == _artifacts(reference)
    assert sorted(labels["scene_id"].unique()) == [0, 1]
    assert labels.groupby("scene_id").size().tolist() == [N, N]

    # the loaders: the scene table from the scenes' artifacts, a scene's labels
    scenes = load_scenes(reference)
    assert list(scenes.columns) == list(scene_records.SCENE_COLUMNS)
    assert sorted(scenes["scene_id"].unique()) == [0, 1]
    for scene_id, rows in labels.groupby("scene_id"):
        kept = scenes[(scenes.scene_id == scene_id) & (scenes.status == "kept")]
        assert set(rows["instance_id"]) == set(kept["instance_id"])
        one = scene_labels(reference, int(scene_id))
        pd.testing.assert_frame_equal(
            one.reset_index(drop=True), rows.reset_index(drop=True), check_exact=True
        )
    manifest = json.loads((reference / MANIFEST_NAME).read_text())
    assert "scenes" in manifest["run"]["config"] and manifest["run"]["inputs"]["scenes"]["per_scene"] == [
        3,
        4,
    ]


def _cli_subprocess(objs: Path, out: Path, config: Path) -> subprocess.Popen:
    """The reference's command (SCENE_ARGS, one worker) in a process of its own."""
    cmd = [sys.executable, "-c", "from annotator.cli import annotate_main; annotate_main()"]
    cmd += ["--objects", str(objs), *map(str, SCENE_ARGS), "--config", str(config)]
    cmd += ["--workers", "1", "--out", str(out), "--quiet"]
    return subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=dict(os.environ),
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


@pytest.mark.slow
def test_a_run_interrupted_mid_scene_resumes_bit_for_bit(concave, views_config, reference, tmp_path):
    """Ctrl-C once the first span of the first scene is on disk; the same command labels only the
    rest, the scene's later span from the record its first span left (no settling again), and the
    labels and views equal an uninterrupted run's (the reference)."""
    out = tmp_path / "interrupted"
    proc = _cli_subprocess(concave, out, views_config)
    try:
        deadline = time.monotonic() + 300  # a guard against a hang only (a loaded machine is slow)
        while not list(out.glob("scene_*.parquet")):
            assert proc.poll() is None, f"finished before the first file:\n{proc.communicate()}"
            assert time.monotonic() < deadline, "no label file after 300 s"
            time.sleep(0.02)
        proc.send_signal(signal.SIGINT)
        _, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130, (proc.returncode, stderr)
    chunk = [p for p in out.glob("scene_000000-*.parquet") if ".000000-" in p.name]
    assert chunk, sorted(p.name for p in out.iterdir())
    partial = pd.read_parquet(chunk[0])
    assert sorted(partial["grasp_id"]) == list(range(SCENE_CHUNK_SIZE))

    proc = _cli_subprocess(concave, out, views_config)
    stdout, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 0, stderr
    manifest = json.loads((out / MANIFEST_NAME).read_text())
    assert manifest["chunks_done"] == {} and len(manifest["objects_done"]) == 2
    resumed = _labels(out)
    pd.testing.assert_frame_equal(resumed, _labels(reference), check_exact=True)
    assert _artifacts(out) == _artifacts(reference)
    assert np.isfinite(resumed["disturbance"]).all()


@pytest.mark.slow
@pytest.mark.cluster
def test_scene_labels_on_a_dask_cluster_equal_local_ones(concave, views_config, reference, tmp_path):
    """The first scene on a Dask cluster (workers with no status folder, the default cache) as
    with one local worker (the reference's scene 0: a scene depends on its id and the seed, not on
    how many scenes the run has), bit for bit, views included."""
    distributed = pytest.importorskip("dask.distributed")
    one = ["--scenes", 1, *SCENE_ARGS[2:], "--config", views_config, "--quiet"]
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as c:
        run_annotate(
            "--objects", concave, "--out", tmp_path / "dask", "--scheduler", c.scheduler_address, *one
        )
    local = _labels(reference)
    local = local[local["scene_id"] == 0].reset_index(drop=True)
    pd.testing.assert_frame_equal(_labels(tmp_path / "dask"), local, check_exact=True)
    first = {k: v for k, v in _artifacts(reference).items() if k.startswith("_views/scene_000000")}
    assert first and _artifacts(tmp_path / "dask") == first
