"""Shared fixtures: real PyBullet worlds in DIRECT mode, closed after each test; a user's gripper
folder; the convex sample objects and one small scene run of them, labelled once a run."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pybullet as pb
import pytest
from gripper_helpers import users_rg2
from helpers import QUICK_VIEWS, SCENE_RUN_N, run_annotate

from annotator.config import GripperConfig, PhysicsConfig
from annotator.objects.machine_speed import FACTOR_ENV
from annotator.sim.hand import FloatingGripper
from annotator.sim.world import World

# The decomposition budget in plain CPU seconds for the suite and every process it starts, unless
# the caller set a factor: each process would otherwise time a reference cut (about 4 s) before its
# first decomposition. tests/test_collision_ladder.py measures it and scales by it on purpose.
os.environ.setdefault(FACTOR_ENV, "1")


@pytest.fixture
def world():
    w = World(PhysicsConfig())
    yield w
    w.close()


@pytest.fixture
def hand(world):
    return FloatingGripper(world, GripperConfig())


def make_box(
    world: World, size: float | tuple, mass: float, pos=(0.0, 0.0, 0.1), friction: float = 1.0
) -> int:
    """A box body of edge ``size`` (m, scalar or (3,)) centred at ``pos``."""
    half = (np.ones(3) * np.asarray(size) / 2).tolist()
    col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=world.client)
    uid = pb.createMultiBody(mass, col, -1, list(pos), physicsClientId=world.client)
    pb.changeDynamics(
        uid,
        -1,
        lateralFriction=friction,
        spinningFriction=0.002,
        rollingFriction=0.0001,
        physicsClientId=world.client,
    )
    return uid


@pytest.fixture
def my_rg2(tmp_path) -> Path:
    """A user's RG2 folder in the test's tmp_path: the shipped files under the name ``my_rg2``."""
    return users_rg2(tmp_path)


REPO = Path(__file__).resolve().parents[1]
CONVEX_OBJECTS = ("box.obj", "can.stl")  # convex: no decomposition, graspable from above wherever they land


@pytest.fixture(scope="package")  # tests/ is no package: once a run
def convex_objects(tmp_path_factory) -> Path:
    """A folder of the convex sample objects (box, can); tests only read it."""
    folder = tmp_path_factory.mktemp("convex-objects")
    for name in CONVEX_OBJECTS:
        shutil.copy(REPO / "objects" / name, folder)
    return folder


@pytest.fixture(scope="package")  # tests/ is no package: once a run
def convex_scene_run(convex_objects, tmp_path_factory) -> Path:
    """``annotate --scenes 2 --per-scene 3 --n 40 --views 1`` of the convex objects with one worker
    (about 15 CPU-seconds), labelled once for every test that reads a scene run; tests only read
    it (copy it to change it)."""
    root = tmp_path_factory.mktemp("convex-scene-run")
    config = root / "views.toml"
    config.write_text(QUICK_VIEWS)
    out = root / "labels"
    args = [
        "--scenes",
        2,
        "--per-scene",
        3,
        "--n",
        SCENE_RUN_N,
        "--views",
        1,
        "--config",
        config,
        "--workers",
        1,
    ]
    run_annotate("--objects", convex_objects, "--out", out, "--quiet", *args)
    return out


@pytest.fixture(scope="package")  # tests/ is no package: once a run
def shape_cache(tmp_path_factory) -> Path:
    """A decomposition cache shared by the run's tests that need an object's collision shape
    but do not test how it is made: the first such test decomposes, the others read it back (the
    parts are the same float64 numbers either way). Tests of the cold path make their own cache."""
    return tmp_path_factory.mktemp("shape-cache")
