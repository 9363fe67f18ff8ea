"""Run the job: objects -> candidates -> chunks of trials on joblib (or Dask) workers -> one writer.

Workers build their world once (PyBullet DIRECT, floating RG2) and keep it for every chunk they
get; an object body is created when a chunk of a new object arrives. Each candidate starts from
a restored snapshot, so labels depend only on (object, seed, candidate), never on which worker
ran it or what it ran before. The main process alone writes: one atomic Parquet file per object
as soon as all its chunks are in, then the manifest.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import joblib
import numpy as np
import pandas as pd

from annotator import dataset
from annotator.config import AnnotatorConfig
from annotator.dataset import Outcome
from annotator.geometry import Transform
from annotator.objects import (
    ObjectDiscoveryError,
    ObjectError,
    create_body,
    discover_objects,
)
from annotator.objects import load_object as _load_object
from annotator.sampler import object_rng, sample_candidates
from annotator.trial import Perturbation, trial_rng

log = logging.getLogger(__name__)

# Candidates per unit of work: small enough to balance 2..64 workers and show progress early,
# large enough that the per-chunk overhead (pickling, object body creation) stays < 1 %.
CHUNK_SIZE = 25


class UsageError(Exception):
    """The command cannot start (missing or empty folder, manifest mismatch): exit code 2."""


@dataclass(frozen=True)
class RunOptions:
    objects_dir: Path
    n: int
    out_dir: Path = Path("labels")
    workers: int = 1
    seed: int = 0
    trials: int = 1
    scheduler: str | None = None
    scale: float | None = None
    overwrite: bool = False
    quiet: bool = False


@dataclass
class ObjectStats:
    n: int
    successes: int
    outcomes: dict[str, int]
    seconds: float


@dataclass
class Summary:
    done: dict[str, ObjectStats] = field(default_factory=dict)
    skipped: list[str] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)
    seconds: float = 0.0
    candidates: int = 0
    physics_trials: int = 0
    sim_steps: int = 0
    worker_seconds: float = 0.0  # summed over workers
    step_seconds: float = 0.0  # of which inside stepSimulation
    first_label_seconds: float | None = None  # from start to the first label file written
    peak_rss_mb: dict[int, float] = field(default_factory=dict)  # per worker pid
    started: float = field(default_factory=time.perf_counter)  # perf_counter at the start


@dataclass(frozen=True)
class Chunk:
    """Candidates ``start..stop`` of one object, with their poses (stop - start, 4, 4)."""

    object_id: str
    source: object  # an annotator.objects.ObjectSource
    scale: float | None
    start: int
    T_obj_tcp: np.ndarray
    width: np.ndarray


# --- worker side -------------------------------------------------------------------------------

_WORKER: dict[str, object] = {}


def _worker_world(config: AnnotatorConfig):
    """This process's world and floating gripper, built on first use (one per worker)."""
    from annotator.sim.hand import FloatingRG2
    from annotator.sim.world import World

    if _WORKER.get("config") != config:
        if "world" in _WORKER:
            _WORKER["world"].close()
            _WORKER.pop("object", None)  # its body lived in the closed world
        world = World(config.physics)
        _WORKER.update(config=config, world=world, hand=FloatingRG2(world, config.gripper), object=None)
    return _WORKER["world"], _WORKER["hand"]


def _worker_trial(chunk: Chunk, config: AnnotatorConfig):
    """A GraspTrial for the chunk's object (the object body is created once per object)."""
    from annotator.trial import GraspTrial

    world, hand = _worker_world(config)
    # Worker processes outlive a run (joblib reuses them), so the key is the file as it is now,
    # not just the id: another run may have had a different object under the same id.
    stat = os.stat(chunk.source.path)
    key = (chunk.object_id, str(chunk.source.path), stat.st_mtime_ns, stat.st_size, chunk.scale)
    current = _WORKER.get("object")
    if current is None or current[0] != key:
        if current is not None:
            current[2].close()
            world.remove_body(current[1])
        model = _load_object(chunk.source, config.objects, scale=chunk.scale)
        hand.teleport(Transform([0.0, 0.0, 2.0], [0, 0, 0, 1]), hand.rg2.max_width)  # parked
        uid = create_body(world.client, model)
        world.set_gravity(False)
        _WORKER["object"] = (key, uid, GraspTrial(world, hand, uid, config), model)
    return _WORKER["object"][2], _WORKER["object"][3]


