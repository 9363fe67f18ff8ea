"""One rung of the collision ladder in an isolated child process: CoACD has segfaulted and hung on
real meshes, so each decomposition runs in its own process (:func:`child_main`) under the CPU
limit the ladder gives it (:mod:`annotator.objects.limited_process`), with one OpenMP thread
(workers already run one per core; CoACD's parts are the same with 1 and 2 threads). The child
saves its best parts so far as it goes, so a rung stopped by its limit keeps what it finished.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from annotator.config import DecompositionConfig
from annotator.objects import cache
from annotator.objects.collision_entry import Rung, entry_arrays, entry_geometry
from annotator.objects.decomposers import METHOD, REMESHED, refine_coacd, run_vhacd
from annotator.objects.fidelity import CollisionError, collision_error
from annotator.objects.limited_process import Checkpoint, describe_exit, limit_own_cpu, run_limited


def save_result(
    job: Path, parts: list[trimesh.Trimesh], error: CollisionError, threshold: float, done: bool
) -> None:
    """Write ``job/out.npz``: ``parts`` (metres, mesh frame), their ``error`` and CoACD
    ``threshold``; ``done``: the rung finished (not only its best so far)."""
    arrays = entry_arrays(parts, error, "", threshold, 0.0)
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
    limit_own_cpu(cpu_limit)
    config = dataclasses.replace(DecompositionConfig(), **fields)
    if rung in (METHOD, REMESHED):
        parts, error, threshold = refine_coacd(
            vertices, faces, config, lambda p, e, t: save_result(src, p, e, t, done=False), rung == REMESHED
        )
        save_result(src, parts, error, threshold, done=True)
        return
    parts = run_vhacd(vertices, faces, config, src)
    if parts:
        mesh = trimesh.Trimesh(vertices, faces, process=False)
        save_result(src, parts, collision_error(mesh, parts, config.collision_error_samples), 0.0, True)


def child_command(job: Path) -> list[str]:
    """The command that runs one decomposition job in its own process (a test seam)."""
    code = "import sys; from annotator.objects.decomposition_child import child_main; child_main(sys.argv[1])"
    return [sys.executable, "-c", code, str(job)]


@dataclass
class RungParts:
    """What a child rung gave: parts and their error (None: nothing), and how the rung went."""

    rung: Rung
    parts: list[trimesh.Trimesh] = field(default_factory=list)
    error: CollisionError | None = None
    threshold: float = 0.0


def child_rung(
    mesh: trimesh.Trimesh,
    config: DecompositionConfig,
    method: str,
    cpu_limit: float,
    first_parts: float | None = None,
) -> RungParts:
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
        run = run_limited(child_command(job), cpu_limit, config.timeout, job, checkpoint)
        try:
            out = cache.load_arrays(job / "out.npz")
            geometry = entry_geometry(out, job)
            done = bool(out["done"])
        except (FileNotFoundError, cache.CorruptEntry, ValueError, KeyError):
            geometry, done = None, False
    if run.over_cpu:
        outcome, detail = "over budget", f"stopped at {run.cpu_seconds:.0f} CPU-s"
    elif run.stalled:
        outcome, detail = "over budget", f"stopped after {config.timeout:g} s without using CPU"
    elif run.returncode != 0:
        outcome = "crashed"
        detail = describe_exit(run.returncode) + (f": {run.stderr}" if run.stderr else "")
    else:
        outcome, detail = ("kept" if geometry is not None else "no parts"), ""
    if geometry is None:
        return RungParts(Rung(method, outcome, run.cpu_seconds, detail=detail))
    if not done:  # stopped during a finer threshold: the best one it finished stays
        detail = f"{outcome}: {detail}" if detail else outcome
        outcome = "kept"
    rung = Rung(method, "kept", run.cpu_seconds, geometry.threshold, geometry.error, detail)
    return RungParts(rung, geometry.parts, geometry.error, geometry.threshold)
