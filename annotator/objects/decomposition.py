"""Collision geometry of an object: its convex hull, its own convex shells, or convex parts from a
ladder of decompositions within a CPU budget, each with its error against the mesh; computed once
per geometry and kept in the content-addressed cache (:mod:`annotator.objects.cache`).

The ladder (a concave object), inside ``ObjectConfig.decomposition_budget`` CPU seconds for the
object's whole load (what its reading and repair used comes off the ladder's share):

1. CoACD at each of :func:`thresholds` (coarse to fine) until the collision error is within
   ``collision_mean_limit`` / ``collision_max_limit``, the best so far kept (CoACD 1.0's tree
   search bounded to ``coacd_search_iterations``, seed 0, on the mesh or the smallest simplified
   copy that follows it within ``decomposition_copy_tolerance``, in a child process limited to the
   budget; a threshold that misses the limits by at most ``coacd_retry_margin`` is cut again with
   CoACD's own search before a finer one; stopped at ``coacd_first_cut_share`` of the budget if it
   has finished no threshold by then); a refinement stopped by the budget keeps the best threshold
   it finished;
2. when that finished no threshold: CoACD again, the same thresholds, on the mesh remeshed by
   CoACD's own manifold preprocessing (``coacd_remesh_resolution``, tree search bounded to
   ``coacd_remesh_search_iterations``), in a child process limited to what is left, stopped at that
   less ``vhacd_reserve`` if it has finished no threshold by then;
3. V-HACD (pybullet.vhacd, bullet3's V-HACD 2.2) when neither CoACD finished a threshold, in a
   child process limited to what is left;
4. the convex hull, in this process, when none gave parts.

Every step reports what it did (:class:`Rung`: kept, over budget, crashed, no parts) with its CPU
seconds and error. Running over the budget or crashing is a normal result, the next rung's turn:
the object still gets its shape, cached like any other, and is never decomposed again; only an
unusable mesh (found before, by reading and cleaning it) fails an object. The budget is CPU time
(RLIMIT_CPU of the child), so a loaded machine does not push an object down the ladder; a slower
one can, and the cache keeps whichever shape was made first.

Isolation: each decomposition runs in a child process (CoACD has segfaulted and hung on real
meshes) with one OpenMP thread (workers already run one per core; CoACD's parts are the same with
1 and 2 threads). Precision: parts are stored as float64; fresh and cached parts are both read
back from that entry, so a first run and later runs simulate identical geometry.

CoACD is the first rung because it was faster and about twice as tight as V-HACD on the concave
sample objects; measurements and reasons in docs/decisions/0101-collision-ladder.md.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from annotator.config import ObjectConfig
from annotator.objects import cache
from annotator.objects.cache import default_cache_dir
from annotator.objects.errors import NotDecomposed
from annotator.objects.fidelity import CollisionError, collision_error, surface_deviation

log = logging.getLogger(__name__)

METHOD = "coacd"  # what load_object asks for a concave object: the ladder, CoACD first
REMESHED = "coacd-remeshed"  # the second rung: CoACD on the mesh remeshed by its preprocessing
LADDER = ("coacd", REMESHED, "vhacd", "hull")
# Called as progress(object_id, message) when a decomposition starts, moves down the ladder and ends.
Progress = Callable[[str, str], None]
# Surface points per side measuring how far a simplified copy strays from the mesh (seeded).
COPY_SAMPLES = 4_000
# CoACD 1.0's own tree-search iterations per cut (coacd.run_coacd's mcts_iterations default): the
# search a near miss of the bounded one is retried with (refine_coacd).
COACD_OWN_SEARCH_ITERATIONS = 150
# How often (s) the parent looks at its decomposition child.
POLL_SECONDS = 0.05

__all__ = ["CollisionGeometry", "Progress", "Rung", "collision_geometry", "default_cache_dir", "thresholds"]


@dataclass(frozen=True)
class Rung:
    """One step of the ladder as it went.

    ``method``: coacd, coacd-remeshed, vhacd or hull; ``outcome``: ``kept`` (its parts are the
    shape), ``over budget`` (stopped by the CPU budget before it had parts), ``crashed`` (its
    process died; the reason in ``detail``) or ``no parts``; ``cpu_seconds`` it took;
    ``threshold`` (CoACD: of its parts; 0 otherwise) and ``error`` of its parts (None without
    parts).
    """

    method: str
    outcome: str
    cpu_seconds: float
    threshold: float = 0.0
    error: CollisionError | None = None
    detail: str = ""

    def summary(self, seconds: bool = True) -> str:
        """One phrase, e.g. ``coacd kept (threshold 0.03, error 0.15 / 1.82 mm, 12.1 CPU-s)``."""
        bits = [f"threshold {self.threshold:g}"] if self.threshold else []
        if self.error is not None:
            bits.append(f"error {self.error.mean * 1e3:.2f} / {self.error.max * 1e3:.2f} mm")
        if self.detail:
            bits.append(self.detail)
        if seconds:
            bits.append(f"{self.cpu_seconds:.1f} CPU-s")
        return f"{self.method} {self.outcome} ({', '.join(bits)})"

    def to_json(self) -> dict:
        out = dataclasses.asdict(self)
        out["error"] = None if self.error is None else dataclasses.astuple(self.error)
        return out

    @classmethod
    def from_json(cls, data: dict) -> Rung:
        error = data.get("error")
        return cls(
            str(data["method"]),
            str(data["outcome"]),
            float(data["cpu_seconds"]),
            float(data.get("threshold", 0.0)),
            None if error is None else CollisionError(*map(float, error)),
            str(data.get("detail", "")),
        )


@dataclass
class CollisionGeometry:
    """Convex ``parts`` (metres, mesh frame), their ``error`` against the mesh, how they were made.

    ``method``: hull, shells, coacd, coacd-remeshed or vhacd (the rung that gave the parts);
    ``threshold``: CoACD's concavity threshold of the parts (0 otherwise); ``seconds``: CPU seconds
    it took to make them (all rungs); ``ladder``: the rungs tried, in order (empty for hull and
    shells); ``file``: the cache entry; ``obj_file``: the multi-part .obj PyBullet loads (None for
    one part).
    """

    parts: list[trimesh.Trimesh]
    error: CollisionError
    method: str
    threshold: float
    file: Path
    from_cache: bool
    seconds: float
    ladder: tuple[Rung, ...] = ()
    obj_file: Path | None = None

    def within(self, config: ObjectConfig) -> bool:
        return self.error.within(config.collision_mean_limit, config.collision_max_limit)

    def ladder_summary(self, seconds: bool = True) -> str:
        """The rungs tried, ``; ``-separated (empty for a hull or shells); ``seconds``: with their
        CPU seconds (which vary from run to run)."""
        return "; ".join(r.summary(seconds) for r in self.ladder)


def thresholds(config: ObjectConfig) -> tuple[float, ...]:
    """CoACD thresholds to try, coarse to fine: the first, x 0.6 each to one significant digit,
    then the last (a step to it shorter than 1.2 x is not taken: 0.05, 0.03, 0.02, 0.01 down to
    0.01; 0.05, 0.03, 0.02 down to 0.02)."""
    last = config.decomposition_min_threshold
    out, t = [], config.decomposition_threshold
    while t > last * (1 + 1e-9):
        out.append(round(t, 6))
        t = float(f"{t * 0.6:.1g}")
        if t < last * 1.2:
            break
    out.append(last)
    return tuple(out)


def settings(method: str, mesh: trimesh.Trimesh, config: ObjectConfig) -> tuple:
    """Every setting that shapes the geometry ``method`` gives ``mesh`` (part of the cache key)."""
    error = (config.collision_error_samples,)
    if method != METHOD:
        return error
    ladder: tuple = (
        thresholds(config),
        config.coacd_search_iterations,
        config.coacd_retry_margin,
        config.coacd_first_cut_share,
        config.coacd_remesh_resolution,
        config.coacd_remesh_search_iterations,
        config.collision_mean_limit,
        config.collision_max_limit,
        config.decomposition_budget,
        config.vhacd_reserve,
        config.vhacd_resolution,
    )
    if len(mesh.faces) > config.decomposition_max_faces:
        # shape only what is simplified
        ladder += (copy_sizes(config), config.decomposition_copy_tolerance, COPY_SAMPLES)
    return error + ladder


def geometry_inputs(
    mesh: trimesh.Trimesh, method: str, config: ObjectConfig, shells: Sequence[trimesh.Trimesh] = ()
) -> cache.EntryInputs:
    """What the cache entry is made from: the exact vertices and faces (of the mesh and of the
    ``shells`` that give the parts), every setting that shapes the result and the library versions."""
    arrays = []
    for m in [mesh, *shells]:
        arrays += [np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)]
    return cache.entry_inputs(method, arrays, settings(method, mesh, config))


def geometry_key(
    mesh: trimesh.Trimesh, method: str, config: ObjectConfig, shells: Sequence[trimesh.Trimesh] = ()
) -> str:
    """The cache key: the hash of :func:`geometry_inputs`."""
    return geometry_inputs(mesh, method, config, shells).key


# --------------------------------------------------------------------------------------------------
# entries: float64 parts, error figures, the ladder


def _arrays(
    parts: list[trimesh.Trimesh],
    error: CollisionError,
    method: str,
    threshold: float,
    seconds: float,
    ladder: tuple[Rung, ...] = (),
) -> dict[str, np.ndarray]:
    return {
        "vertex_counts": np.array([len(p.vertices) for p in parts], dtype=np.int64),
        "face_counts": np.array([len(p.faces) for p in parts], dtype=np.int64),
        "vertices": np.concatenate([np.asarray(p.vertices, dtype=np.float64) for p in parts]),
        "faces": np.concatenate([np.asarray(p.faces, dtype=np.int64) for p in parts]),
        "error": np.array(dataclasses.astuple(error), dtype=np.float64),
        "method": np.array(method),
        "threshold": np.array(threshold, dtype=np.float64),
        "seconds": np.array(seconds, dtype=np.float64),
        "ladder": np.array(json.dumps([r.to_json() for r in ladder])),
    }


def _geometry(arrays: dict[str, np.ndarray], path: Path) -> CollisionGeometry:
    """The geometry of an entry's arrays; ValueError/KeyError when they do not make one."""
    v_split = np.cumsum(arrays["vertex_counts"])[:-1]
    f_split = np.cumsum(arrays["face_counts"])[:-1]
    parts = [
        trimesh.Trimesh(v, f, process=False)
        for v, f in zip(
            np.split(arrays["vertices"], v_split), np.split(arrays["faces"], f_split), strict=True
        )
    ]
    if not parts or any(len(p.faces) == 0 for p in parts):
        raise ValueError("no parts")
    ladder = tuple(Rung.from_json(r) for r in json.loads(str(arrays["ladder"])))
    return CollisionGeometry(
        parts,
        CollisionError(*arrays["error"].tolist()),
        str(arrays["method"]),
        float(arrays["threshold"]),
        path,
        True,
        float(arrays["seconds"]),
        ladder,
    )


