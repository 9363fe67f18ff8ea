"""Collision geometry of an object: its convex hull, its own convex shells, or convex parts from the
collision ladder (:mod:`annotator.objects.collision_ladder`: decompositions within a CPU budget,
each in an isolated child process), each with its error against the mesh; computed once per
geometry and kept in the content-addressed cache (:mod:`annotator.objects.cache`, the entry's
form in :mod:`annotator.objects.collision_entry`).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from annotator.config import DecompositionConfig
from annotator.objects import cache
from annotator.objects.cache import default_cache_dir
from annotator.objects.collision_entry import CollisionGeometry, Rung, entry_arrays, read_entry
from annotator.objects.collision_ladder import Progress, run_ladder, say
from annotator.objects.decomposers import METHOD, copy_sizes, thresholds
from annotator.objects.errors import NotDecomposed
from annotator.objects.fidelity import collision_error
from annotator.objects.own_hull import own_hull_geometry

__all__ = ["CollisionGeometry", "Progress", "Rung", "collision_geometry", "default_cache_dir", "thresholds"]


def settings(method: str, mesh: trimesh.Trimesh, config: DecompositionConfig) -> tuple[Any, ...]:
    """Every setting that shapes the geometry ``method`` gives ``mesh`` (part of the cache key)."""
    error = (config.collision_error_samples,)
    if method != METHOD:
        return error
    ladder: tuple[Any, ...] = (
        thresholds(config),
        config.coacd_search_iterations,
        config.coacd_retry_margin,
        config.coacd_first_cut_share,
        config.coacd_remesh_resolution,
        config.coacd_remesh_search_iterations,
        config.collision_mean_limit,
        config.collision_max_limit,
        config.budget,
        config.budget_basis,
        config.vhacd_reserve,
        config.vhacd_resolution,
    )
    if len(mesh.faces) > config.max_faces:
        # shape only what is simplified (the samples in the place their constant had: the same key)
        ladder += (copy_sizes(config), config.copy_tolerance, config.copy_samples)
    # an implicit setting (every decomposition had its default before it was one) keys a shape only
    # where it differs from that, so the shapes cached before keep their keys
    if config.coacd_refine_iterations != DecompositionConfig.coacd_refine_iterations:
        ladder += (("coacd_refine_iterations", config.coacd_refine_iterations),)
    return error + ladder


def geometry_inputs(
    mesh: trimesh.Trimesh, method: str, config: DecompositionConfig, shells: Sequence[trimesh.Trimesh] = ()
) -> cache.EntryInputs:
    """What the cache entry is made from: the exact vertices and faces (of the mesh and of the
    ``shells`` that give the parts), every setting that shapes the result and the library versions."""
    arrays = []
    for m in [mesh, *shells]:
        arrays += [np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)]
    return cache.entry_inputs(method, arrays, settings(method, mesh, config))


def geometry_key(
    mesh: trimesh.Trimesh, method: str, config: DecompositionConfig, shells: Sequence[trimesh.Trimesh] = ()
) -> str:
    """The cache key: the hash of :func:`geometry_inputs`."""
    return geometry_inputs(mesh, method, config, shells).key


def _compute(
    mesh: trimesh.Trimesh,
    method: str,
    config: DecompositionConfig,
    shells: list[trimesh.Trimesh],
    label: str,
    progress: Progress | None,
    load_started: float | None = None,
) -> dict[str, np.ndarray]:
    """The entry's arrays for ``method``: computed here (hull, shells) or by the ladder, which
    counts the CPU this process used since ``load_started`` (``time.process_time()``) against the
    budget."""
    if method != METHOD:
        start = time.process_time()
        parts = [mesh.convex_hull] if method == "hull" else [shell.convex_hull for shell in shells]
        error = collision_error(mesh, parts, config.collision_error_samples)
        return entry_arrays(parts, error, method, 0.0, time.process_time() - start)
    say(progress, label, f"decomposing ({len(mesh.faces)} faces) into convex parts")
    spent = 0.0 if load_started is None else max(0.0, time.process_time() - load_started)
    found, rungs = run_ladder(mesh, config, label, progress, spent)
    seconds = sum(r.cpu_seconds for r in rungs)
    kept = rungs[-1]
    assert found.error is not None, "the ladder ends on a rung that gave parts (the hull at the last)"
    return entry_arrays(found.parts, found.error, kept.method, found.threshold, seconds, rungs)


def collision_geometry(
    mesh: trimesh.Trimesh,
    method: str,
    config: DecompositionConfig,
    cache_dir: Path | None,
    object_id: str = "",
    shells: Sequence[trimesh.Trimesh] = (),
    progress: Progress | None = None,
    decompose: bool = True,
    load_started: float | None = None,
) -> CollisionGeometry:
    """The object's collision geometry by ``method``, cached: ``hull`` (the convex hull),
    ``shells`` (the hulls of the mesh's own convex ``shells``: a file written as convex parts,
    e.g. a V-HACD collision mesh, collides as those parts, as PyBullet itself would) or ``coacd``
    (the ladder: CoACD, V-HACD, hull, within ``config.budget``). A closed mesh
    that is its own convex hull (:mod:`annotator.objects.own_hull`) is its hull with no error, made
    here and never cached: no error sampling, no cache entry to write or read.

    ``cache_dir``: the cache folder (None: :func:`default_cache_dir`). ``progress(object_id,
    message)`` hears when a decomposition starts, moves down the ladder and ends. Never raises for
    a decomposition that crashes or runs over its budget: the next rung's shape is the result.
    ``decompose=False``: :class:`NotDecomposed` instead of running the ladder when the cache does
    not hold its result (a hull or shells are still made here: they take a fraction of a second).
    ``load_started``: ``time.process_time()`` when the load began; the CPU this process used since
    then (reading, cleaning, repairing the mesh) is taken from the ladder's budget, so the whole
    load stays within ``budget``.
    """
    if method not in ("hull", "shells", METHOD):
        raise ValueError(f"unknown collision method {method!r}")
    if method == "hull":
        own = own_hull_geometry(mesh)  # a closed convex mesh: its hull, no error, nothing cached
        if own is not None:
            return own
    root = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    inputs = geometry_inputs(mesh, method, config, shells if method == "shells" else ())
    path = root / f"{inputs.key}.npz"
    label = object_id or path.stem[:12]
    geometry = read_entry(path, label, inputs)
    if geometry is not None:
        return geometry
    if not decompose and method == METHOD:
        raise NotDecomposed(f"{label}: its decomposition is not in the cache {root}")
    with cache.advisory_lock(path.with_suffix(".lock")):
        geometry = read_entry(path, label, inputs)  # another process may have made it meanwhile
        if geometry is not None:
            return geometry
        computed = _compute(mesh, method, config, list(shells), label, progress, load_started)
        path = cache.write_here_or_aside(path, lambda target: cache.save_arrays(target, computed, inputs))
    geometry = read_entry(path, label, inputs)  # fresh and cached: the same float64 entry
    if geometry is None:  # pragma: no cover - removed or damaged between the write and the read
        raise OSError(f"{label}: the collision cache entry {path} vanished after it was written")
    geometry.from_cache = False
    if method == METHOD:
        say(
            progress,
            label,
            f"decomposed into {len(geometry.parts)} parts by {geometry.method} in {geometry.seconds:.1f} "
            f"CPU-s (collision error mean {geometry.error.mean * 1e3:.2f} mm, "
            f"max {geometry.error.max * 1e3:.2f} mm)",
        )
    return geometry
