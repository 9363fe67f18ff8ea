"""Shared fixtures: real PyBullet worlds in DIRECT mode, closed after each test."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pybullet as pb
import pytest
from gripper_helpers import users_rg2

from annotator.config import GripperConfig, PhysicsConfig
from annotator.sim.hand import FloatingGripper
from annotator.sim.world import World


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