def obj_text(parts: list[trimesh.Trimesh]) -> str:
    """Multi-part .obj, one ``o`` group per convex part (PyBullet loads it as a compound), with
    repr-exact coordinates of the float64 parts."""
    lines, offset = [], 1
    for i, part in enumerate(parts):
        lines.append(f"o part_{i}")
        lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in np.asarray(part.vertices, dtype=float).tolist()]
        lines += [f"f {a + offset} {b + offset} {c + offset}" for a, b, c in np.asarray(part.faces).tolist()]
        offset += len(part.vertices)
    return "\n".join(lines) + "\n"


_REPORTED: set[tuple[str, str]] = set()  # (entry, problem) already logged by this process


def _read_entry(path: Path, label: str, inputs: cache.EntryInputs | None = None) -> CollisionGeometry | None:
    """The verified entry at ``path`` (made from ``inputs`` when given) with its .obj in place;
    None when missing, broken or made from other inputs (logged once per entry and problem)."""
    try:
        geometry = _geometry(cache.load_arrays(path, inputs), path)
    except FileNotFoundError:
        return None
    except (cache.CorruptEntry, ValueError, KeyError, TypeError) as exc:
        what = "foreign" if isinstance(exc, cache.ForeignEntry) else "broken"
        if (str(path), str(exc)) not in _REPORTED:
            _REPORTED.add((str(path), str(exc)))
            log.warning("%s: %s collision cache entry %s (%s); making it again", label, what, path.name, exc)
        return None
    if len(geometry.parts) > 1:
        geometry.obj_file = cache.write_obj(path.parent, path.stem, obj_text(geometry.parts))
    return geometry


