"""Grasp candidates for an object resting on the cell's table (``annotate --cell``).

The floating sampler (:mod:`annotator.sampler`) knows nothing of a table: on the sample objects
most of its candidates came from below or beside the table top, or put the fingertips into it. Here
each placement gets its own candidates, sampled in the world frame of that placement:

* the object's N rows are shared among its placements (:func:`allocate`: by stable-pose
  probability, or evenly; ``[cell] candidates_per_placement``), each placement's drawn from its own
  Generator keyed on (seed, object id, placement), and the rows are then shuffled with a Generator
  keyed on (seed, object id): a prefix of the grasp ids is a fair subsample, and a row depends on
  neither workers nor spans;
* antipodal pairs tested as the floating sampler tests them (same friction cone, same stroke),
  cast along the first contact's inward normal turned towards the horizontal by up to
  ``level_angle`` (a level closing axis admits a grasp from straight above); the approach is drawn
  uniformly from the arc of directions perpendicular to the closing axis that lie within
  ``approach_cone`` of straight down (where the fingers would not clear the table, turned halfway,
  then fully, to the most downward one); a pair whose closing axis is too steep for any such
  approach is dropped;
* the fingers (their collision boxes, :class:`annotator.sim.gripper.FingerEnvelope`), open for the
  approach and closed on the chord, must stay ``finger_clearance`` above the table top: a grasp
  on a low part sits back along its approach by the least standoff that clears, at most
  ``max_standoff`` (the contacts then lie towards the pads' tips); a pair that would need more is
  dropped. The kinematic check with the table (:class:`annotator.trial.GraspTrial`) still decides
  ``collision``: knuckles, housing and the approach path are not in this bound;
* the less selective share (``[sampler] random_fraction``, and any shortfall of accepted pairs):
  a surface point, an approach uniform over the cone, a closing axis uniform about it (into the
  object), the same standoff rule but never dropped: the informative negatives, table collisions
  among them.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import trimesh

from annotator.config import AnnotatorConfig
from annotator.geometry import Transform
from annotator.rng import keyed_rng
from annotator.sampler import Candidates, ContactPairs, chords, unit
from annotator.sim.gripper import FingerEnvelope

log = logging.getLogger(__name__)

DOWN = np.array([0.0, 0.0, -1.0])
# Where the fingers of a pair's drawn approach would not clear the table, the approach is tried
# again turned towards the most downward one by these shares of the drawn turn (the last: straight
# along it): a low part is grasped from nearer above rather than dropped.
APPROACH_RETRIES = (1.0, 0.5, 0.0)


@dataclass(frozen=True)
class TableSide:
    """What a placement's candidates must respect: the object's pose ``T_world_obj`` on the table,
    the table top's height ``top_z`` (m, world), the fingers' ``envelope`` and the opening during
    the approach, the expected chord + 2 x ``pregrasp_clearance`` (m), at most ``max_width``."""

    T_world_obj: Transform
    top_z: float
    envelope: FingerEnvelope
    pregrasp_clearance: float
    max_width: float


def allocate(n: int, probabilities: Sequence[float], mode: str) -> np.ndarray:
    """Rows per placement (P,) int64 summing to ``n``: shares by ``probabilities`` (mode
    "probability") or equal ("even"), rounded by largest remainder (ties: the earlier placement)."""
    p = np.asarray(probabilities, dtype=float)
    if p.size == 0:
        raise ValueError("no placements to share candidates among")
    if mode == "even" or not p.sum() > 0:
        p = np.ones_like(p)
    elif mode != "probability":
        raise ValueError(f"unknown candidates_per_placement {mode!r}; use 'probability' or 'even'")
    share = n * p / p.sum()
    counts = np.floor(share).astype(np.int64)
    rest = n - int(counts.sum())
    order = np.lexsort((np.arange(p.size), -np.round(share - counts, 9)))  # ties (to 1e-9): the earlier
    counts[order[:rest]] += 1
    return counts


def _approach_arc(
    x_world: np.ndarray, cos_cone: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each closing axis ``x_world`` (n, 3): the most downward approach perpendicular to it
    (n, 3), a turn ``phi`` (n,) rad about the axis drawn uniformly over the arc of approaches within
    the cone about straight down, and whether there is such an arc (n,) bool.

    With ``e`` the closing axis's elevation, the approach turned by ``phi`` from the most downward
    one makes cos(angle from vertical) = cos(phi) cos(e): the arc is |phi| <= acos(cos_cone / cos
    e), empty when e exceeds the cone.
    """
    cos_e = np.sqrt(np.clip(1.0 - x_world[:, 2] ** 2, 0.0, 1.0))
    feasible = cos_e >= cos_cone + 1e-12
    lowest = DOWN[None, :] - (x_world @ DOWN)[:, None] * x_world  # down minus its part along x
    norm = np.linalg.norm(lowest, axis=1)
    lowest = np.where(norm[:, None] > 1e-12, lowest / np.maximum(norm, 1e-12)[:, None], DOWN[None, :])
    phi_max = np.arccos(np.clip(cos_cone / np.maximum(cos_e, 1e-12), -1.0, 1.0))
    phi = rng.uniform(-1.0, 1.0, size=x_world.shape[0]) * np.where(feasible, phi_max, 0.0)
    return lowest, phi, feasible


