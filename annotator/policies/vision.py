"""Grasps from what the Kinect sees: antipodal pairs on the observed point cloud, kept where the
open gripper clears the cloud and the table; ``vision-random`` picks among them at random.

From an :class:`~annotator.policies.records.Observation` alone:

1. *The observed surface* (:func:`observed_surface`): each depth image's valid pixels in the table
   frame, inside the workspace and more than TABLE_MARGIN above the table (the objects), thinned
   to one point per VOXEL cube; each point's normal is the least-variance axis of its NEIGHBOURS
   nearest points, turned towards the camera that saw it. A point on an edge of what is seen (a
   rim, EDGE_OFFSET) is a contact a second time, with its edge normal (along its face, away from
   its neighbours: the unseen wall below a rim faces that way).
2. *Antipodal pairs* (:func:`antipodal_pairs`): a point p1 drawn at random; along its inward normal,
   the nearest observed point p2 within LATERAL of that line, farther than the sampler's
   ``min_width`` and closer than the stroke less its ``width_margin``, with both normals inside the
   friction cone (``SamplerConfig.friction_coefficient``) of the chord p1-p2. One view sees few
   opposite walls but many opposite rims: a pair needs both contacts observed.
3. *Grasps* (:func:`grasps_from_pairs`): TCP midway, +x along the chord, the approach +z one of
   ``SamplerConfig.n_rotations`` directions about it (random phase), those that come from below the
   table's plane left out; width = the chord.
4. *Clearance* (:func:`clear_of_observed`): the gripper's collision boxes
   (:mod:`annotator.policies.gripper_boxes`) opened to the chord + 2 x
   ``ProtocolConfig.pregrasp_clearance``, swept from the grasp back along the approach
   (``ProtocolConfig.approach_distance``), meet no observed object point (all of them, not
   thinned) and stay above the table's plane.

Random numbers come from a Generator keyed on (seed, round, attempt), so a round depends on the
scene and the policy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from annotator.config import ProtocolConfig, SamplerConfig
from annotator.policies.gripper_boxes import box_corners, gripper_boxes, points_in_swept_boxes
from annotator.policies.records import Grasps, Observation
from annotator.rng import keyed_rng

# m above the table top below which a point is the table: the Kinect model's noise at 1.2 m is
# 1.5 mm x 1.44 = 2.2 mm (KinectConfig.noise_sigma_1m), two sigma of it rounded up.
TABLE_MARGIN = 0.005
VOXEL = 0.003  # m: one point per cube of this side (the depth's pixel pitch on a pile ~1 m away: 1.9 mm)
NEIGHBOURS = 12  # points of a normal's plane fit
LATERAL = 0.003  # m: how far off the closing line the second contact may lie (one voxel)
# An observed point is on an edge of what is seen (a top face's rim, a silhouette) when its
# neighbours' centroid lies more than this share of their mean distance off it within its tangent
# plane (inside a face it is ~0); its edge normal points away from them, along the face: the
# unseen wall below a rim faces that way. One view sees few opposite walls, but opposite rims.
EDGE_OFFSET = 0.3
SEEDS = 600  # points drawn as first contacts per call
KEEP = 20  # vision-random: grasps returned (random scores), the arm takes the first it reaches


@dataclass(frozen=True)
class ObservedSurface:
    """The observed object points ``points`` (n, 3) table frame m, their unit outward ``normals``
    (n, 3), and a KD-tree over the points (scipy's cKDTree); the contacts a pair may use
    ``contacts`` (m, 3) with ``contact_normals`` (m, 3) (the points with their normals, then the
    edge points again with their edge normals) and a KD-tree over them; every observed object
    point, not thinned, ``dense`` (k, 3) with its KD-tree (what the gripper must clear)."""

    points: np.ndarray
    normals: np.ndarray
    tree: object
    contacts: np.ndarray
    contact_normals: np.ndarray
    contact_tree: object
    dense: np.ndarray
    dense_tree: object


def observed_surface(observation: Observation) -> ObservedSurface:
    """Step 1 of the module docstring."""
    from scipy.spatial import cKDTree

    workspace = observation.workspace
    points, eyes = [], []
    for image in observation.images:
        d = np.asarray(image.depth, dtype=np.float64)
        K = image.K
        v, u = np.nonzero(d > 0)
        z = d[v, u]
        p_cam = np.stack([(u - K.cx) / K.fx * z, (v - K.cy) / K.fy * z, z], axis=1)
        p = image.T_table_camera.apply(p_cam)
        keep = workspace.contains(p) & (p[:, 2] > TABLE_MARGIN)
        points.append(p[keep])
        eyes.append(np.broadcast_to(image.T_table_camera.pos, (int(keep.sum()), 3)))
    if not points or not sum(len(p) for p in points):
        empty = np.zeros((0, 3))
        tree = cKDTree(empty)
        return ObservedSurface(empty, empty, tree, empty, empty, tree, empty, tree)
    p, eye = np.concatenate(points), np.concatenate(eyes)
    dense = p
    _, first = np.unique(np.floor(p / VOXEL).astype(np.int64), axis=0, return_index=True)
    first = np.sort(first)
    p, eye = p[first], eye[first]
    tree = cKDTree(p)
    k = min(NEIGHBOURS, len(p))
    _, idx = tree.query(p, k=k)
    idx = np.asarray(idx).reshape(len(p), k)
    nbrs = p[idx] - p[idx].mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", nbrs, nbrs)
    _, vecs = np.linalg.eigh(cov)
    normals = vecs[:, :, 0]
    flip = np.einsum("ni,ni->n", normals, eye - p) < 0
    normals[flip] *= -1
    # an edge of what is seen: the neighbours' centroid lies off the point within its tangent plane
    offset = p[idx].mean(axis=1) - p
    offset -= np.einsum("ni,ni->n", offset, normals)[:, None] * normals
    spacing = np.linalg.norm(p[idx] - p[:, None], axis=2).mean(axis=1)
    size = np.linalg.norm(offset, axis=1)
    edge = size > EDGE_OFFSET * np.maximum(spacing, 1e-9)
    edge_normals = -offset[edge] / size[edge][:, None]
    contacts = np.concatenate([p, p[edge]])
    contact_normals = np.concatenate([normals, edge_normals])
    return ObservedSurface(
        p, normals, tree, contacts, contact_normals, cKDTree(contacts), dense, cKDTree(dense)
    )


def antipodal_pairs(
    surface: ObservedSurface,
    rng: np.random.Generator,
    *,
    seeds: int,
    max_width: float,
    sampler: SamplerConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """Step 2 of the module docstring: (p1, p2), each (k, 3) table frame."""
    points, normals = surface.contacts, surface.contact_normals
    n = len(points)
    if n == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    cos_cone = math.cos(math.atan(sampler.friction_coefficient))
    top = max_width - sampler.width_margin
    first = rng.choice(n, size=min(seeds, n), replace=False)
    near = surface.contact_tree.query_ball_point(points[first], r=top)
    out1, out2 = [], []
    for i, others in zip(first, near, strict=True):
        others = np.asarray(others, dtype=np.int64)
        p1, inward = points[i], -normals[i]
        d = points[others] - p1
        t = d @ inward
        lateral = np.linalg.norm(d - t[:, None] * inward, axis=1)
        ok = (t > sampler.min_width) & (t < top) & (lateral < LATERAL)
        if not ok.any():
            continue
        cand, dist = others[ok], np.linalg.norm(d[ok], axis=1)
        chord = d[ok] / dist[:, None]
        ok2 = (chord @ inward > cos_cone) & (np.einsum("ni,ni->n", normals[cand], chord) > cos_cone)
        if not ok2.any():
            continue
        j = cand[ok2][np.argmin(t[ok][ok2])]
        out1.append(p1)
        out2.append(points[j])
    if not out1:
        return np.zeros((0, 3)), np.zeros((0, 3))
    return np.array(out1), np.array(out2)


def grasps_from_pairs(
    p1: np.ndarray, p2: np.ndarray, rng: np.random.Generator, rotations: int
) -> tuple[np.ndarray, np.ndarray]:
    """Step 3 of the module docstring: (T_table_tcp (m, 4, 4), width (m,))."""
    chord = p2 - p1
    width = np.linalg.norm(chord, axis=1)
    x = chord / width[:, None]
    helper = np.where(np.abs(x[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(x, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(x, u)
    phase = rng.uniform(0.0, 2 * math.pi, size=len(x))
    Ts, widths = [], []
    for k in range(rotations):
        angle = phase + 2 * math.pi * k / rotations
        z = np.cos(angle)[:, None] * u + np.sin(angle)[:, None] * v
        y = np.cross(z, x)
        T = np.tile(np.eye(4), (len(x), 1, 1))
        T[:, :3, 0], T[:, :3, 1], T[:, :3, 2] = x, y, z
        T[:, :3, 3] = (p1 + p2) / 2
        down = z[:, 2] <= 0.0  # an approach from below the table's plane cannot start
        Ts.append(T[down])
        widths.append(width[down])
    if not Ts:
        return np.zeros((0, 4, 4)), np.zeros(0)
    return np.concatenate(Ts), np.concatenate(widths)


def clear_of_observed(
    surface: ObservedSurface,
    T_table_tcp: np.ndarray,
    width: np.ndarray,
    protocol: ProtocolConfig,
    gripper: str | None = None,
) -> np.ndarray:
    """Step 4 of the module docstring: (m,) bool, the grasps whose open gripper clears;
    ``gripper``: whose collision boxes (a shipped name or folder; default the RG2)."""
    boxes_of = gripper_boxes(gripper)
    back = protocol.approach_distance
    keep = np.zeros(len(width), dtype=bool)
    for k in range(len(width)):
        open_width = min(boxes_of.max_width, float(width[k]) + 2 * protocol.pregrasp_clearance)
        boxes = boxes_of.at(open_width, float(width[k]))
        R, t = T_table_tcp[k, :3, :3], T_table_tcp[k, :3, 3]
        corners = box_corners(boxes)
        reach = float(np.linalg.norm(corners, axis=1).max()) + back
        lowest = min(((corners - [0.0, 0.0, s]) @ R.T + t)[:, 2].min() for s in (0.0, back))
        if lowest < 0.0:  # the gripper would enter the table (its top is the plane z = 0)
            continue
        near = surface.dense
        if len(near):
            near = near[surface.dense_tree.query_ball_point(t, r=reach)]
        local = (near - t) @ R
        keep[k] = not points_in_swept_boxes(local, boxes, protocol.approach_distance).any()
    return keep


def sample_grasps(
    observation: Observation,
    rng: np.random.Generator,
    *,
    seeds: int = SEEDS,
    limit: int | None = None,
    sampler: SamplerConfig | None = None,
    protocol: ProtocolConfig | None = None,
    surface: ObservedSurface | None = None,
) -> Grasps:
    """Antipodal grasps on the observed cloud that the open gripper clears (module docstring),
    in random order, score 0; at most ``limit`` (checked in that order until enough pass).
    ``surface``: the observation's :func:`observed_surface`, if already computed."""
    sampler, protocol = sampler or SamplerConfig(), protocol or ProtocolConfig()
    surface = surface if surface is not None else observed_surface(observation)
    p1, p2 = antipodal_pairs(surface, rng, seeds=seeds, max_width=observation.max_width, sampler=sampler)
    T, width = grasps_from_pairs(p1, p2, rng, sampler.n_rotations)
    order = rng.permutation(len(width))
    T, width = T[order], width[order]
    kept: list[int] = []
    for start in range(0, len(width), 32):
        part = slice(start, start + 32)
        clear = clear_of_observed(surface, T[part], width[part], protocol, observation.gripper)
        kept.extend(start + np.flatnonzero(clear))
        if limit is not None and len(kept) >= limit:
            kept = kept[:limit]
            break
    kept_idx = np.asarray(kept, dtype=np.int64)
    return Grasps(T[kept_idx], width[kept_idx], np.zeros(len(kept_idx)))


def vision_random(observation: Observation) -> Grasps:
    """The ``vision-random`` baseline: up to KEEP grasps of :func:`sample_grasps`, random scores
    (the arm executes the first of them in a random order that it reaches)."""
    rng = keyed_rng("vision-random", observation.seed, observation.round_id, observation.attempt)
    grasps = sample_grasps(observation, rng, limit=KEEP)
    return Grasps(grasps.T_table_tcp, grasps.width, rng.uniform(size=len(grasps)))