# --------------------------------------------------------------------------------------------------
# computing, in the child process


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


def copy_sizes(config: ObjectConfig) -> tuple[int, ...]:
    """Face counts of the copies to consider, smallest first: ``decomposition_max_faces``, doubled
    up to ``decomposition_copy_max_faces`` (5,000, 10,000, 20,000)."""
    sizes = [config.decomposition_max_faces]
    while sizes[-1] * 2 <= config.decomposition_copy_max_faces:
        sizes.append(sizes[-1] * 2)
    return tuple(sizes)


def decomposition_copy(vertices: np.ndarray, faces: np.ndarray, config: ObjectConfig) -> Copy:
    """The copy CoACD cuts: the mesh itself when it has at most ``decomposition_max_faces`` faces,
    else the smallest copy of :func:`copy_sizes` within ``decomposition_copy_tolerance`` of the
    mesh (:func:`~annotator.objects.fidelity.surface_deviation`), else the largest.

    Parts cut from a copy cannot follow the mesh more closely than the copy does: quadric
    decimation to 5,000 faces moves the rims of the YCB chips can 1.5 mm and those of the power
    drill 1.2 mm, most of the 2 mm the collision error may have (0101-collision-ladder).
    """
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    copy = Copy(*decomposition_input(vertices, faces, config.decomposition_max_faces), 0.0)
    if len(faces) <= config.decomposition_max_faces:
        return copy
    for size in copy_sizes(config):
        v, f = decomposition_input(vertices, faces, size)
        deviation = surface_deviation(mesh, trimesh.Trimesh(v, f, process=False), COPY_SAMPLES)
        copy = Copy(v, f, deviation)
        if deviation <= config.decomposition_copy_tolerance:
            break
    return copy


