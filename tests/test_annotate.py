"""End-to-end tests of the ``annotate`` command: real physics, small samples, no mocks.

Every run here goes through the click command (in process with CliRunner, or as a real
subprocess where signals are involved) and checks what a user gets: exit codes, the printed
summary, the Parquet labels (docs/labels.md), the manifest, resume and Ctrl-C safety.
Objects are small convex primitives written into tmp dirs (no CoACD decomposition) or convex
sample objects copied from ``objects/``.
"""

from __future__ import annotations

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
import trimesh
from click.testing import CliRunner
from helpers import run_annotate

from annotator.cli import annotate_command, main
from annotator.config import AnnotatorConfig
from annotator.dataset import OUTCOMES, load_labels
from annotator.objects import ObjectSource, load_object
from annotator.rng import object_rng
from annotator.sampler import sample_candidates
from annotator.sim.hand import max_width as _max_width
from annotator.store import MANIFEST_NAME
from annotator.store.files import write_labels
from annotator.store.names import chunk_filename

REPO = Path(__file__).resolve().parents[1]
SAMPLES = REPO / "objects"

DTYPES = {
    "grasp_id": "int64",
    "x": "float64",
    "y": "float64",
    "z": "float64",
    "qx": "float64",
    "qy": "float64",
    "qz": "float64",
    "qw": "float64",
    "width": "float64",
    "success": "bool",
    "score": "float64",
    "object_scale": "float64",
    "seed": "int64",
}
STRING_COLUMNS = ("object_id", "outcome", "mesh_sha256")


# --- helpers -----------------------------------------------------------------------------------