def _turned(x_world: np.ndarray, lowest: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """The approach (n, 3) turned by ``phi`` (n,) rad about ``x_world`` from ``lowest``."""
    return unit(np.cos(phi)[:, None] * lowest + np.sin(phi)[:, None] * np.cross(x_world, lowest))


def _standoff(
    side: TableSide,
    x_world: np.ndarray,
    z_world: np.ndarray,
    mid_world: np.ndarray,
    chord: np.ndarray,
    clearance: float,
) -> np.ndarray:
    """The least distance (n,) m to move each TCP back along its approach so that the fingers,
    open for the approach and closed on the chord, stay ``clearance`` above the table top (inf
    when moving back does not raise them: an approach that is not downwards)."""
    n = x_world.shape[0]
    R = np.stack([x_world, np.cross(z_world, x_world), z_world], axis=2)  # (n, 3, 3) world <- tcp
    up_in_tcp = R[:, 2, :]  # world z in the TCP frame, (n, 3)
    open_width = np.minimum(side.max_width, chord + 2.0 * side.pregrasp_clearance)
    corners = np.concatenate(
        [side.envelope.corners_at(open_width, chord), side.envelope.corners_at(chord, chord)], axis=1
    )  # (n, 4c, 3)
    lowest = mid_world[:, 2] - side.top_z + np.min(np.einsum("nkj,nj->nk", corners, up_in_tcp), axis=1)
    rise = -z_world[:, 2]  # height gained per metre moved back along the approach
    short = clearance - lowest
    out = np.zeros(n)
    need = short > 0.0
    out[need] = np.where(rise[need] > 1e-9, short[need] / np.maximum(rise[need], 1e-9), np.inf)
    return out


def _poses(side: TableSide, pairs: ContactPairs, z_world: np.ndarray, standoff: np.ndarray) -> np.ndarray:
    """TCP poses (n, 4, 4) in the mesh frame: closing axis along the pair, approach ``z_world``,
    origin the contacts' midpoint moved back by ``standoff`` (n,) m along the approach."""
    R_world_obj = side.T_world_obj.rotation
    z = z_world @ R_world_obj  # into the mesh frame (rows: R^T z)
    x = pairs.x
    z = unit(z - np.sum(z * x, axis=1, keepdims=True) * x)
    T = np.zeros((x.shape[0], 4, 4))
    T[:, :3, 0] = x
    T[:, :3, 1] = np.cross(z, x)
    T[:, :3, 2] = z
    T[:, :3, 3] = 0.5 * (pairs.p1 + pairs.p2) - standoff[:, None] * z
    T[:, 3, 3] = 1.0
    return T


def _world(side: TableSide, vectors: np.ndarray) -> np.ndarray:
    return vectors @ side.T_world_obj.rotation.T


def _levelled_pairs(
    mesh: trimesh.Trimesh, count: int, rng: np.random.Generator, config: AnnotatorConfig, side: TableSide
) -> ContactPairs:
    """``count`` surface points, each with a ray along its inward normal turned towards the
    horizontal (of the placement's world) by a uniform angle up to ``level_angle``, never past it."""
    points, face_idx = trimesh.sample.sample_surface(mesh, count, seed=rng)
    d_world = _world(side, -mesh.face_normals[face_idx])
    elevation = np.arcsin(np.clip(d_world[:, 2], -1.0, 1.0))
    turn = rng.uniform(0.0, math.radians(config.cell.level_angle), size=count)
    levelled = np.sign(elevation) * np.maximum(0.0, np.abs(elevation) - turn)
    flat = d_world * np.array([1.0, 1.0, 0.0])
    norm = np.linalg.norm(flat, axis=1, keepdims=True)
    flat = np.where(norm > 1e-9, flat / np.maximum(norm, 1e-9), [[1.0, 0.0, 0.0]])  # straight up or down: any
    d_world = np.cos(levelled)[:, None] * flat + np.sin(levelled)[:, None] * np.array([0.0, 0.0, 1.0])
    d = unit(d_world @ side.T_world_obj.rotation)  # back into the mesh frame
    return chords(mesh, points, face_idx, d, config.sampler, side.max_width)


def _accepted_pairs(
    mesh: trimesh.Trimesh, wanted: int, rng: np.random.Generator, config: AnnotatorConfig, side: TableSide
) -> tuple[ContactPairs, np.ndarray, np.ndarray]:
    """Antipodal pairs with an approach from above whose fingers clear the table: (pairs, approach
    in the world (m, 3), standoff (m,)), at least ``wanted`` if ``max_rounds`` rounds find them."""
    cell, sampler = config.cell, config.sampler
    cos_cone = math.cos(math.radians(cell.approach_cone))
    found: list[tuple[ContactPairs, np.ndarray, np.ndarray]] = []
    total = 0
    for round_ in range(sampler.max_rounds):
        count = max(16, sampler.oversample * wanted * 2**round_)
        pairs = _levelled_pairs(mesh, count, rng, config, side)
        pairs = pairs.take(np.flatnonzero(pairs.antipodal))
        x_world = _world(side, pairs.x)
        lowest, phi, feasible = _approach_arc(x_world, cos_cone, rng)
        mid_world = side.T_world_obj.apply(0.5 * (pairs.p1 + pairs.p2))
        z_world = np.zeros_like(x_world)
        standoff = np.full(x_world.shape[0], np.inf)
        for share in APPROACH_RETRIES:  # the drawn approach; if the fingers hit, nearer the lowest
            retry = np.flatnonzero(feasible & (standoff > cell.max_standoff))
            z = _turned(x_world[retry], lowest[retry], share * phi[retry])
            z_world[retry] = z
            standoff[retry] = _standoff(
                side, x_world[retry], z, mid_world[retry], pairs.width[retry], cell.finger_clearance
            )
        ok = np.flatnonzero(feasible & (standoff <= cell.max_standoff))
        found.append((pairs.take(ok), z_world[ok], standoff[ok]))
        total += ok.size
        log.debug("cell sampler round %d: %d of %d antipodal pairs fit the table", round_, ok.size, count)
        if total >= wanted:
            break
    pairs = ContactPairs(
        *(np.concatenate([getattr(f[0], k) for f in found]) for k in ("p1", "p2", "x", "width", "antipodal"))
    )
    return pairs, np.concatenate([f[1] for f in found]), np.concatenate([f[2] for f in found])


def _less_selective(
    mesh: trimesh.Trimesh, count: int, rng: np.random.Generator, config: AnnotatorConfig, side: TableSide
) -> tuple[ContactPairs, np.ndarray, np.ndarray]:
    """``count`` surface points, each with an approach uniform over the cone (solid angle), a
    closing axis uniform about it, turned into the object, and the capped standoff."""
    cell = config.cell
    points, face_idx = trimesh.sample.sample_surface(mesh, count, seed=rng)
    cos_a = rng.uniform(math.cos(math.radians(cell.approach_cone)), 1.0, size=count)
    azimuth = rng.uniform(0.0, 2.0 * np.pi, size=count)
    turn = rng.uniform(0.0, 2.0 * np.pi, size=count)
    sin_a = np.sqrt(1.0 - cos_a**2)
    z_world = np.stack([sin_a * np.cos(azimuth), sin_a * np.sin(azimuth), -cos_a], axis=1)
    u = unit(np.cross(z_world, np.where(np.abs(z_world[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])))
    v = np.cross(z_world, u)
    x_world = np.cos(turn)[:, None] * u + np.sin(turn)[:, None] * v
    x = x_world @ side.T_world_obj.rotation  # mesh frame
    inward = np.sum(x * mesh.face_normals[face_idx], axis=1) <= 0.0
    sign = np.where(inward, 1.0, -1.0)[:, None]
    x, x_world = x * sign, x_world * sign
    pairs = chords(mesh, points, face_idx, unit(x), config.sampler, side.max_width)
    mid_world = side.T_world_obj.apply(0.5 * (pairs.p1 + pairs.p2))
    standoff = _standoff(side, x_world, z_world, mid_world, pairs.width, cell.finger_clearance)
    return pairs, z_world, np.minimum(standoff, cell.max_standoff)


def sample_placement(
    mesh: trimesh.Trimesh, n: int, rng: np.random.Generator, config: AnnotatorConfig, side: TableSide
) -> Candidates:
    """Exactly ``n`` candidates for the object resting as ``side`` says (mesh frame, unshuffled:
    the accepted antipodal ones first, then the less selective)."""
    n_random = int(round(n * config.sampler.random_fraction))
    n_anti = n - n_random
    parts: list[tuple[ContactPairs, np.ndarray, np.ndarray]] = []
    if n_anti > 0:
        pairs, z_world, standoff = _accepted_pairs(mesh, n_anti, rng, config, side)
        k = min(n_anti, len(pairs.width))
        if k < n_anti:
            log.info(
                "only %d antipodal pairs fit the table for %d wanted; filling with less selective", k, n_anti
            )
        keep = np.arange(k)
        parts.append((pairs.take(keep), z_world[keep], standoff[keep]))
        n_random = n - k
    if n_random > 0:
        parts.append(_less_selective(mesh, n_random, rng, config, side))
    if not parts:
        return Candidates(np.zeros((0, 4, 4)), np.zeros(0), np.zeros(0, dtype=bool), np.zeros((0, 2, 3)))
    T = np.concatenate([_poses(side, *part) for part in parts])
    chosen = [part[0] for part in parts]
    return Candidates(
        T_obj_tcp=T,
        width_expected=np.concatenate([p.width for p in chosen]).astype(np.float64),
        antipodal=np.concatenate([p.antipodal for p in chosen]).astype(bool),
        contacts=np.stack(
            [np.concatenate([p.p1 for p in chosen]), np.concatenate([p.p2 for p in chosen])], axis=1
        ),
    )


def sample_cell_candidates(
    mesh: trimesh.Trimesh,
    n: int,
    seed: int,
    object_id: str,
    sides: Sequence[TableSide],
    probabilities: Sequence[float],
    config: AnnotatorConfig,
) -> Candidates:
    """Exactly ``n`` candidates over the object's placements (``sides``, with their stable-pose
    ``probabilities``), shuffled; ``placement`` says which each was sampled for."""
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    counts = allocate(n, probabilities, config.cell.candidates_per_placement)
    parts = []
    for p, (side, count) in enumerate(zip(sides, counts, strict=True)):
        rng = keyed_rng("cell-candidates", int(seed), object_id, p)
        parts.append(sample_placement(mesh, int(count), rng, config, side))
    order = keyed_rng("cell-order", int(seed), object_id).permutation(n)
    return Candidates(
        T_obj_tcp=np.concatenate([c.T_obj_tcp for c in parts])[order],
        width_expected=np.concatenate([c.width_expected for c in parts])[order],
        antipodal=np.concatenate([c.antipodal for c in parts])[order],
        contacts=np.concatenate([c.contacts for c in parts])[order],
        placement=np.repeat(np.arange(len(parts), dtype=np.int64), counts)[order],
    )