Found = Callable[[list[trimesh.Trimesh], CollisionError, float], None]


def next_threshold(
    todo: tuple[float, ...], threshold: float, error: CollisionError, config: ObjectConfig
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


def near_miss(error: CollisionError, config: ObjectConfig) -> bool:
    """Beyond the error limits, but by at most ``coacd_retry_margin`` (a share of each limit)."""
    grown = 1.0 + config.coacd_retry_margin
    limits = (config.collision_mean_limit, config.collision_max_limit)
    return not error.within(*limits) and error.within(limits[0] * grown, limits[1] * grown)


def _cut_coacd(
    coacd,
    mesh: trimesh.Trimesh,
    copy: Copy,
    threshold: float,
    iterations: int,
    config: ObjectConfig,
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
    config: ObjectConfig,
    found: Found | None = None,
    remesh: bool = False,
) -> tuple[list[trimesh.Trimesh], CollisionError, float]:
    """CoACD at thresholds coarse to fine (:func:`thresholds`, skipping those :func:`next_threshold`
    finds too coarse) until within the error limits; the best (lowest max) otherwise. A threshold
    whose bounded search is a :func:`near_miss` is cut again with CoACD's own search
    (:data:`COACD_OWN_SEARCH_ITERATIONS`) and the better of the two kept: the YCB cracker box at
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
    retry = not remesh and iterations < COACD_OWN_SEARCH_ITERATIONS
    while todo:
        threshold, todo = todo[0], todo[1:]
        cut = _cut_coacd(coacd, mesh, copy, threshold, iterations, config, remesh)
        keep(cut, threshold)
        if cut is not None and retry and near_miss(cut[1], config):
            again = _cut_coacd(coacd, mesh, copy, threshold, COACD_OWN_SEARCH_ITERATIONS, config)
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
    vertices: np.ndarray, faces: np.ndarray, config: ObjectConfig, job: Path
) -> list[trimesh.Trimesh]:
    """V-HACD's convex parts (pybullet.vhacd, voxel mode, ``vhacd_resolution`` voxels, its other
    settings PyBullet's defaults) of the mesh, simplified to ``decomposition_max_faces`` first."""
    from annotator.sim import pb

    v, f = decomposition_input(vertices, faces, config.decomposition_max_faces)
    src, out = job / "vhacd_in.obj", job / "vhacd_out.obj"
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in v.tolist()]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f.tolist()]
    src.write_text("\n".join(lines) + "\n")
    pb.vhacd(str(src), str(out), str(job / "vhacd.log"), resolution=int(config.vhacd_resolution))
    return read_vhacd_parts(out) if out.is_file() else []