def simulate_chunk(
    chunk: Chunk, config: AnnotatorConfig, seed: int, trials: int = 1
) -> tuple[pd.DataFrame, dict]:
    """Label rows for one chunk and worker statistics (runs in a worker process).

    The statistics: ``seconds`` of worker time, ``step_seconds`` inside stepSimulation,
    ``peak_rss_mb`` of the worker process so far, its ``pid``.

    Trial 0 of each candidate is unperturbed and gives ``success``, ``outcome``, ``width`` and
    the pose; trials 1..K-1 are perturbed from the candidate's own Generator (trial_rng) and
    ``score`` is the fraction of all K trials that held.
    """
    t0 = time.perf_counter()
    trial, model = _worker_trial(chunk, config)
    step_seconds0 = trial.world.step_seconds
    rows = []
    for k in range(len(chunk.width)):
        grasp_id = chunk.start + k
        T = Transform.from_matrix(chunk.T_obj_tcp[k])
        held = 0
        try:
            r = trial.run(T, float(chunk.width[k]))
            outcome, T_label, width, steps, slip = r.outcome, r.T_obj_tcp, r.width, r.steps, r.slip
            held = int(outcome == Outcome.SUCCESS)
            rng = trial_rng(seed, chunk.object_id, grasp_id)
            for _ in range(trials - 1):
                p = trial.run(T, float(chunk.width[k]), Perturbation.sample(rng, config.robust))
                held += int(p.outcome == Outcome.SUCCESS)
                steps += p.steps
        except Exception as exc:  # a physics failure on one candidate must not lose the others
            log.warning("%s grasp %d: %s: %s", chunk.object_id, grasp_id, type(exc).__name__, exc)
            outcome, T_label, width, steps, slip = Outcome.ERROR, T, float(chunk.width[k]), 0, np.nan
            held = 0
        rows.append(
            {
                "object_id": chunk.object_id,
                "grasp_id": grasp_id,
                **dict(zip(("x", "y", "z"), T_label.pos.tolist(), strict=True)),
                **dict(zip(("qx", "qy", "qz", "qw"), _canonical(T_label.quat).tolist(), strict=True)),
                "width": width,
                "success": outcome == Outcome.SUCCESS,
                "outcome": outcome.label,
                "score": held / trials,
                "object_scale": model.scale,
                "mesh_sha256": model.mesh_sha256,
                "seed": seed,
                "sim_steps": steps,
                "slip": slip,
                "object_mass": model.mass,
            }
        )
    stats = {
        "seconds": time.perf_counter() - t0,
        "step_seconds": trial.world.step_seconds - step_seconds0,
        "peak_rss_mb": _peak_rss_mb(),
        "pid": os.getpid(),
    }
    return pd.DataFrame(rows), stats


def _peak_rss_mb() -> float:
    """This process's peak resident memory (MB); 0 where the platform does not say."""
    try:
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux
    except (ImportError, OSError):  # pragma: no cover - Windows
        return 0.0


def _canonical(q: np.ndarray) -> np.ndarray:
    return -q if q[3] < 0 else q


# --- main process ------------------------------------------------------------------------------


def _prepare(source, options: RunOptions, config: AnnotatorConfig, max_width: float):
    """Load, validate, decompose and sample one object (in a worker).

    Returns ``(candidates, None)`` or ``(None, one-line error)``.
    """
    try:
        model = _load_object(source, config.objects, scale=options.scale)
        rng = object_rng(options.seed, model.object_id)
        return sample_candidates(model.mesh, options.n, rng, config.sampler, max_width), None
    except ObjectError as exc:
        return None, str(exc)
    except Exception as exc:  # an unexpected failure is this object's, not the run's
        log.exception("%s: unexpected error while loading", source.object_id)
        return None, f"{type(exc).__name__}: {exc}"


def _max_width(config: AnnotatorConfig) -> float:
    """The RG2 stroke from the model's FK (a throwaway DIRECT client)."""
    from annotator.sim.hand import FloatingRG2
    from annotator.sim.world import World

    with World(config.physics) as world:
        return FloatingRG2(world, config.gripper).rg2.max_width


def _parallel(options: RunOptions):
    """(dask client or None, a function returning a fresh backend context for each use)."""
    if options.scheduler:
        try:
            from dask.distributed import Client
        except ImportError as exc:
            raise UsageError("--scheduler needs Dask: pip install 'rg2-annotator[cluster]'") from exc
        try:
            client = Client(options.scheduler)
        except (OSError, ValueError, TypeError) as exc:  # unreachable, timed out, malformed address
            raise UsageError(f"--scheduler {options.scheduler}: cannot connect ({exc})") from exc
        return client, lambda: joblib.parallel_config(backend="dask")
    return None, contextlib.nullcontext


