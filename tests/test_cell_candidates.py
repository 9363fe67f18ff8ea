"""Candidates for objects resting on the table (``annotate --cell``): from above, fingers clear.

The finger envelope is checked against PyBullet's own bounding boxes of the finger links; the
sampled candidates are checked with the gripper model placed at each of them, not with the
sampler's arithmetic.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pybullet as pb
import pytest
import trimesh

from annotator.cell import build_cell
from annotator.cell.candidates import TableSide, allocate, sample_cell_candidates
from annotator.cell.placement import place, stable_poses
from annotator.config import AnnotatorConfig
from annotator.geometry import Transform, axis_angle_to_matrix
from annotator.sim.hand import FloatingGripper
from annotator.sim.world import World

CONFIG = AnnotatorConfig()


def test_rows_are_shared_by_stable_pose_probability_or_evenly():
    assert allocate(100, [0.29, 0.29, 0.17], "probability").tolist() == [39, 39, 22]
    assert allocate(100, [0.29, 0.29, 0.17], "even").tolist() == [34, 33, 33]
    assert allocate(2, [0.5, 0.3, 0.2], "probability").tolist() == [1, 1, 0]
    assert allocate(7, [0.1], "probability").tolist() == [7]
    assert allocate(0, [0.6, 0.4], "even").tolist() == [0, 0]
    with pytest.raises(ValueError):
        allocate(5, [], "even")


def _finger_lowest(hand: FloatingGripper) -> float:
    """The lowest point of the finger links (finger plate and pad), from PyBullet's AABBs."""
    links = [hand.body.links[name] for finger in hand.gripper.rigid_finger_links() for name in finger]
    return min(pb.getAABB(hand.uid, link, physicsClientId=hand.client)[0][2] for link in links)


@pytest.fixture(scope="module")
def gripper():
    with World(CONFIG.physics) as world:
        hand = FloatingGripper(world, CONFIG.gripper)
        table = build_cell(world, CONFIG.cell, robot=False, kinect=False)
        yield hand, hand.gripper.finger_envelope(), table.top


def test_the_finger_envelope_is_the_finger_links_collision_boxes(gripper):
    """Placed for one opening, opened to another, turned anyhow: the envelope's lowest corner is
    the lowest point of the finger links' bounding boxes in the simulated model."""
    hand, envelope, _ = gripper
    rng = np.random.default_rng(3)
    for chord, opening in ((0.0, 0.02), (0.03, 0.05), (0.08, 0.1), (0.05, 0.05)):
        axis = rng.normal(size=3)
        R = axis_angle_to_matrix(axis / np.linalg.norm(axis), rng.uniform(0.0, np.pi))
        T_world_tcp = Transform.from_rotation(R, [0.1, -0.2, 0.5])
        hand.teleport(hand.T_world_base_for_tcp(T_world_tcp, chord), opening)
        corners = T_world_tcp.apply(envelope.corners_at(np.array([opening]), np.array([chord]))[0])
        assert corners[:, 2].min() == pytest.approx(_finger_lowest(hand), abs=1e-6)


def _sides(mesh: trimesh.Trimesh, top, envelope, count: int) -> list[TableSide]:
    xy = np.array([CONFIG.cell.placement_x, CONFIG.cell.placement_y])
    poses = stable_poses(mesh, CONFIG.cell.placement_merge_angle)[:count]
    return [
        TableSide(place(pose, top, xy, 0.0, mesh.center_mass), top.z, envelope, 0.01, 0.11) for pose in poses
    ]


def _config(**sampler) -> AnnotatorConfig:
    return dataclasses.replace(CONFIG, sampler=dataclasses.replace(CONFIG.sampler, **sampler))