def _save_result(job: Path, parts, error: CollisionError, threshold: float, done: bool) -> None:
    arrays = _arrays(parts, error, "", threshold, 0.0)
    arrays["done"] = np.array(done)
    cache.save_arrays(job / "out.npz", arrays)


def child_main(job: str) -> None:
    """Entry of the isolated process: read ``job/in.npz`` (mesh, settings, rung), write
    ``job/out.npz`` (its best parts so far, then the final ones)."""
    src = Path(job)
    with np.load(src / "in.npz", allow_pickle=False) as z:
        vertices, faces = z["vertices"], z["faces"]
        fields = json.loads(str(z["config"]))
        rung = str(z["rung"])
        cpu_limit = float(z["cpu_limit"])
    _limit_own_cpu(cpu_limit)
    config = dataclasses.replace(ObjectConfig(), **fields)
    if rung in (METHOD, REMESHED):
        parts, error, threshold = refine_coacd(
            vertices, faces, config, lambda p, e, t: _save_result(src, p, e, t, done=False), rung == REMESHED
        )
        _save_result(src, parts, error, threshold, done=True)
        return
    parts = run_vhacd(vertices, faces, config, src)
    if parts:
        mesh = trimesh.Trimesh(vertices, faces, process=False)
        _save_result(src, parts, collision_error(mesh, parts, config.collision_error_samples), 0.0, True)


def _limit_own_cpu(seconds: float) -> None:
    """The CPU limit on this process itself, where the parent could not set it (no prlimit)."""
    import resource

    soft = max(1, math.ceil(seconds))
    current, _ = resource.getrlimit(resource.RLIMIT_CPU)
    if current == resource.RLIM_INFINITY or current > soft:
        try:
            resource.setrlimit(resource.RLIMIT_CPU, (soft, soft + 1))
        except (ValueError, OSError):  # pragma: no cover - a hard limit below it: keep that
            pass


def child_command(job: Path) -> list[str]:
    """The command that runs one decomposition job in its own process (a test seam)."""
    code = "import sys; from annotator.objects.decomposition import child_main; child_main(sys.argv[1])"
    return [sys.executable, "-c", code, str(job)]


@dataclass(frozen=True)
class ChildRun:
    """How a limited child process ended: its exit code (negative: the signal), CPU seconds (its
    own and its waited-for children's), whether a limit stopped it, the end of its stderr."""

    returncode: int
    cpu_seconds: float
    over_cpu: bool
    stalled: bool  # stopped after using no CPU for the stall limit (a hang, not work)
    stderr: str = ""


def _limit_cpu(pid: int, seconds: float) -> None:
    """RLIMIT_CPU of process ``pid``: SIGXCPU at ``seconds`` (whole, at least 1), SIGKILL a second
    later; no core file. Linux (prlimit); elsewhere the child limits itself (child_main)."""
    import resource

    soft = max(1, math.ceil(seconds))
    resource.prlimit(pid, resource.RLIMIT_CORE, (0, 0))
    resource.prlimit(pid, resource.RLIMIT_CPU, (soft, soft + 1))


