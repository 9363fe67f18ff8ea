"""A user's gripper as a hostile or careless user writes it: each fault below is refused in one
line before any work (or, for an edit made during a run, cannot reach the workers)."""

from __future__ import annotations

import os
import shutil
import struct
from pathlib import Path

import numpy as np
import pybullet as pb
import pytest
import trimesh
from gripper_helpers import description_error, edit
from helpers import run_annotate

from annotator.grippers import GripperFiles, gripper_dir, load_gripper, resolve_gripper
from annotator.grippers.meshes import MAX_MESH_BYTES, MAX_MESH_FACES

PAD_BOX = '<geometry><box size="0.011450 0.020200 0.029800"/></geometry>'
PAD_SIZE = (0.01145, 0.0202, 0.0298)
REPO = Path(__file__).resolve().parents[1]


def _mesh_pads(folder: Path, name: str = "pad.obj") -> None:
    """Both pads' collision boxes become mesh ``name``, their size stated in the TOML."""
    edit(folder / "rg2.urdf", PAD_BOX, f'<geometry><mesh filename="{name}"/></geometry>', 2)
    edit(folder / "gripper.toml", "[pads]\n", f"[pads]\nsize = {list(PAD_SIZE)}\n")


# --- numbers: finite and in range ----------------------------------------------------------------------

NUMBER_BREAKS = [
    ("default = 40.0", "default = inf", "[force] default: expected a finite number, got inf"),
    ("max = 40.0", "max = 4e9", "[force] max 4e+09 N is beyond any parallel gripper's"),
    ("close_speed = 1.0", "close_speed = inf", "[drive] close_speed: expected a finite number, got inf"),
    ("close_speed = 1.0", "close_speed = 1e6", "[drive] close_speed must be in (0, 10]"),
    ("close_speed = 1.0", "close_speed = nan", "[drive] close_speed: expected a finite number, got nan"),
    ("xyz = [0.0, 0.0, 0.0]", "xyz = [0.0, nan, 0.0]", "[mount] xyz: expected three finite numbers"),
    ("xyz = [0.0, 0.0, 0.0]", "xyz = [0.0, 0.0, 40.0]", "[mount] xyz [0.0, 0.0, 40.0]: each must be within"),
    ("rpy = [0.0, 0.0, 0.0]", "rpy = [0.0, 0.0, -inf]", "[mount] rpy: expected three finite numbers"),
    ("max = 0.110", "max = 1e300", "[stroke] max 1e+300 m is beyond any parallel gripper's"),
    ("lateral_friction = 1.0", "lateral_friction = inf", "[pads] lateral_friction: expected a finite number"),
]


@pytest.mark.parametrize("old, new, fragment", NUMBER_BREAKS)
def test_a_number_out_of_range_or_not_finite_is_one_line(my_rg2, old, new, fragment):
    edit(my_rg2 / "gripper.toml", old, new)
    assert fragment in description_error(my_rg2)


def test_a_nan_in_the_urdf_is_one_line(my_rg2):
    origin = '<origin xyz="-0.017000 0.000000 0.110000"'
    edit(my_rg2 / "rg2.urdf", origin, origin.replace("0.000000", "nan"))
    assert "expected 3 finite numbers" in description_error(my_rg2)


# --- masses, inertias and inertial origins: a body's ----------------------------------------------------

HOUSING_MASS = '<mass value="0.631500"/>'
INERTIAL_BREAKS = [
    (HOUSING_MASS, '<mass value="-1"/>', "link 'rg2_base_link': mass -1 kg: must be a finite number > 0"),
    ('<mass value="0.015000"/>', '<mass value="-1"/>', "link 'gripper_finger1_knuckle_link': mass -1 kg"),
    (HOUSING_MASS, '<mass value="nan"/>', "link 'rg2_base_link': mass nan kg"),
    (HOUSING_MASS, '<mass value="0"/>', "link 'rg2_base_link': mass 0 kg"),
    ('ixx="1.1785e-03"', 'ixx="nan"', "link 'rg2_base_link': inertia ixx nan"),
    ('izz="2.8760e-04"', 'izz="-1e-4"', "principal moments must all be > 0"),
    ('izz="2.8760e-04"', 'izz="5e-3"', "exceeds the sum of the other two"),
    (
        '<inertial><origin xyz="0.000000 0.000000 0.053795"/>',
        '<inertial><origin xyz="0.000000 inf 0.053795"/>',
        "link 'rg2_base_link': inertial origin xyz 0 inf 0.053795: must be finite numbers",
    ),
]


