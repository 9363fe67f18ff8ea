"""Run the job: objects -> spans of candidates on joblib (or Dask) workers -> one writer.

The main process only discovers the objects and hands out spans (candidates start..stop of one
object); it never loads a mesh, so work starts at once. Workers build their world once (PyBullet
DIRECT, floating RG2) and keep it; when a span of a new object arrives they load the object
(the convex decomposition comes from the cache), sample its N candidates (the same on every
worker: the Generator is keyed on seed and object id) and create its body. Each candidate starts
from a restored snapshot, so labels depend only on (object, seed, candidate), never on which
worker ran it or what it ran before. The main process alone writes: one atomic Parquet file per
span as soon as it is back, merged into the object's file when its last span is in.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import threading
import time
from collections import Counter, defaultdict
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
from annotator.pipeline import store
from annotator.sampler import object_rng, sample_candidates
from annotator.trial import Perturbation, trial_rng

log = logging.getLogger(__name__)

# Candidates per unit of work (and per chunk file): small enough that the first labels are on disk
# within seconds, that 2..64 workers stay balanced and that an interrupt loses little; large
# enough that the per-span overhead (pickling, a chunk file, a manifest save) stays ~ 1 %.
CHUNK_SIZE = 10
# The manifest (which vouches for chunk files) is saved at most this often while chunks come in,
# always when an object is merged and when the run ends or is interrupted; a hard kill loses at
# most this many seconds of chunks (unvouched chunk files are redone on resume).
MANIFEST_SAVE_SECONDS = 2.0


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


@dataclass(frozen=True)
class Span:
    """A unit of work for the runner: candidates ``start..stop-1`` of one object.

    The worker samples the object's N candidates itself (once per object, cached) and simulates
    this slice, so the main process never waits for objects to be loaded before work starts.
    """

    object_id: str
    source: object  # an annotator.objects.ObjectSource
    scale: float | None
    start: int
    stop: int


@dataclass
class _Loaded:
    """The object a worker has in its world: body, trial runner, model, sampled candidates."""

    key: tuple
    uid: int
    trial: object  # annotator.trial.GraspTrial
    model: object  # annotator.objects.ObjectModel
    candidates: dict[tuple, object] = field(default_factory=dict)  # (seed, n) -> Candidates


_WORKER: dict[str, object] = {}


def _worker_world(config: AnnotatorConfig):
    """This process's world and floating gripper, built on first use (one per worker)."""
    from annotator.sim.hand import FloatingRG2
    from annotator.sim.world import World

    if _WORKER.get("config") != config:
        if "world" in _WORKER:
            _WORKER["world"].close()
        world = World(config.physics)
        _WORKER.update(config=config, world=world, hand=FloatingRG2(world, config.gripper), object=None)
        _WORKER["failed"] = {}
    return _WORKER["world"], _WORKER["hand"]


def _object_key(object_id: str, source, scale: float | None) -> tuple:
    # Worker processes outlive a run (joblib reuses them), so the key is the file as it is now,
    # not just the id: another run may have had a different object under the same id.
    stat = os.stat(source.path)
    return (object_id, str(source.path), stat.st_mtime_ns, stat.st_size, scale)


def _worker_object(object_id: str, source, scale: float | None, config: AnnotatorConfig) -> _Loaded:
    """The worker's loaded object (its body is created once per object); raises ObjectError."""
    from annotator.trial import GraspTrial

    world, hand = _worker_world(config)
    try:
        key = _object_key(object_id, source, scale)
    except OSError as exc:
        raise ObjectError(f"cannot read {source.path}: {exc.strerror or exc}") from exc
    if key in _WORKER["failed"]:
        raise ObjectError(_WORKER["failed"][key])
    current: _Loaded | None = _WORKER.get("object")
    if current is None or current.key != key:
        if current is not None:
            current.trial.close()
            world.remove_body(current.uid)
            _WORKER["object"] = None
        try:
            model = _load_object(source, config.objects, scale=scale)
        except ObjectError as exc:
            _WORKER["failed"][key] = str(exc)
            raise
        hand.teleport(Transform([0.0, 0.0, 2.0], [0, 0, 0, 1]), hand.rg2.max_width)  # parked
        uid = create_body(world.client, model)
        world.set_gravity(False)
        _WORKER["object"] = _Loaded(key, uid, GraspTrial(world, hand, uid, config), model)
    return _WORKER["object"]


def object_candidates(model, n: int, seed: int, config: AnnotatorConfig, max_width: float):
    """The object's N candidates: the same for every worker (Generator keyed on seed and id)."""
    return sample_candidates(model.mesh, n, object_rng(seed, model.object_id), config.sampler, max_width)