def _cpu_ticks(pid: int) -> int | None:
    """CPU clock ticks (user + system) process ``pid`` has used so far; None where /proc cannot say."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            fields = fh.read().rsplit(b")", 1)[1].split()
        return int(fields[11]) + int(fields[12])  # utime, stime: fields 14 and 15 of stat(5)
    except (OSError, IndexError, ValueError):
        return None


@dataclass(frozen=True)
class Checkpoint:
    """Stop a child at ``seconds`` of CPU unless ``keep_going()`` says it has earned the rest of
    its limit (CoACD: it has finished a threshold, so V-HACD's reserve is no longer needed)."""

    seconds: float
    keep_going: Callable[[], bool]


@dataclass
class _Watch:
    """The parent's view of a running child: its CPU ticks, when they last moved, and why it was
    stopped (a checkpoint it had not earned, or a stall)."""

    stall_seconds: float
    checkpoint: Checkpoint | None
    tick: float
    last_ticks: int | None = None
    progress: float = field(default_factory=time.monotonic)
    stopped: bool = False
    stalled: bool = False

    def must_stop(self, pid: int) -> bool:
        ticks, now = _cpu_ticks(pid), time.monotonic()
        if ticks is not None and ticks != self.last_ticks:
            self.last_ticks, self.progress = ticks, now
        if self.checkpoint is not None and ticks is not None and ticks / self.tick >= self.checkpoint.seconds:
            self.stopped = not self.checkpoint.keep_going()
            self.checkpoint = None  # earned, or stopped now: decided once
        self.stalled = now - self.progress > self.stall_seconds
        return self.stopped or self.stalled


def run_limited(
    cmd: list[str], cpu_seconds: float, stall_seconds: float, cwd: Path, checkpoint: Checkpoint | None = None
) -> ChildRun:
    """Run ``cmd`` with at most ``cpu_seconds`` of CPU time (and at most ``checkpoint.seconds``
    unless it has earned more), stopped too when it uses no CPU for ``stall_seconds`` (a hang;
    where /proc cannot tell, after ``stall_seconds`` of wall time), one OpenMP thread; returns how it
    ended. A loaded machine slows it down but does not stop it."""
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    with open(cwd / "stderr.txt", "w+b") as err:
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err, env=env)
        watched = _cpu_ticks(proc.pid) is not None  # /proc tells its CPU: the checkpoint can be kept
        try:
            _limit_cpu(proc.pid, cpu_seconds if watched or checkpoint is None else checkpoint.seconds)
        except (AttributeError, OSError, ValueError):  # pragma: no cover - no prlimit: the child's own
            pass
        watch = _Watch(stall_seconds, checkpoint, float(os.sysconf("SC_CLK_TCK")))
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if watch.must_stop(proc.pid):
                proc.kill()
                pid, status, usage = os.wait4(proc.pid, 0)
                break
            time.sleep(POLL_SECONDS)
        proc.returncode = os.waitstatus_to_exitcode(status)
        err.seek(0)
        tail = err.read().decode(errors="replace").strip().splitlines()[-1:]
    cpu = usage.ru_utime + usage.ru_stime
    # SIGXCPU comes from the CPU limit alone; SIGKILL from its hard limit a second later, or from
    # this function at the checkpoint or after a stall. rusage's user + system time is sampled and
    # can read a second short of the limit the kernel enforced.
    hard_limit = proc.returncode == -signal.SIGKILL and cpu >= max(1, math.ceil(cpu_seconds)) - 1.5
    over_cpu = watch.stopped or (not watch.stalled and (proc.returncode == -signal.SIGXCPU or hard_limit))
    return ChildRun(proc.returncode, cpu, over_cpu, watch.stalled, tail[0][:160] if tail else "")


def _describe_exit(code: int) -> str:
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


@dataclass
class _Found:
    """What a child rung gave: parts and their error (None: nothing), and how the rung went."""

    rung: Rung
    parts: list[trimesh.Trimesh] = field(default_factory=list)
    error: CollisionError | None = None
    threshold: float = 0.0


