"""The decomposers a concave object's collision ladder runs, and their settings: CoACD 1.0 refined
over its concavity thresholds (coarse to fine, until the collision error is within the limits), on
the mesh, a simplified copy or the mesh remeshed by CoACD's own preprocessing; V-HACD 2.2
(pybullet.vhacd). They run in an isolated child process (:mod:`annotator.objects.decomposition_child`);
the ladder that chooses among them is :mod:`annotator.objects.collision_ladder`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from annotator.config import DecompositionConfig
from annotator.objects.fidelity import CollisionError, collision_error, surface_deviation

METHOD = "coacd"  # what load_object asks for a concave object: the ladder, CoACD first
REMESHED = "coacd-remeshed"  # the second rung: CoACD on the mesh remeshed by its preprocessing
VHACD = "vhacd"  # the third rung: V-HACD


def thresholds(config: DecompositionConfig) -> tuple[float, ...]:
    """CoACD thresholds to try, coarse to fine: the first, x 0.6 each to one significant digit,
    then the last (a step to it shorter than 1.2 x is not taken: 0.05, 0.03, 0.02, 0.01 down to
    0.01; 0.05, 0.03, 0.02 down to 0.02)."""
    last = config.min_threshold
    out, t = [], config.threshold
    while t > last * (1 + 1e-9):
        out.append(round(t, 6))
        t = float(f"{t * 0.6:.1g}")
        if t < last * 1.2:
            break
    out.append(last)
    return tuple(out)


def decomposition_input(
    vertices: np.ndarray, faces: np.ndarray, max_faces: int
) -> tuple[np.ndarray, np.ndarray]:
    """What a decomposition cuts: the mesh itself, or a copy simplified to ``max_faces`` (quadric
    decimation) when it has more. ``vertices : (n, 3) float``, ``faces : (m, 3) int``; returns
    float64 vertices and int32 faces."""
    vertices = np.ascontiguousarray(vertices, dtype=np.float64)
    faces = np.ascontiguousarray(faces, dtype=np.int32)
    if len(faces) <= max_faces:
        return vertices, faces
    import fast_simplification

    v, f = fast_simplification.simplify(vertices, faces, target_count=max_faces)
    return np.ascontiguousarray(v, dtype=np.float64), np.ascontiguousarray(f, dtype=np.int32)


@dataclass(frozen=True)
class Copy:
    """What CoACD cuts: ``vertices`` (n, 3) float64 and ``faces`` (m, 3) int32 (metres, mesh
    frame), the mesh itself or a simplified copy, and ``deviation`` (m), how far the copy strays
    from the mesh (0 for the mesh itself)."""

    vertices: np.ndarray
    faces: np.ndarray
    deviation: float


def copy_sizes(config: DecompositionConfig) -> tuple[int, ...]:
    """Face counts of the copies to consider, smallest first: ``max_faces``, doubled
    up to ``copy_max_faces`` (5,000, 10,000, 20,000)."""
    sizes = [config.max_faces]
    while sizes[-1] * 2 <= config.copy_max_faces:
        sizes.append(sizes[-1] * 2)
    return tuple(sizes)


def decomposition_copy(vertices: np.ndarray, faces: np.ndarray, config: DecompositionConfig) -> Copy:
    """The copy CoACD cuts: the mesh itself when it has at most ``max_faces`` faces,
    else the smallest copy of :func:`copy_sizes` within ``copy_tolerance`` of the
    mesh (:func:`~annotator.objects.fidelity.surface_deviation`), else the largest.

    Parts cut from a copy cannot follow the mesh more closely than the copy does: quadric
    decimation to 5,000 faces moves the rims of the YCB chips can 1.5 mm and those of the power
    drill 1.2 mm, most of the 2 mm the collision error may have (0101-collision-ladder).
    """
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    copy = Copy(*decomposition_input(vertices, faces, config.max_faces), 0.0)
    if len(faces) <= config.max_faces:
        return copy
    for size in copy_sizes(config):
        v, f = decomposition_input(vertices, faces, size)
        deviation = surface_deviation(mesh, trimesh.Trimesh(v, f, process=False), config.copy_samples)
        copy = Copy(v, f, deviation)
        if deviation <= config.copy_tolerance:
            break
    return copy


Found = Callable[[list[trimesh.Trimesh], CollisionError, float], None]


def next_threshold(
    todo: tuple[float, ...], threshold: float, error: CollisionError, config: DecompositionConfig
) -> int:
    """Index in ``todo`` (the finer thresholds left, coarse to fine) of the one to try after
    ``threshold`` gave ``error``: the coarsest at or below ``threshold`` x (limit / error) for the
    worse of mean and max, the finest when none is; never more than one threshold skipped.

    CoACD's threshold bounds each part's concavity relative to the mesh's size, so the error
    shrinks about in proportion to it: a threshold that the error says cannot be enough is skipped
    (the YCB power drill at 0.05, 4.65 mm max: straight to 0.02, not 0.03 first). The sample
    objects that refine (banana 3.12 mm, bowl 3.15 mm, mug 2.69 mm at 0.05) still go to 0.03.
    The proportion is only about right and the finer thresholds cost the most, so one step skips
    at most one threshold: the YCB cracker box at 0.05 (5.06 mm, the bounded search) goes to 0.02
    (1.97 mm when measured), not to 0.01, which its budget could not finish.
    """
    ratio = min(
        config.collision_mean_limit / max(error.mean, 1e-300),
        config.collision_max_limit / max(error.max, 1e-300),
    )
    enough = threshold * ratio * (1 + 1e-9)
    coarsest_enough = next((i for i, t in enumerate(todo) if t <= enough), len(todo) - 1)
    return min(coarsest_enough, 1)


def near_miss(error: CollisionError, config: DecompositionConfig) -> bool:
    """Beyond the error limits, but by at most ``coacd_retry_margin`` (a share of each limit)."""
    grown = 1.0 + config.coacd_retry_margin
    limits = (config.collision_mean_limit, config.collision_max_limit)
    return not error.within(*limits) and error.within(limits[0] * grown, limits[1] * grown)


def _cut_coacd(
    coacd: Any,
    mesh: trimesh.Trimesh,
    copy: Copy,
    threshold: float,
    iterations: int,
    config: DecompositionConfig,
    remesh: bool = False,
) -> tuple[list[trimesh.Trimesh], CollisionError] | None:
    """CoACD's parts of ``copy`` at ``threshold`` with ``iterations`` of tree search per cut (seed 0),
    as convex hulls, and their error against ``mesh``; None when it gives no part with volume.
    ``remesh``: CoACD remeshes ``copy`` first (its manifold preprocessing at
    ``coacd_remesh_resolution``); otherwise it cuts ``copy`` as it is (cleaned and watertight: the
    remeshing would only move its surface)."""
    if remesh:
        preprocess = {"preprocess_mode": "on", "preprocess_resolution": int(config.coacd_remesh_resolution)}
    else:
        preprocess = {"preprocess_mode": "off"}
    result = coacd.run_coacd(
        coacd.Mesh(copy.vertices, copy.faces),
        threshold=float(threshold),
        mcts_iterations=int(iterations),
        seed=0,
        **preprocess,
    )
    parts = [trimesh.Trimesh(v, f).convex_hull for v, f in result]
    parts = [p for p in parts if p.volume > 0]
    if not parts:
        return None
    return parts, collision_error(mesh, parts, config.collision_error_samples)


def refine_coacd(
    vertices: np.ndarray,
    faces: np.ndarray,
    config: DecompositionConfig,
    found: Found | None = None,
    remesh: bool = False,
) -> tuple[list[trimesh.Trimesh], CollisionError, float]:
    """CoACD at thresholds coarse to fine (:func:`thresholds`, skipping those :func:`next_threshold`
    finds too coarse) until within the error limits; the best (lowest max) otherwise. A threshold
    whose bounded search is a :func:`near_miss` is cut again with CoACD's own search
    (``[objects] coacd_refine_iterations``) and the better of the two kept: the YCB cracker box at
    0.02, 2.03 mm bounded, 1.97 mm with the own search (13 CPU-s), where 0.01 does not finish in
    the budget; the scissors at 0.02, 2.06 mm, 1.91 mm and 28 parts, where 0.01 gives 97. A wider
    miss goes finer: the master chef can at 0.03, 2.13 mm, is still 2.04 mm with the own search
    (23 CPU-s more), and 0.02 then no longer fits the budget (1.68 mm when it does).

    ``remesh``: each cut on the mesh remeshed by CoACD's manifold preprocessing, its search bounded
    to ``coacd_remesh_search_iterations`` and never retried (the ladder's second rung).

    Returns (parts, error, threshold); ``found(parts, error, threshold)`` is called each time the
    best so far improves (the child saves it, so a refinement stopped by the budget keeps it).
    """
    import coacd

    coacd.set_log_level("error")
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    copy = decomposition_copy(vertices, faces, config)
    best: tuple[list[trimesh.Trimesh], CollisionError, float] | None = None

    def keep(cut: tuple[list[trimesh.Trimesh], CollisionError] | None, threshold: float) -> None:
        nonlocal best
        if cut is not None and (best is None or cut[1].max < best[1].max):
            best = (cut[0], cut[1], float(threshold))
            if found is not None:
                found(*best)  # saved before anything else is tried

    todo = thresholds(config)
    iterations = config.coacd_remesh_search_iterations if remesh else config.coacd_search_iterations
    retry = not remesh and iterations < config.coacd_refine_iterations
    while todo:
        threshold, todo = todo[0], todo[1:]
        cut = _cut_coacd(coacd, mesh, copy, threshold, iterations, config, remesh)
        keep(cut, threshold)
        if cut is not None and retry and near_miss(cut[1], config):
            again = _cut_coacd(coacd, mesh, copy, threshold, config.coacd_refine_iterations, config)
            keep(again, threshold)
            if again is not None and again[1].max < cut[1].max:
                cut = again
        if cut is None:
            continue
        error = cut[1]
        if error.within(config.collision_mean_limit, config.collision_max_limit) or not todo:
            break
        todo = todo[next_threshold(todo, threshold, error, config) :]
    if best is None:
        raise RuntimeError("convex decomposition produced no parts")
    return best


def read_vhacd_parts(path: Path) -> list[trimesh.Trimesh]:
    """The convex hulls of the ``o`` groups of a V-HACD output .obj (global vertex numbering)."""
    groups: list[list[int]] = []
    vertices: list[list[float]] = []
    for line in path.read_text().splitlines():
        if line.startswith("o "):
            groups.append([])
        elif line.startswith("v "):
            if not groups:
                groups.append([])
            vertices.append([float(x) for x in line.split()[1:4]])
            groups[-1].append(len(vertices) - 1)
    points = np.asarray(vertices, dtype=np.float64)
    parts = []
    for idx in groups:
        if len(idx) < 4:
            continue
        try:
            hull = trimesh.Trimesh(points[idx], process=False).convex_hull
        except Exception:  # qhull: a flat group
            continue
        if hull.volume > 0:
            parts.append(hull)
    return parts


def run_vhacd(
    vertices: np.ndarray, faces: np.ndarray, config: DecompositionConfig, job: Path
) -> list[trimesh.Trimesh]:
    """V-HACD's convex parts (pybullet.vhacd, voxel mode, ``vhacd_resolution`` voxels, its other
    settings PyBullet's defaults) of the mesh, simplified to ``max_faces`` first."""
    from annotator.sim.decompose import vhacd

    v, f = decomposition_input(vertices, faces, config.max_faces)
    src, out = job / "vhacd_in.obj", job / "vhacd_out.obj"
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in v.tolist()]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f.tolist()]
    src.write_text("\n".join(lines) + "\n")
    vhacd(src, out, job / "vhacd.log", int(config.vhacd_resolution))
    return read_vhacd_parts(out) if out.is_file() else []