@pytest.mark.parametrize("old, new, fragment", INERTIAL_BREAKS)
def test_a_mass_inertia_or_inertial_origin_no_body_has_is_one_line(my_rg2, old, new, fragment):
    edit(my_rg2 / "rg2.urdf", old, new)
    assert fragment in description_error(my_rg2)


def _objects(tmp_path: Path) -> Path:
    objects = tmp_path / "objects"
    objects.mkdir()
    shutil.copy(REPO / "objects" / "box.obj", objects)
    return objects


def test_annotate_refuses_a_gripper_of_negative_mass_before_any_work(my_rg2, tmp_path):
    """It labelled every grasp a failure (0 % against 80 %) and said nothing."""
    edit(my_rg2 / "rg2.urdf", HOUSING_MASS, '<mass value="-1"/>')
    out = tmp_path / "out"
    args = ("--objects", _objects(tmp_path), "--n", 2, "--out", out, "--gripper", my_rg2)
    result = run_annotate(*args, check=2)
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and "link 'rg2_base_link': mass -1 kg" in errors[0]
    assert "Traceback" not in result.output and not out.exists()


def test_a_gripper_that_fails_its_physics_checks_is_refused_before_a_run(my_rg2, tmp_path):
    """A user's gripper whose pads cannot hold the check's box (4 N, friction 0.1): annotate runs
    annotator gripper check's physics first and refuses it in one line naming the verdict."""
    edit(my_rg2 / "gripper.toml", "default = 40.0", "default = 4.0")
    edit(my_rg2 / "gripper.toml", "lateral_friction = 1.0", "lateral_friction = 0.1")
    out = tmp_path / "out"
    args = ("--objects", _objects(tmp_path), "--n", 2, "--out", out, "--gripper", my_rg2)
    result = run_annotate(*args, check=2)
    assert "fails annotator gripper check: FAIL box held through lift and shake" in result.output
    assert "Traceback" not in result.output and not out.exists()


# --- shapes PyBullet loads, of the stated size ---------------------------------------------------------


def test_a_mesh_pad_of_the_stated_size_loads_and_pybullet_sees_that_size(my_rg2):
    trimesh.creation.box(extents=PAD_SIZE).export(my_rg2 / "pad.obj")
    _mesh_pads(my_rg2)
    d = load_gripper(my_rg2)
    assert ("pad.obj", (my_rg2 / "pad.obj").read_bytes()) in d.files
    client = pb.connect(pb.DIRECT)
    try:
        uid = pb.loadURDF(str(d.urdf), useFixedBase=True, physicsClientId=client)
        count = pb.getNumJoints(uid, physicsClientId=client)
        links = {pb.getJointInfo(uid, j, physicsClientId=client)[12].decode(): j for j in range(count)}
        lo, hi = pb.getAABB(uid, links[d.pad_links[0]], physicsClientId=client)
    finally:
        pb.disconnect(physicsClientId=client)
    # what PyBullet loaded has the stated size: its AABB adds the same collision margin on every side
    grown = np.subtract(sorted(np.subtract(hi, lo)), sorted(PAD_SIZE))
    assert np.ptp(grown) < 1e-5 and 0.0 <= grown[0] < 0.01, grown


@pytest.mark.parametrize(
    "content, fragment",
    [
        (b"", "pad.obj is empty"),
        (np.random.default_rng(0).bytes(4096), "pad.obj holds no face"),
        (b"v 0 0 0\nv 1 0 0\nf 1 2\n", "faces but fewer than three vertices"),
    ],
    ids=["empty", "random-bytes", "two-vertices"],
)
def test_a_pad_mesh_pybullet_would_not_load_is_one_line(my_rg2, content, fragment):
    (my_rg2 / "pad.obj").write_bytes(content)
    _mesh_pads(my_rg2)
    assert fragment in description_error(my_rg2)


def test_a_pad_mesh_of_another_size_than_stated_is_one_line(my_rg2):
    trimesh.creation.box(extents=np.multiply(PAD_SIZE, 1000)).export(my_rg2 / "pad.obj")  # millimetres
    _mesh_pads(my_rg2)
    assert "does not match pad 'gripper_finger1_pad_link''s mesh pad.obj" in description_error(my_rg2)