def _child_rung(
    mesh: trimesh.Trimesh,
    config: ObjectConfig,
    method: str,
    cpu_limit: float,
    first_parts: float | None = None,
) -> _Found:
    """One rung (coacd, coacd-remeshed or vhacd) in a limited child process; whatever it gave within
    the limit. With ``first_parts`` (CPU-s, below the limit), it is stopped there unless it has
    parts by then (the next rungs need the rest only if this one gives nothing)."""
    with tempfile.TemporaryDirectory(prefix="rg2-decompose-") as tmp:
        job = Path(tmp)
        np.savez(
            job / "in.npz",
            vertices=np.asarray(mesh.vertices, dtype=np.float64),
            faces=np.asarray(mesh.faces, dtype=np.int64),
            config=np.array(json.dumps(dataclasses.asdict(config))),
            rung=np.array(method),
            cpu_limit=np.array(cpu_limit),
        )
        checkpoint = None
        if first_parts is not None and first_parts < cpu_limit:
            checkpoint = Checkpoint(max(1.0, first_parts), (job / "out.npz").is_file)
        run = run_limited(child_command(job), cpu_limit, config.decomposition_timeout, job, checkpoint)
        try:
            out = cache.load_arrays(job / "out.npz")
            geometry = _geometry(out, job)
            done = bool(out["done"])
        except (FileNotFoundError, cache.CorruptEntry, ValueError, KeyError):
            geometry, done = None, False
    if run.over_cpu:
        outcome, detail = "over budget", f"stopped at {run.cpu_seconds:.0f} CPU-s"
    elif run.stalled:
        outcome, detail = "over budget", f"stopped after {config.decomposition_timeout:g} s without using CPU"
    elif run.returncode != 0:
        outcome = "crashed"
        detail = _describe_exit(run.returncode) + (f": {run.stderr}" if run.stderr else "")
    else:
        outcome, detail = ("kept" if geometry is not None else "no parts"), ""
    if geometry is None:
        return _Found(Rung(method, outcome, run.cpu_seconds, detail=detail))
    if not done:  # stopped during a finer threshold: the best one it finished stays
        detail = f"{outcome}: {detail}" if detail else outcome
        outcome = "kept"
    rung = Rung(method, "kept", run.cpu_seconds, geometry.threshold, geometry.error, detail)
    return _Found(rung, geometry.parts, geometry.error, geometry.threshold)


# CPU seconds the ladder leaves for what follows it in a load: writing the cache entry, reading it
# back and writing the parts' .obj (a 100-part entry of the YCB meshes: about 0.1 CPU-s).
AFTER_LADDER_SECONDS = 0.5


def first_parts_by(method: str, limit: float, config: ObjectConfig) -> float | None:
    """CPU-s of its own by which a rung given ``limit`` CPU-s must have parts or be stopped (None:
    no such point). CoACD as the mesh is: ``coacd_first_cut_share`` of the budget, and at the
    latest ``vhacd_reserve`` before its limit; CoACD remeshed: ``vhacd_reserve`` before its limit."""
    if method not in (METHOD, REMESHED):
        return None
    stop = limit - config.vhacd_reserve
    if method == METHOD:
        stop = min(stop, config.coacd_first_cut_share * config.decomposition_budget)
    return stop if stop < limit else None


def _ladder(
    mesh: trimesh.Trimesh, config: ObjectConfig, label: str, progress: Progress | None, spent: float = 0.0
) -> tuple[_Found, tuple[Rung, ...]]:
    """The ladder within what is left of the budget (``spent``: CPU seconds the load used before
    it; the ladder's own work in this process counts too): CoACD, CoACD remeshed, V-HACD, the hull;
    the first rung with parts. CoACD remeshed starts only with more than a CPU-s beyond V-HACD's
    reserve left."""
    budget = config.decomposition_budget - spent - AFTER_LADDER_SECONDS
    start = time.process_time()
    rungs: list[Rung] = []
    children = 0.0
    for method in LADDER:
        used = children + (time.process_time() - start)
        if method == "hull":
            hull_started = time.process_time()
            parts = [mesh.convex_hull]
            error = collision_error(mesh, parts, config.collision_error_samples)
            found = _Found(Rung("hull", "kept", time.process_time() - hull_started, 0.0, error), parts, error)
        elif budget - used < 1.0:  # the load spent the budget before this rung: no child at all
            left = f"{max(0.0, budget - used):.1f} CPU-s left"
            found = _Found(Rung(method, "over budget", 0.0, detail=left))
        elif method == REMESHED and budget - used - config.vhacd_reserve < 1.0:
            left = f"{max(0.0, budget - used):.1f} CPU-s left, V-HACD's reserve {config.vhacd_reserve:g}"
            found = _Found(Rung(method, "over budget", 0.0, detail=left))
        else:
            # CoACD may use the whole budget once it has parts; until then it leaves the next rungs theirs
            limit = math.floor(budget - used)  # whole seconds, within the budget
            found = _child_rung(mesh, config, method, limit, first_parts_by(method, limit, config))
        rungs.append(found.rung)
        if method != "hull":
            children += found.rung.cpu_seconds
        if found.parts:
            return found, tuple(rungs)
        _say(progress, label, f"{found.rung.summary()}; next: {LADDER[LADDER.index(method) + 1]}")
    raise AssertionError("the hull always has parts")  # pragma: no cover