@pytest.mark.parametrize(
    "name, mesh",
    [
        ("box", trimesh.creation.box((0.06, 0.04, 0.03))),
        ("puck", trimesh.creation.cylinder(radius=0.03, height=0.016, sections=32)),  # lower than a pad
    ],
)
def test_selective_candidates_come_from_above_with_the_fingers_clear_of_the_table(gripper, name, mesh):
    """With no less selective share every row is an accepted pair: its approach within the cone of
    straight down, the gripper model at it (open for the approach, closed on the chord) with its
    fingers at least ``finger_clearance`` above the table top, the TCP on the line of the approach
    through the contacts' midpoint, at most ``max_standoff`` behind it. On the 16 mm puck the fingers
    clear only by standing off, so every row does."""
    hand, envelope, top = gripper
    cell, protocol = CONFIG.cell, CONFIG.protocol
    config = _config(random_fraction=0.0)
    sides = _sides(mesh, top, envelope, 2)
    n = 40
    cands = sample_cell_candidates(mesh, n, 0, name, sides, [0.7, 0.3], config)
    assert len(cands) == n
    assert (
        np.bincount(cands.placement, minlength=2).tolist() == allocate(n, [0.7, 0.3], "probability").tolist()
    )
    assert cands.antipodal.all()
    standoffs = []
    for k in range(n):
        T_world_obj = sides[cands.placement[k]].T_world_obj
        T_world_tcp = T_world_obj * Transform.from_matrix(cands.T_obj_tcp[k])
        approach = T_world_tcp.rotation[:, 2]
        assert math.degrees(math.acos(-approach[2])) <= cell.approach_cone + 1e-6
        chord = float(cands.width_expected[k])
        base = hand.T_world_base_for_tcp(T_world_tcp, chord)
        for opening in (min(hand.gripper.max_width, chord + 2 * protocol.pregrasp_clearance), chord):
            hand.teleport(base, opening)
            assert _finger_lowest(hand) >= top.z + cell.finger_clearance - 1e-6
        midpoint = T_world_obj.apply(cands.contacts[k].mean(axis=0))
        behind = midpoint - T_world_tcp.pos
        standoff = float(behind @ approach)
        np.testing.assert_allclose(behind, standoff * approach, atol=1e-9)
        assert -1e-9 <= standoff <= cell.max_standoff + 1e-9
        standoffs.append(standoff)
    if name == "puck":  # no contact is 17.9 mm up (pad centre to fingertip 14.9 + clearance 3)
        assert min(standoffs) > 0.001


def test_less_selective_candidates_keep_the_cone_and_include_table_collisions(gripper):
    """All less selective: approaches still from above, but neither the antipodal test nor the
    table decides, so some rows put the fingers into the table (informative negatives)."""
    hand, envelope, top = gripper
    mesh = trimesh.creation.cylinder(radius=0.03, height=0.016, sections=32)
    sides = _sides(mesh, top, envelope, 1)
    cands = sample_cell_candidates(mesh, 30, 0, "puck", sides, [1.0], _config(random_fraction=1.0))
    below = 0
    for k in range(len(cands)):
        T_world_tcp = sides[0].T_world_obj * Transform.from_matrix(cands.T_obj_tcp[k])
        assert -T_world_tcp.rotation[2, 2] >= math.cos(math.radians(CONFIG.cell.approach_cone)) - 1e-9
        chord = float(cands.width_expected[k])
        hand.teleport(hand.T_world_base_for_tcp(T_world_tcp, chord), chord)
        below += _finger_lowest(hand) < top.z
    assert below > 0 and not cands.antipodal.all()


def test_each_placement_draws_from_its_own_generator(gripper):
    """Rows depend on (seed, object, placement): changing placement 1 leaves placement 0's rows as
    they were; the same inputs give the same arrays bit for bit; another seed, other rows."""
    _, envelope, top = gripper
    mesh = trimesh.creation.box((0.06, 0.04, 0.03))
    sides = _sides(mesh, top, envelope, 3)
    a = sample_cell_candidates(mesh, 30, 0, "box", sides[:2], [0.5, 0.5], CONFIG)
    b = sample_cell_candidates(mesh, 30, 0, "box", sides[:2], [0.5, 0.5], CONFIG)
    c = sample_cell_candidates(mesh, 30, 0, "box", [sides[0], sides[2]], [0.5, 0.5], CONFIG)
    d = sample_cell_candidates(mesh, 30, 1, "box", sides[:2], [0.5, 0.5], CONFIG)
    for field in ("T_obj_tcp", "width_expected", "antipodal", "contacts", "placement"):
        assert np.array_equal(getattr(a, field), getattr(b, field))
    first = a.placement == 0
    assert np.array_equal(c.placement, a.placement)
    assert np.array_equal(c.T_obj_tcp[first], a.T_obj_tcp[first])
    assert not np.array_equal(c.T_obj_tcp[~first], a.T_obj_tcp[~first])
    assert not np.array_equal(d.T_obj_tcp, a.T_obj_tcp)