def label_span(
    span: Span, config: AnnotatorConfig, seed: int, n: int, trials: int = 1
) -> tuple[Span, pd.DataFrame | None, str | None, dict]:
    """Labels of one span (runs in a worker): ``(span, rows, None, stats)`` or
    ``(span, None, error, stats)``.

    ``error`` is the object's one-line reason (it cannot be loaded or sampled); the other spans of
    that object fail the same way at once, without loading it again.
    """
    t0 = time.perf_counter()
    try:
        loaded = _worker_object(span.object_id, span.source, span.scale, config)
        cands = loaded.candidates.get((seed, n))
        if cands is None:
            _, hand = _worker_world(config)
            cands = object_candidates(loaded.model, n, seed, config, hand.rg2.max_width)
            loaded.candidates[(seed, n)] = cands
    except ObjectError as exc:
        return span, None, str(exc), _stats(t0, 0.0)
    except Exception as exc:  # an unexpected failure is this object's, not the run's
        log.exception("%s: unexpected error while loading", span.object_id)
        return span, None, f"{type(exc).__name__}: {exc}", _stats(t0, 0.0)
    chunk = Chunk(
        span.object_id,
        span.source,
        span.scale,
        span.start,
        cands.T_obj_tcp[span.start : span.stop],
        cands.width_expected[span.start : span.stop],
    )
    df, stats = simulate_chunk(chunk, config, seed, trials, loaded)
    return span, df, None, _stats(t0, stats["step_seconds"])


def _stats(t0: float, step_seconds: float) -> dict:
    """Worker statistics of one unit of work (see simulate_chunk)."""
    return {
        "seconds": time.perf_counter() - t0,
        "step_seconds": step_seconds,
        "peak_rss_mb": _peak_rss_mb(),
        "pid": os.getpid(),
    }


def simulate_chunk(
    chunk: Chunk, config: AnnotatorConfig, seed: int, trials: int = 1, loaded: _Loaded | None = None
) -> tuple[pd.DataFrame, dict]:
    """Label rows for one chunk and worker statistics (runs in a worker process).

    The statistics: ``seconds`` of worker time, ``step_seconds`` inside stepSimulation,
    ``peak_rss_mb`` of the worker process so far, its ``pid``.

    Trial 0 of each candidate is unperturbed and gives ``success``, ``outcome``, ``width`` and
    the pose; trials 1..K-1 are perturbed from the candidate's own Generator (trial_rng) and
    ``score`` is the fraction of all K trials that held. ``loaded``: the chunk's object if the
    caller has already loaded it in this worker (label_span).
    """
    t0 = time.perf_counter()
    if loaded is None:
        loaded = _worker_object(chunk.object_id, chunk.source, chunk.scale, config)
    trial, model = loaded.trial, loaded.model
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
            rng = trial_rng(seed, chunk.object_id, grasp_id) if trials > 1 else None
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
    return pd.DataFrame(rows), _stats(t0, trial.world.step_seconds - step_seconds0)


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


def _spans(options: RunOptions, sources, manifest, out_dir: Path, hashes) -> tuple[list[Span], dict]:
    """The spans still to simulate, and each pending object's chunks already on disk.

    Order: the first span of every object, then the rest object by object. On a first run the
    workers thus load (and convex-decompose) different objects at once instead of the same one.
    """
    first: list[Span] = []
    rest: list[Span] = []
    done_before: dict[str, dict[tuple[int, int], str]] = {}
    for source in sources:
        planned = [(a, min(options.n, a + CHUNK_SIZE)) for a in range(0, options.n, CHUNK_SIZE)]
        recorded = manifest.chunks_of(source.object_id, out_dir, hashes[source.object_id])
        done = {r: f for r, f in recorded.items() if r in planned}
        done_before[source.object_id] = done
        # chunks the manifest does not vouch for (written just before a stop, of a changed mesh,
        # or of another chunk size) are deleted and their spans redone
        store.remove_chunks(out_dir, source.object_id, keep=done.values())
        todo = [Span(source.object_id, source, options.scale, a, b) for a, b in planned if (a, b) not in done]
        first += todo[:1]
        rest += todo[1:]
    return first + rest, done_before