@pytest.fixture(scope="module", autouse=True)
def _cache_dir(tmp_path_factory):
    """Decomposition cache in a tmp dir, set before any run (and inherited by worker processes)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("RG2_CACHE_DIR", str(tmp_path_factory.mktemp("rg2-cache")))
        yield


def _primitives(folder: Path, which: tuple[str, ...] = ("box", "cylinder")) -> Path:
    """Small convex objects (metres) written into ``folder``; returns ``folder``."""
    makers = {
        "box": lambda: trimesh.creation.box((0.05, 0.04, 0.10)),
        "cylinder": lambda: trimesh.creation.cylinder(radius=0.03, height=0.09, sections=24),
        "slab": lambda: trimesh.creation.box((0.08, 0.03, 0.06)),
        "capsule": lambda: trimesh.creation.capsule(height=0.06, radius=0.025, count=(12, 12)),
    }
    folder.mkdir(parents=True, exist_ok=True)
    for name in which:
        makers[name]().export(folder / f"{name}.obj")
    return folder


def _sorted(df: pd.DataFrame) -> pd.DataFrame:
    return df.sort_values(["object_id", "grasp_id"], kind="stable").reset_index(drop=True)


def _labels(out: Path) -> pd.DataFrame:
    return _sorted(pd.read_parquet(out))


def _manifest(out: Path) -> dict:
    return json.loads((out / MANIFEST_NAME).read_text())


@pytest.fixture(scope="module")
def two_objects(tmp_path_factory) -> Path:
    return _primitives(tmp_path_factory.mktemp("objs"), ("box", "cylinder"))


N_SMALL = 14  # two spans per object (CHUNK_SIZE 10): chunk files, their merge, uneven spans


@pytest.fixture(scope="module")
def reference_run(two_objects, tmp_path_factory) -> tuple[Path, str]:
    """The local single-worker run every other run is compared against: (out dir, output)."""
    out = tmp_path_factory.mktemp("ref") / "labels"
    result = run_annotate("--objects", two_objects, "--n", N_SMALL, "--workers", 1, "--out", out, "--quiet")
    return out, result.output


# --- 1. happy path -------------------------------------------------------------------------------


@pytest.mark.slow
def test_labels_have_the_contract_schema_and_values(two_objects, reference_run):
    out, output = reference_run
    df = _labels(out)

    assert sorted(df["object_id"].unique()) == ["box", "cylinder"]
    assert df.groupby("object_id").size().to_dict() == {"box": N_SMALL, "cylinder": N_SMALL}
    for oid, g in df.groupby("object_id"):
        assert g["grasp_id"].tolist() == list(range(N_SMALL)), oid
    for col, dtype in DTYPES.items():
        assert str(df[col].dtype) == dtype, (col, df[col].dtype)
    for col in STRING_COLUMNS:
        assert pd.api.types.is_string_dtype(df[col]), (col, df[col].dtype)
        assert df[col].map(lambda v: isinstance(v, str)).all(), col

    assert set(df["outcome"]) <= set(OUTCOMES)
    assert (df["success"] == (df["outcome"] == "success")).all()
    assert (df["score"] == df["success"].astype(float)).all()  # K = 1
    q = df[["qx", "qy", "qz", "qw"]].to_numpy()
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-9)
    assert np.isfinite(df[["x", "y", "z", "width"]].to_numpy()).all()
    assert (df["object_scale"] == 1.0).all()
    assert (df["seed"] == 0).all()
    assert (df["mesh_sha256"].str.fullmatch(r"[0-9a-f]{64}")).all()
    assert df.groupby("object_id")["mesh_sha256"].nunique().eq(1).all()
    # a box 40 mm across and a 60 mm can are graspable by a 110 mm gripper: some successes
    assert df["success"].any(), df[["object_id", "outcome"]]

    # collision rows: the candidate pose unchanged and the open width (never simulated)
    config = AnnotatorConfig()
    max_width = _max_width(config)
    clearance = config.protocol.pregrasp_clearance
    for oid, g in df.groupby("object_id"):
        model = load_object(ObjectSource(oid, two_objects / f"{oid}.obj"), config.objects)
        cands = sample_candidates(model.mesh, N_SMALL, object_rng(0, oid), config.sampler, max_width)
        for row in g[g["outcome"] == "collision"].itertuples():
            open_width = min(max_width, cands.width_expected[row.grasp_id] + 2 * clearance)
            assert row.width == pytest.approx(open_width, abs=1e-12)
            assert 0 < row.width <= max_width + 1e-9
            np.testing.assert_allclose(
                [row.x, row.y, row.z], cands.T_obj_tcp[row.grasp_id][:3, 3], atol=1e-12
            )
    # every simulated row has a width the RG2 can reach
    assert ((df["width"] >= 0) & (df["width"] <= max_width + 1e-6)).all()

    # the loader's validation accepts it and returns the same rows
    pd.testing.assert_frame_equal(load_labels(out), df, check_exact=True)

    manifest = _manifest(out)
    assert sorted(manifest["objects_done"]) == ["box", "cylinder"]
    assert manifest["objects_failed"] == {}
    assert {v["n"] for v in manifest["objects_done"].values()} == {N_SMALL}
    assert manifest["run"]["seed"] == 0 and manifest["run"]["n"] == N_SMALL and manifest["run"]["trials"] == 1
    # the summary names each object and the totals
    assert "box" in output and "cylinder" in output
    assert "2 objects labelled, 0 done earlier, 0 failed" in output
    header = next(line for line in output.splitlines() if line.startswith("object"))
    for column in ("rate", "score", *OUTCOMES):  # whole names, not cut to nine characters
        assert f" {column} " in f"{header} ", (column, header)


# --- 2., 3. the same labels whatever runs them ---------------------------------------------------


@pytest.mark.slow
def test_labels_do_not_depend_on_workers(two_objects, reference_run, tmp_path):
    out2 = tmp_path / "w2"
    run_annotate("--objects", two_objects, "--n", N_SMALL, "--workers", 2, "--out", out2, "--quiet")
    pd.testing.assert_frame_equal(_labels(out2), _labels(reference_run[0]), check_exact=True)


@pytest.mark.slow
@pytest.mark.cluster
def test_dask_cluster_gives_the_same_labels(two_objects, reference_run, tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    out = tmp_path / "dask"
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        run_annotate(
            "--objects",
            two_objects,
            "--n",
            N_SMALL,
            "--scheduler",
            cluster.scheduler_address,
            "--out",
            out,
            "--quiet",
        )
    pd.testing.assert_frame_equal(_labels(out), _labels(reference_run[0]), check_exact=True)


@pytest.mark.slow
@pytest.mark.cluster
def test_unreachable_scheduler_is_a_usage_error(two_objects, tmp_path):
    dask = pytest.importorskip("dask")
    pytest.importorskip("dask.distributed")
    with dask.config.set({"distributed.comm.timeouts.connect": "2s"}):
        result = run_annotate(
            "--objects",
            two_objects,
            "--n",
            2,
            "--scheduler",
            "tcp://127.0.0.1:1",
            "--out",
            tmp_path / "out",
            "--quiet",
            check=2,
        )
    assert "--scheduler" in result.output and "tcp://127.0.0.1:1" in result.output
    assert "Traceback" not in result.output


# --- robust labels ----------------------------------------------------------------------------------


def test_trials_add_a_score_and_keep_the_nominal_labels(two_objects, reference_run, tmp_path):
    objs = tmp_path / "objs"
    objs.mkdir()
    shutil.copy(two_objects / "box.obj", objs)
    out = tmp_path / "out"
    result = run_annotate("--objects", objs, "--n", N_SMALL, "--workers", 1, "--trials", 2, "--out", out)
    robust = _labels(out)
    # the summary counts the candidates that ran physics and says each ran both trials
    tried = int((robust["outcome"] != "collision").sum())
    assert f"candidates/s, {tried} past the kinematic check, 2 trials each)" in result.output
    nominal = _labels(reference_run[0])
    nominal = nominal[nominal["object_id"] == "box"].reset_index(drop=True)
    assert set(robust["score"]) <= {0.0, 0.5, 1.0}
    # trial 0 is the unperturbed one: outcome, pose and width are those of the K = 1 run
    same = ["object_id", "grasp_id", *"x y z qx qy qz qw".split(), "width", "success", "outcome"]
    pd.testing.assert_frame_equal(robust[same], nominal[same], check_exact=True)
    assert _manifest(out)["run"]["trials"] == 2
    # a different K is another run: resuming it into the same folder needs --overwrite
    result = run_annotate("--objects", objs, "--n", N_SMALL, "--trials", 3, "--out", out, check=2)
    assert "--overwrite" in result.output


# --- 4. an object wider than the stroke -------------------------------------------------------------


def test_too_wide_object_never_succeeds(tmp_path):
    objs = tmp_path / "objs"
    objs.mkdir()
    shutil.copy(SAMPLES / "big_ball.obj", objs)
    out = tmp_path / "out"
    run_annotate("--objects", objs, "--n", 6, "--workers", 1, "--out", out, "--quiet")
    df = _labels(out)
    assert len(df) == 6 and set(df["object_id"]) == {"big_ball"}
    assert not df["success"].any(), df["outcome"].value_counts()
    assert (df["score"] == 0).all()


# --- 5. bad inputs ----------------------------------------------------------------------------------


def test_missing_objects_folder_is_a_usage_error(tmp_path):
    missing = tmp_path / "no_such_folder"
    result = run_annotate("--objects", missing, "--n", 2, "--out", tmp_path / "out", check=2)
    assert "no_such_folder" in result.output


def test_empty_objects_folder_is_a_usage_error(tmp_path):
    empty = tmp_path / "empty_folder"
    empty.mkdir()
    result = run_annotate("--objects", empty, "--n", 2, "--out", tmp_path / "out", check=2)
    assert "no objects" in result.output and "empty_folder" in result.output


def _write_bad_objects(folder: Path) -> dict[str, tuple[str, ...]]:
    """Broken meshes beside good ones; returns object_id -> words one of which the reason names."""
    (folder / "empty.obj").write_bytes(b"")
    (folder / "notes.obj").write_text("hello\n")
    nan = trimesh.creation.box((0.05, 0.05, 0.05))
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in nan.vertices]
    lines[0] = "v nan 0.0 0.0"
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in nan.faces]
    (folder / "nan.obj").write_text("\n".join(lines) + "\n")
    trimesh.creation.box((50.0, 50.0, 50.0)).export(folder / "millimetres.obj")  # a 50 mm box in mm
    # a flat 10 x 10 grid of triangles: many faces, zero volume
    u, v = np.meshgrid(np.linspace(0, 0.05, 10), np.linspace(0, 0.05, 10))
    verts = np.column_stack([u.ravel(), v.ravel(), np.zeros(u.size)])
    faces = []
    for i in range(9):
        for j in range(9):
            a = i * 10 + j
            faces += [(a, a + 1, a + 10), (a + 1, a + 11, a + 10)]
    trimesh.Trimesh(verts, np.array(faces), process=False).export(folder / "flat.obj")
    return {
        "empty": ("empty",),
        "notes": ("not a readable mesh", "not a mesh", "no triangles"),
        "nan": ("nan",),
        "millimetres": ("millimetres",),
        "flat": ("degenerate", "zero volume", "flat"),
    }


def test_bad_objects_fail_alone_with_a_reason(tmp_path):
    objs = _primitives(tmp_path / "objs", ("box",))
    expected = _write_bad_objects(objs)
    out = tmp_path / "out"
    # 12 candidates: two spans per object, so each bad object fails in two workers' tasks
    result = run_annotate("--objects", objs, "--n", 12, "--workers", 2, "--out", out, "--quiet", check=1)

    df = _labels(out)
    assert set(df["object_id"]) == {"box"} and len(df) == 12
    manifest = _manifest(out)
    assert sorted(manifest["objects_done"]) == ["box"]
    assert sorted(manifest["objects_failed"]) == sorted(expected)
    summary_lines = result.output.splitlines()
    for oid, words in expected.items():
        reason = manifest["objects_failed"][oid]
        assert "\n" not in reason and reason.strip()
        assert any(w in reason.lower() for w in words), (oid, reason)
        line = [ln for ln in summary_lines if ln.startswith(oid) and "FAILED" in ln]
        assert line, f"{oid} missing from the summary:\n{result.output}"
        assert any(w in line[0].lower() for w in words), line[0]
        assert len(line) == 1, line  # reported once, whichever span failed first
    assert "1 objects labelled, 0 done earlier, 5 failed" in result.output
    assert manifest["chunks_done"] == {}  # no chunk of a failed object, and box's merged


def test_millimetre_mesh_is_accepted_with_scale(tmp_path):
    objs = tmp_path / "objs"
    objs.mkdir()
    trimesh.creation.box((50.0, 40.0, 100.0)).export(objs / "mm_box.obj")
    out = tmp_path / "out"
    run_annotate("--objects", objs, "--n", 4, "--workers", 1, "--scale", 0.001, "--out", out, "--quiet")
    df = _labels(out)
    assert len(df) == 4 and (df["object_scale"] == 0.001).all()


# --- 6. resume and overwrite ------------------------------------------------------------------------


def test_resume_skips_done_objects_and_overwrite_starts_over(tmp_path):
    objs = _primitives(tmp_path / "objs", ("box",))
    out = tmp_path / "out"
    args = ["--objects", objs, "--n", 4, "--workers", 1, "--out", out, "--quiet"]
    run_annotate(*args)
    files = sorted(out.glob("*.parquet"))
    assert len(files) == 1
    stamps = {p: p.stat().st_mtime_ns for p in files}
    first = _labels(out)

    again = run_annotate(*args)
    assert "earlier" in again.output and "0 objects labelled, 1 done earlier" in again.output
    assert {p: p.stat().st_mtime_ns for p in sorted(out.glob("*.parquet"))} == stamps
    pd.testing.assert_frame_equal(_labels(out), first)

    other_seed = run_annotate(*args, "--seed", 1, check=2)
    assert "--overwrite" in other_seed.output and "seed" in other_seed.output
    assert {p: p.stat().st_mtime_ns for p in sorted(out.glob("*.parquet"))} == stamps  # untouched

    run_annotate(*args, "--seed", 1, "--overwrite")
    rerun = _labels(out)
    assert len(rerun) == 4 and (rerun["seed"] == 1).all()
    assert _manifest(out)["run"]["seed"] == 1
    assert not rerun[["x", "y", "z"]].equals(first[["x", "y", "z"]])  # a new draw


def test_resume_redoes_chunks_the_manifest_does_not_vouch_for(two_objects, reference_run, tmp_path):
    """Chunk files without a manifest entry (written just before a crash, or of another chunk size)
    never reach the labels: they are deleted and their candidates simulated again."""
    out = tmp_path / "out"
    shutil.copytree(reference_run[0], out)
    manifest = _manifest(out)
    entry = manifest["objects_done"].pop("box")
    (out / entry["file"]).unlink()
    (out / MANIFEST_NAME).write_text(json.dumps(manifest))
    reference = _labels(reference_run[0])
    fake = reference[reference["object_id"] == "box"].copy()
    fake["success"], fake["outcome"] = False, "error"  # wrong on purpose
    stale = [out / chunk_filename("box", 0, 10), out / chunk_filename("box", 10, 13)]
    key, source, run_id = manifest["run_key"], entry["source_sha256"], manifest["run_id"]
    # as if this folder's run was killed after writing them and before recording them
    write_labels(out, fake.iloc[0:10], 0, 10, stale[0].name, key, source, run_id=run_id)
    write_labels(out, fake.iloc[10:13], 10, 13, stale[1].name, key, source, run_id=run_id)
    assert all(p.exists() for p in stale)

    result = run_annotate("--objects", two_objects, "--n", N_SMALL, "--workers", 1, "--out", out, "--quiet")
    assert "1 objects labelled, 1 done earlier" in result.output
    assert f"{N_SMALL} candidates simulated in" in result.output  # box redone whole, cylinder kept
    assert not any(p.exists() for p in stale)
    pd.testing.assert_frame_equal(_labels(out), reference, check_exact=True)


# --- 7. Ctrl-C ----------------------------------------------------------------------------------------


N_LONG = 25  # three spans per object: an interrupt lands between chunk files
LONG_OBJECTS = ("box", "cylinder", "slab")


def _cli_subprocess(objs: Path, out: Path) -> subprocess.Popen:
    cmd = [sys.executable, "-c", "from annotator.cli import annotate_main; annotate_main()"]
    cmd += ["--objects", str(objs), "--n", str(N_LONG), "--workers", "2", "--out", str(out), "--quiet"]
    return subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=dict(os.environ),
        cwd=objs.parent,
        # Ctrl-C as a terminal delivers it: a shell starts background jobs (`pytest &`, nohup)
        # with SIGINT ignored, children inherit that and Python then never raises
        # KeyboardInterrupt, so the run would (rightly) ignore the signal
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


def _span_of(path: Path) -> tuple[int, int] | None:
    """(start, stop) of a chunk file ``<object>.SSSSSS-EEEEEE.parquet``; None for an object file."""
    name = path.name[: -len(".parquet")]
    head, _, tail = name.rpartition(".")
    if not head or "-" not in tail:
        return None
    start, stop = tail.split("-")
    return int(start), int(stop)


@pytest.mark.slow
def test_ctrl_c_leaves_whole_files_and_resume_completes(tmp_path):
    objs = _primitives(tmp_path / "objs", LONG_OBJECTS)
    out = tmp_path / "interrupted"
    proc = _cli_subprocess(objs, out)
    try:
        deadline = time.monotonic() + 90
        while not list(out.glob("*.parquet")):
            assert proc.poll() is None, f"finished before the first file:\n{proc.communicate()}"
            assert time.monotonic() < deadline, "no label file after 90 s"
            time.sleep(0.02)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130, (proc.returncode, stderr)
    assert "Traceback" not in stderr, stderr
    assert "re-run" in stderr

    # only whole files: object files with N rows, chunk files with exactly their span's grasps
    files = sorted(out.glob("*.parquet"))
    assert files
    for p in files:
        got = pd.read_parquet(p)
        span = _span_of(p)
        want = range(N_LONG) if span is None else range(*span)
        assert sorted(got["grasp_id"]) == list(want), p.name
    assert not [p.name for p in out.iterdir() if p.name.endswith(".tmp")]
    partial = _labels(out)
    assert not partial.duplicated(["object_id", "grasp_id"]).any()
    assert len(partial) < N_LONG * len(LONG_OBJECTS)  # interrupted part-way
    # the manifest lists what it knows to be whole (SIGINT may land between a file and its entry)
    manifest = _manifest(out)
    names = {p.name for p in files}
    kept = 0
    for oid, entry in manifest["objects_done"].items():
        assert entry["file"] in names, oid
        kept += N_LONG
    for oid, entry in manifest["chunks_done"].items():
        for key, rec in entry["files"].items():
            assert rec["file"] in names, (oid, key)
            start, stop = map(int, key.split("-"))
            kept += stop - start

    # the same command again simulates only what is missing and finishes the job
    proc = _cli_subprocess(objs, out)
    stdout, stderr = proc.communicate(timeout=180)
    assert proc.returncode == 0, stderr
    assert f"{N_LONG * len(LONG_OBJECTS) - kept} candidates simulated in" in stdout, (kept, stdout)
    final = list(out.glob("*.parquet"))  # one file per object: every chunk merged and removed
    assert len(final) == len(LONG_OBJECTS) and all(_span_of(p) is None for p in final), final
    resumed = _labels(out)

    fresh = tmp_path / "fresh"
    run_annotate("--objects", objs, "--n", N_LONG, "--workers", 2, "--out", fresh, "--quiet")
    expected = _labels(fresh)
    assert not resumed.duplicated(["object_id", "grasp_id"]).any()
    assert resumed.groupby("object_id").size().to_dict() == dict.fromkeys(LONG_OBJECTS, N_LONG)
    pd.testing.assert_frame_equal(resumed, expected, check_exact=True)
    assert _manifest(out)["chunks_done"] == {}


# --- 8. help ------------------------------------------------------------------------------------------


def test_annotate_help_lists_the_options():
    result = CliRunner().invoke(annotate_command, ["--help"])
    assert result.exit_code == 0
    for opt in (
        "--objects",
        "--n",
        "--out",
        "--workers",
        "--seed",
        "--trials",
        "--scheduler",
        "--overwrite",
        "--config",
        "--quiet",
    ):
        assert opt in result.output, opt


def test_annotator_help_lists_the_subcommands():
    result = CliRunner().invoke(main, ["--help"])
    assert result.exit_code == 0
    commands = result.output.split("Commands:")[1]
    assert "annotate" in commands and "scene" in commands


def test_console_scripts_run_as_processes():
    """The installed ``annotate`` and ``annotator`` scripts, as a user types them."""
    bindir = Path(sys.executable).parent
    for script, args in (("annotate", ["--help"]), ("annotator", ["annotate", "--help"])):
        exe = shutil.which(script, path=str(bindir)) or shutil.which(script)
        if exe is None:
            pytest.skip(f"console script {script!r} not installed")
        proc = subprocess.run([exe, *args], capture_output=True, text=True, timeout=60)
        assert proc.returncode == 0, proc.stderr
        assert "--objects" in proc.stdout


def test_no_pybullet_banner_in_the_output():
    """pybullet prints its build time on import; every worker would add one to the progress bar."""
    proc = subprocess.run(
        [sys.executable, "-c", "import annotator.sim.world, pybullet; print('imported')"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "imported"
    assert "build time" not in proc.stderr + proc.stdout
    # every command imports its modules (scene, cell, tools) for --help: none may print it either
    code = "from annotator.cli import main; main()"
    proc = subprocess.run([sys.executable, "-c", code, "--help"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and "Commands:" in proc.stdout, proc.stderr
    assert "build time" not in proc.stderr + proc.stdout