def _say(progress: Progress | None, label: str, message: str) -> None:
    log.info("%s: %s", label, message)
    if progress is not None:
        progress(label, message)


def _compute(
    mesh: trimesh.Trimesh,
    method: str,
    config: ObjectConfig,
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
        return _arrays(parts, error, method, 0.0, time.process_time() - start)
    _say(progress, label, f"decomposing ({len(mesh.faces)} faces) into convex parts")
    spent = 0.0 if load_started is None else max(0.0, time.process_time() - load_started)
    found, rungs = _ladder(mesh, config, label, progress, spent)
    seconds = sum(r.cpu_seconds for r in rungs)
    kept = rungs[-1]
    assert found.error is not None, "the ladder ends on a rung that gave parts (the hull at the last)"
    return _arrays(found.parts, found.error, kept.method, found.threshold, seconds, rungs)


def collision_geometry(
    mesh: trimesh.Trimesh,
    method: str,
    config: ObjectConfig,
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
    (the ladder: CoACD, V-HACD, hull, within ``config.decomposition_budget``).

    ``cache_dir``: the cache folder (None: :func:`default_cache_dir`). ``progress(object_id,
    message)`` hears when a decomposition starts, moves down the ladder and ends. Never raises for
    a decomposition that crashes or runs over its budget: the next rung's shape is the result.
    ``decompose=False``: :class:`NotDecomposed` instead of running the ladder when the cache does
    not hold its result (a hull or shells are still made here: they take a fraction of a second).
    ``load_started``: ``time.process_time()`` when the load began; the CPU this process used since
    then (reading, cleaning, repairing the mesh) is taken from the ladder's budget, so the whole
    load stays within ``decomposition_budget``.
    """
    if method not in ("hull", "shells", METHOD):
        raise ValueError(f"unknown collision method {method!r}")
    root = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    inputs = geometry_inputs(mesh, method, config, shells if method == "shells" else ())
    path = root / f"{inputs.key}.npz"
    label = object_id or path.stem[:12]
    geometry = _read_entry(path, label, inputs)
    if geometry is not None:
        return geometry
    if not decompose and method == METHOD:
        raise NotDecomposed(f"{label}: its decomposition is not in the cache {root}")
    with cache.advisory_lock(path.with_suffix(".lock")):
        geometry = _read_entry(path, label, inputs)  # another process may have made it meanwhile
        if geometry is not None:
            return geometry
        computed = _compute(mesh, method, config, list(shells), label, progress, load_started)
        cache.save_arrays(path, computed, inputs)
    geometry = _read_entry(path, label, inputs)  # fresh and cached: the same float64 entry
    if geometry is None:  # pragma: no cover - removed or damaged between the write and the read
        raise OSError(f"{label}: the collision cache entry {path} vanished after it was written")
    geometry.from_cache = False
    if method == METHOD:
        _say(
            progress,
            label,
            f"decomposed into {len(geometry.parts)} parts by {geometry.method} in {geometry.seconds:.1f} "
            f"CPU-s (collision error mean {geometry.error.mean * 1e3:.2f} mm, "
            f"max {geometry.error.max * 1e3:.2f} mm)",
        )
    return geometry