def test_random_bytes_as_a_finger_stl_are_one_line(my_rg2):
    (my_rg2 / "tip.stl").write_bytes(np.random.default_rng(1).bytes(1000))
    tip = '<geometry><box size="0.003050 0.020200 0.055000"/></geometry>'
    edit(my_rg2 / "rg2.urdf", tip, '<geometry><mesh filename="tip.stl"/></geometry>')
    assert "tip.stl is neither a binary STL" in description_error(my_rg2)


# --- budgets: faces and bytes, checked before reading --------------------------------------------------


def _binary_stl(path: Path, faces: int) -> None:
    """A binary STL of ``faces`` small triangles (written for real)."""
    rng = np.random.default_rng(2)
    records = np.zeros(faces, dtype=[("n", "<f4", 3), ("v", "<f4", 9), ("a", "<u2")])
    records["v"] = rng.uniform(0, 0.01, size=(faces, 9))
    path.write_bytes(b"\0" * 80 + struct.pack("<I", faces) + records.tobytes())


def test_a_mesh_over_the_face_budget_is_refused_with_the_figure(my_rg2):
    _binary_stl(my_rg2 / "tip.stl", MAX_MESH_FACES + 5_000)
    tip = '<geometry><box size="0.003050 0.020200 0.055000"/></geometry>'
    edit(my_rg2 / "rg2.urdf", tip, '<geometry><mesh filename="tip.stl"/></geometry>')
    message = description_error(my_rg2)
    faces = f"{MAX_MESH_FACES + 5_000:,}"
    assert f"the meshes hold {faces} faces (tip.stl: {faces})" in message
    assert f"budget of {MAX_MESH_FACES:,}" in message


@pytest.mark.parametrize("size", [84 + 50 * 2_000_000, 20 * 1024**3], ids=["2M-face-stl", "20GB"])
def test_a_huge_mesh_is_refused_by_its_size_before_it_is_read(my_rg2, size):
    """A sparse file (no disk used): 2 million faces' worth of binary STL, or 20 GB."""
    with open(my_rg2 / "tip.stl", "wb") as f:
        f.truncate(size)
    tip = '<geometry><box size="0.003050 0.020200 0.055000"/></geometry>'
    edit(my_rg2 / "rg2.urdf", tip, '<geometry><mesh filename="tip.stl"/></geometry>')
    message = description_error(my_rg2)
    budget = f"over the gripper's budget of {MAX_MESH_BYTES:,}"
    assert f"the meshes are {size:,} bytes (tip.stl: {size:,}), {budget}" in message


# --- paths: inside the folder only ---------------------------------------------------------------------


def test_mesh_paths_outside_the_folder_are_refused_in_one_line(my_rg2, tmp_path):
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    trimesh.creation.box(extents=PAD_SIZE).export(outside / "pad.obj")
    (my_rg2 / "linked").symlink_to(outside, target_is_directory=True)
    cases = {
        "/etc/passwd": "references /etc/passwd: an absolute path",
        "../elsewhere/pad.obj": "references ../elsewhere/pad.obj lies outside the gripper's folder",
        "linked/pad.obj": "references linked/pad.obj lies outside the gripper's folder",
        "package://rg2/pad.obj": "package:// is not resolved",
    }
    _mesh_pads(my_rg2, "MESH")
    urdf = (my_rg2 / "rg2.urdf").read_text()
    for name, fragment in cases.items():
        (my_rg2 / "rg2.urdf").write_text(urdf.replace("MESH", name))
        assert fragment in description_error(my_rg2), name
    edit(my_rg2 / "gripper.toml", 'urdf = "rg2.urdf"', 'urdf = "../elsewhere/rg2.urdf"')
    assert "urdf ../elsewhere/rg2.urdf lies outside the gripper's folder" in description_error(my_rg2)


def test_a_urdf_nested_200000_deep_is_one_line(my_rg2):
    edit(my_rg2 / "rg2.urdf", "</robot>", "<x>" * 200_000 + "</x>" * 200_000 + "</robot>")
    assert "elements nested more than 32 deep: not a URDF" in description_error(my_rg2)