def run(options: RunOptions, config: AnnotatorConfig) -> Summary:
    """The whole job; returns a summary (and logs it). Raises UsageError for exit code 2."""
    summary = Summary()
    t0 = summary.started
    try:
        sources = discover_objects(options.objects_dir)
    except ObjectDiscoveryError as exc:
        raise UsageError(str(exc)) from exc
    try:
        manifest = dataset.open_run(
            options.out_dir, config.to_dict(), options.seed, options.n, options.trials, options.overwrite
        )
    except dataset.ManifestMismatchError as exc:
        raise UsageError(str(exc)) from exc

    hashes = {s.object_id: dataset.file_sha256(s.path) for s in sources}  # the file given
    todo_ids = set(manifest.pending([s.object_id for s in sources], options.out_dir, hashes))
    summary.skipped = [s.object_id for s in sources if s.object_id not in todo_ids]
    if summary.skipped:
        log.info("resuming: %d objects already labelled, %d to do", len(summary.skipped), len(todo_ids))

    max_width = _max_width(config)
    client, backend = _parallel(options)
    chunks: list[Chunk] = []
    pending = [s for s in sources if s.object_id in todo_ids]
    with backend():
        # load, validate, decompose (cached by mesh hash) and sample every object in parallel
        prepared = joblib.Parallel(n_jobs=options.workers)(
            joblib.delayed(_prepare)(source, options, config, max_width) for source in pending
        )
    for source, (cands, error) in zip(pending, prepared, strict=True):
        if error is not None:
            summary.failed[source.object_id] = error
            manifest.mark_failed(source.object_id, error)
            log.error("%s: %s", source.object_id, error)
            continue
        for start in range(0, options.n, CHUNK_SIZE):
            stop = min(options.n, start + CHUNK_SIZE)
            chunks.append(
                Chunk(
                    source.object_id,
                    source,
                    options.scale,
                    start,
                    cands.T_obj_tcp[start:stop],
                    cands.width_expected[start:stop],
                )
            )
    manifest.save(options.out_dir)
    n_chunks = defaultdict(int)
    for c in chunks:
        n_chunks[c.object_id] += 1

    from tqdm.auto import tqdm

    results: dict[str, list[pd.DataFrame]] = defaultdict(list)
    worker_seconds: dict[str, float] = defaultdict(float)
    bar = tqdm(
        total=sum(len(c.width) for c in chunks),
        unit="grasp",
        disable=options.quiet,
        smoothing=0.1,
        dynamic_ncols=True,
    )
    try:
        with backend():
            parallel = joblib.Parallel(n_jobs=options.workers, return_as="generator_unordered")
            jobs = (joblib.delayed(simulate_chunk)(c, config, options.seed, options.trials) for c in chunks)
            for df, stats in parallel(jobs):
                oid = df["object_id"].iat[0]
                results[oid].append(df)
                worker_seconds[oid] += stats["seconds"]
                summary.worker_seconds += stats["seconds"]
                summary.step_seconds += stats["step_seconds"]
                summary.sim_steps += int(df["sim_steps"].sum())
                summary.peak_rss_mb[stats["pid"]] = stats["peak_rss_mb"]
                bar.update(len(df))
                summary.candidates += len(df)
                summary.physics_trials += int((df["outcome"] != Outcome.COLLISION.label).sum())
                if len(results[oid]) == n_chunks[oid]:
                    _finish_object(
                        oid, results.pop(oid), manifest, options, summary, hashes[oid], worker_seconds[oid]
                    )
    except KeyboardInterrupt:
        bar.close()
        log.info("interrupted: %d objects written this run", len(summary.done))
        raise
    finally:
        bar.close()
        if client is not None:
            client.close()
    summary.seconds = time.perf_counter() - t0
    _log_summary(summary, options)
    return summary


def _finish_object(oid, parts, manifest, options, summary, source_sha256, seconds) -> None:
    """Write one object's labels atomically, then record it in the manifest."""
    df = pd.concat(parts, ignore_index=True).sort_values("grasp_id", ignore_index=True)
    path = dataset.write_object_labels(options.out_dir, df)
    manifest.mark_done(oid, path, len(df), source_sha256)
    manifest.save(options.out_dir)
    if summary.first_label_seconds is None:
        summary.first_label_seconds = time.perf_counter() - summary.started
    counts = df["outcome"].value_counts().to_dict()
    summary.done[oid] = ObjectStats(len(df), int(df["success"].sum()), counts, seconds)


def format_summary(summary: Summary) -> str:
    """A per-object table: n, success rate, outcome counts, time; then failures and totals."""
    cols = list(dataset.OUTCOMES)
    head = (
        f"{'object':<28} {'n':>5} {'success':>8} " + " ".join(f"{c[:9]:>9}" for c in cols) + f" {'time':>7}"
    )
    lines = [head, "-" * len(head)]
    for oid, st in sorted(summary.done.items()):
        rate = st.successes / st.n if st.n else 0.0
        counts = " ".join(f"{st.outcomes.get(c, 0):>9}" for c in cols)
        lines.append(f"{oid[:28]:<28} {st.n:>5} {rate:>8.1%} {counts} {st.seconds:>6.1f}s")
    for oid in summary.skipped:
        lines.append(f"{oid[:28]:<28} already done (resumed)")
    for oid, err in sorted(summary.failed.items()):
        lines.append(f"{oid[:28]:<28} FAILED: {err}")
    rate = summary.candidates / summary.seconds if summary.seconds else 0.0
    lines.append(
        f"{len(summary.done)} objects labelled, {len(summary.skipped)} skipped, "
        f"{len(summary.failed)} failed; "
        f"{summary.candidates} candidates in {summary.seconds:.1f} s ({rate:.1f} candidates/s, "
        f"{summary.physics_trials} physics trials)"
    )
    return "\n".join(lines)


def _log_summary(summary: Summary, options: RunOptions) -> None:
    text = format_summary(summary)
    # the summary is the command's result: printed to stdout even with --quiet
    import click

    click.echo(text, err=False)
    log.debug("summary printed for %s", os.fspath(options.out_dir))