def run(options: RunOptions, config: AnnotatorConfig) -> Summary:
    """The whole job; returns a summary (and logs it). Raises UsageError for exit code 2."""
    summary = Summary()
    try:
        sources = discover_objects(options.objects_dir)
    except ObjectDiscoveryError as exc:
        raise UsageError(str(exc)) from exc
    try:
        manifest = store.open_run(
            options.out_dir, config.to_dict(), options.seed, options.n, options.trials, options.overwrite
        )
    except store.ManifestMismatchError as exc:
        raise UsageError(str(exc)) from exc

    hashes = {s.object_id: store.file_sha256(s.path) for s in sources}  # the file given
    todo_ids = set(manifest.pending([s.object_id for s in sources], options.out_dir, hashes))
    summary.skipped = [s.object_id for s in sources if s.object_id not in todo_ids]
    pending = [s for s in sources if s.object_id in todo_ids]
    spans, done_before = _spans(options, pending, manifest, options.out_dir, hashes)
    if summary.skipped or any(done_before.values()):
        log.info(
            "resuming: %d objects already labelled, %d chunks of unfinished objects kept; %d to do",
            len(summary.skipped),
            sum(len(d) for d in done_before.values()),
            len(pending),
        )
    remaining = Counter(sp.object_id for sp in spans)  # spans still out, per object
    for oid in [s.object_id for s in pending if remaining[s.object_id] == 0]:  # all chunks on disk
        _finish_object(oid, manifest, options, summary, hashes[oid], 0.0)

    client, backend = _parallel(options)
    from tqdm.auto import tqdm

    worker_seconds: dict[str, float] = defaultdict(float)
    saved = time.perf_counter()  # when the manifest was last saved
    bar = tqdm(
        total=sum(sp.stop - sp.start for sp in spans),
        unit="grasp",
        disable=options.quiet,
        smoothing=0.1,
        dynamic_ncols=True,
    )
    try:
        with backend():
            parallel = joblib.Parallel(n_jobs=options.workers, return_as="generator_unordered")
            task = joblib.delayed(label_span)
            jobs = (task(sp, config, options.seed, options.n, options.trials) for sp in spans)
            for span, df, error, stats in parallel(jobs):
                oid = span.object_id
                bar.update(span.stop - span.start)
                summary.worker_seconds += stats["seconds"]
                summary.peak_rss_mb[stats["pid"]] = stats["peak_rss_mb"]
                if error is not None:
                    if oid not in summary.failed:
                        summary.failed[oid] = error
                        manifest.mark_failed(oid, error)
                        manifest.save(options.out_dir)
                        store.remove_chunks(options.out_dir, oid)  # no partial labels of it stay
                        log.error("%s: %s", oid, error)
                    continue
                if oid in summary.failed:  # another worker could load it; the object is failed
                    continue
                worker_seconds[oid] += stats["seconds"]
                summary.step_seconds += stats["step_seconds"]
                summary.sim_steps += int(df["sim_steps"].sum())
                summary.candidates += len(df)
                summary.physics_trials += int((df["outcome"] != Outcome.COLLISION.label).sum())
                path = store.write_chunk_labels(options.out_dir, df, span.start)
                manifest.mark_chunk(oid, span.start, path, len(df), hashes[oid])
                if summary.first_label_seconds is None:
                    summary.first_label_seconds = time.perf_counter() - summary.started
                remaining[oid] -= 1
                if remaining[oid] == 0:
                    _finish_object(oid, manifest, options, summary, hashes[oid], worker_seconds[oid])
                    saved = time.perf_counter()
                elif time.perf_counter() - saved > MANIFEST_SAVE_SECONDS:
                    manifest.save(options.out_dir)
                    saved = time.perf_counter()
    except KeyboardInterrupt:
        bar.close()
        log.info("interrupted: %d candidates written this run", summary.candidates)
        raise
    finally:
        manifest.save(options.out_dir)  # every chunk written so far, also on Ctrl-C or an error
        bar.close()
        if client is not None:
            client.close()
    summary.seconds = time.perf_counter() - summary.started
    _log_summary(summary, options)
    return summary


@contextlib.contextmanager
def _sigint_deferred():
    """Hold back Ctrl-C (in the main thread) until the block is done, then raise it."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: received.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if received:
            raise KeyboardInterrupt


def _finish_object(oid, manifest, options, summary, source_sha256, seconds) -> None:
    """Merge one object's chunk files into its label file, record it, delete the chunks.

    Ctrl-C waits for the three steps, so the folder never holds an object's file and its chunks.
    """
    files = manifest.chunks_of(oid, options.out_dir, source_sha256)
    df = store.merge_chunks(options.out_dir, oid, [files[k] for k in sorted(files)])
    with _sigint_deferred():
        path = store.write_object_labels(options.out_dir, df)
        manifest.mark_done(oid, path, len(df), source_sha256)
        manifest.save(options.out_dir)
        store.remove_chunks(options.out_dir, oid)
    counts = df["outcome"].value_counts().to_dict()
    summary.done[oid] = ObjectStats(len(df), int(df["success"].sum()), counts, seconds)


def format_summary(summary: Summary) -> str:
    """A per-object table: n, success rate, outcome counts, time; then failures and totals."""
    cols = list(dataset.OUTCOMES)
    head = f"{'object':<28} {'n':>5} {'rate':>8} " + " ".join(f"{c[:9]:>9}" for c in cols) + f" {'time':>7}"
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