def test_an_entity_declaration_is_one_line(my_rg2):
    text = (my_rg2 / "rg2.urdf").read_text()
    lol = '<!DOCTYPE r [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;">]>'
    (my_rg2 / "rg2.urdf").write_text(text.replace("<robot", lol + "<robot", 1))
    assert "a DOCTYPE or ENTITY declaration is not accepted" in description_error(my_rg2)


def test_a_bad_gripper_on_the_command_line_is_one_line_and_exit_2(my_rg2, tmp_path):
    _mesh_pads(my_rg2, "/etc/passwd")
    objects = tmp_path / "objects"
    objects.mkdir()
    shutil.copy(REPO / "objects" / "box.obj", objects)
    out = tmp_path / "out"
    result = run_annotate("--objects", objects, "--n", 2, "--out", out, "--gripper", my_rg2, check=2)
    assert "references /etc/passwd: an absolute path" in result.output
    assert "Traceback" not in result.output and not (tmp_path / "out").exists()


# --- names: a shipped gripper's name is its own --------------------------------------------------------


def test_a_shipped_name_on_another_model_is_refused_but_a_copy_keeps_it(tmp_path):
    copy = tmp_path / "rg2_copy"
    shutil.copytree(gripper_dir("rg2"), copy)
    assert load_gripper(copy).digest == load_gripper("rg2").digest  # the same files: the same gripper
    edit(copy / "gripper.toml", "default = 40.0", "default = 30.0")
    assert "name 'rg2' is a shipped gripper's and this model is another" in description_error(copy)
    other = tmp_path / "not_panda"
    shutil.copytree(gripper_dir("rg2"), other)
    edit(other / "gripper.toml", 'name = "rg2"', 'name = "panda"')
    assert "name 'panda' is a shipped gripper's" in description_error(other)


def test_a_description_loads_without_a_physics_client(my_rg2, monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("a physics client was opened to load a description")

    monkeypatch.setattr(pb, "connect", refuse)
    assert load_gripper(my_rg2).name == "my_rg2"


# --- frozen: the workers simulate the files the run read -----------------------------------------------


def test_a_worker_gets_the_files_read_at_the_start_not_the_edited_folder(my_rg2, tmp_path):
    run = load_gripper(my_rg2)  # the main process reads the folder once
    before = (my_rg2 / "rg2.urdf").read_bytes()
    edit(my_rg2 / "rg2.urdf", PAD_BOX, '<geometry><box size="0.011450 0.020200 0.002000"/></geometry>', 2)
    worker = resolve_gripper(run, tmp_path / "cache")  # a worker starting (or restarting) after the edit
    assert worker.digest == run.digest and worker.folder == tmp_path / "cache" / "grippers" / run.digest
    assert worker.urdf.read_bytes() == before
    assert GripperFiles.of(run).files == run.files  # never read again
    assert resolve_gripper(load_gripper("rg2"), tmp_path / "cache").folder == gripper_dir("rg2")


@pytest.mark.slow
def test_a_gripper_edited_before_the_workers_start_gives_the_clean_labels(my_rg2, tmp_path, monkeypatch):
    """Two loky workers start after the user's URDF was edited (a restarted worker is the same
    case): every row is the clean run's, bit for bit."""
    import pandas as pd

    from annotator.config import AnnotatorConfig
    from annotator.pipeline.run import RunOptions, run

    objects = tmp_path / "objects"
    objects.mkdir()
    shutil.copy(REPO / "objects" / "box.obj", objects)
    monkeypatch.setenv("RG2_CACHE_DIR", str(tmp_path / "cache"))
    clean = tmp_path / "clean"
    run_annotate("--objects", objects, "--n", 12, "--out", clean, "--workers", 1, "--gripper", my_rg2, "-q")
    description = load_gripper(my_rg2)
    # the pads become 2 mm tall slivers: a worker reading the folder would label another gripper
    edit(my_rg2 / "rg2.urdf", PAD_BOX, '<geometry><box size="0.011450 0.020200 0.002000"/></geometry>', 2)
    edited = tmp_path / "edited"
    options = RunOptions(objects, 12, edited, workers=2, quiet=True, gripper=description)
    run(options, AnnotatorConfig())
    key = ["object_id", "grasp_id"]
    pd.testing.assert_frame_equal(
        pd.read_parquet(edited).sort_values(key, ignore_index=True),
        pd.read_parquet(clean).sort_values(key, ignore_index=True),
        check_exact=True,
    )
    assert os.listdir(tmp_path / "cache" / "grippers") == [description.digest]
