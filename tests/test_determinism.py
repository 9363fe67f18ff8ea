"""Labels depend on (object, seed, candidate) only: not on what a worker's world did before.

Concave, decomposed objects (the ring has a dozen convex parts, the banana two) show what boxes
hide: Bullet keeps contact manifolds, with the impulses that warm-start its solver, across
``restoreState``; a trial then depended on the trial before it.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from annotator.config import AnnotatorConfig
from annotator.objects import discover_objects
from annotator.pipeline import object_cache, worker
from annotator.pipeline.modes import CellMode
from annotator.pipeline.tasks import Span, SpanTask

SAMPLES = Path(__file__).resolve().parents[1] / "objects"
N = 30  # three spans per object


@pytest.fixture(scope="module")
def concave(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("concave")
    for name in ("ring.off", "banana.obj"):
        shutil.copy(SAMPLES / name, folder)
    return folder


@pytest.fixture(scope="module")
def cache(shape_cache):
    """The run's shared decomposition cache as the default cache of this module's workers."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("RG2_CACHE_DIR", str(shape_cache))
        yield shape_cache


def _fresh_worker() -> None:
    worker.worker_state().close()
    worker._State.instance = None


def _run(spans, config) -> pd.DataFrame:
    frames = []
    for span in spans:
        result = worker.label_span(SpanTask(span=span, config=config, seed=0, n=N))
        assert result.error is None, result.error
        frames.append(result.rows)
    return pd.concat(frames).sort_values(["object_id", "grasp_id"]).reset_index(drop=True)


@pytest.mark.slow
def test_span_results_do_not_depend_on_the_worker_history(concave, cache):
    config = AnnotatorConfig()
    sources = discover_objects(concave)
    spans = [Span(s.object_id, s, None, a, a + 10) for s in sources for a in range(0, N, 10)]
    _fresh_worker()
    reference = _run(spans, config)
    assert (reference["outcome"] != "collision").sum() >= 10  # enough trials reach the physics
    # one worker, the spans dealt in a shuffled order, objects interleaved, every span twice
    order = np.random.default_rng(7).permutation(len(spans)).tolist()
    _fresh_worker()
    shuffled = _run([spans[i] for i in order] + [spans[i] for i in order[::-1]], config)
    shuffled = shuffled.drop_duplicates(["object_id", "grasp_id"], keep="last").reset_index(drop=True)
    pd.testing.assert_frame_equal(shuffled, reference, check_exact=True)
    _fresh_worker()


@pytest.mark.slow
@pytest.mark.parametrize("budget", [object_cache.RECENT_OBJECT_BYTES, 0])
def test_a_worker_returning_to_an_object_reuses_it_within_the_memory_budget(
    concave, cache, monkeypatch, budget
):
    """Spans dealt as the plan deals them (each object's first span, then the rest): a worker that
    comes back to an object reuses its model and candidates when they fit the budget, else loads
    and samples it again; the labels are the same bit for bit either way."""
    config = AnnotatorConfig()
    sources = discover_objects(concave)
    firsts = [Span(s.object_id, s, None, 0, 10) for s in sources]
    rest = [Span(s.object_id, s, None, a, a + 10) for s in sources for a in range(10, N, 10)]
    _fresh_worker()
    reference = _run(firsts + rest, config)
    loads, samplings = [], []
    from annotator.pipeline import loaded, object_modes  # the loader; the floating mode samples

    load_object, object_candidates = loaded.load_object, object_modes.object_candidates
    monkeypatch.setattr(
        loaded, "load_object", lambda source, *a, **k: loads.append(source) or load_object(source, *a, **k)
    )
    monkeypatch.setattr(
        object_modes,
        "object_candidates",
        lambda model, *a: samplings.append(model) or object_candidates(model, *a),
    )
    monkeypatch.setattr(object_cache, "RECENT_OBJECT_BYTES", budget)
    _fresh_worker()
    again = _run(firsts + rest, config)
    pd.testing.assert_frame_equal(again, reference, check_exact=True)
    expected = len(sources) if budget else 2 * len(sources)  # once, or once per pass
    assert len(loads) == expected and len(samplings) == expected
    _fresh_worker()


@pytest.mark.slow
def test_labels_do_not_depend_on_another_worlds_contact_breaking_threshold(concave, cache):
    """PyBullet keeps one contact breaking threshold per process: a world made since (here one
    at PyBullet's 0.02 m) must not decide the contacts of the worker's world (at 5 mm)."""
    import dataclasses

    from annotator.sim.world import World

    base = AnnotatorConfig()
    config = dataclasses.replace(
        base, physics=dataclasses.replace(base.physics, contact_breaking_threshold=0.005)
    )
    other = dataclasses.replace(
        base, physics=dataclasses.replace(base.physics, contact_breaking_threshold=0.02)
    )
    source = next(s for s in discover_objects(concave) if s.object_id == "banana")
    span = Span(source.object_id, source, None, 0, N)
    _fresh_worker()
    alone = _run([span], config)
    with_other = _run([span], other)
    assert not with_other.equals(alone)  # the threshold matters to these trials
    _fresh_worker()
    _run([span], config)  # the worker's world at 5 mm ...
    with World(other.physics):  # ... then another world sets 0.02 m for the process
        again = _run([span], config)
    pd.testing.assert_frame_equal(again, alone, check_exact=True)
    _fresh_worker()


def _annotate(objs: Path, out: Path, *extra) -> pd.DataFrame:
    from click.testing import CliRunner

    from annotator.cli import annotate_command

    args = ["--objects", str(objs), "--n", str(N), "--out", str(out), "--quiet", *map(str, extra)]
    result = CliRunner().invoke(annotate_command, args, catch_exceptions=False)
    assert result.exit_code == 0, result.output
    return pd.read_parquet(out).sort_values(["object_id", "grasp_id"]).reset_index(drop=True)


@pytest.mark.slow
@pytest.mark.cluster
def test_labels_are_identical_cold_or_warm_on_any_worker_layout(concave, tmp_path, monkeypatch):
    """Decomposed concave objects: a first run (empty cache, 2 workers) equals later runs with the
    parts read back from the cache (1 worker, 2 workers, a Dask cluster), column for column."""
    monkeypatch.setenv("RG2_CACHE_DIR", str(tmp_path / "fresh-cache"))
    cold = _annotate(concave, tmp_path / "cold", "--workers", 2)
    assert list((tmp_path / "fresh-cache").glob("*")), "nothing was decomposed: the test would hide the cache"
    warm1 = _annotate(concave, tmp_path / "warm1", "--workers", 1)
    pd.testing.assert_frame_equal(warm1, cold, check_exact=True)
    warm2 = _annotate(concave, tmp_path / "warm2", "--workers", 2)
    pd.testing.assert_frame_equal(warm2, cold, check_exact=True)
    distributed = pytest.importorskip("dask.distributed")
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as c:
        dask = _annotate(concave, tmp_path / "dask", "--scheduler", c.scheduler_address)
    pd.testing.assert_frame_equal(dask, cold, check_exact=True)


# --- the cell (annotate --cell --views) ------------------------------------------------------------

CELL_N = 20
QUICK_VIEWS = AnnotatorConfig.from_dict({"kinect": {"views_color_scale": 0.25}})


def _run_cell(spans, config, cell) -> tuple[pd.DataFrame, dict[str, bytes]]:
    frames, artifacts = [], {}
    for span in spans:
        result = worker.label_span(SpanTask(span=span, config=config, seed=0, n=CELL_N, mode=cell))
        assert result.error is None, result.error
        frames.append(result.rows)
        for name, data in (result.artifacts or {}).items():
            artifacts[f"{span.object_id}/{name}"] = data
    rows = pd.concat(frames).sort_values(["object_id", "grasp_id"]).reset_index(drop=True)
    return rows, artifacts


@pytest.mark.slow
def test_cell_rows_and_views_do_not_depend_on_the_worker_history(cache):
    """Objects resting on the table (settled placements, reach checks in the arm world, rendered
    views): spans dealt shuffled, interleaved and twice to one worker give the rows and the image
    bytes of a fresh worker; and a floating span after cell spans is the floating span of a fresh
    worker (the modes leave nothing behind)."""
    sources = [s for s in discover_objects(SAMPLES) if s.object_id in ("box", "banana")]
    spans = [Span(s.object_id, s, None, a, a + 10) for s in sources for a in range(0, CELL_N, 10)]
    cell = CellMode(views=1)
    _fresh_worker()
    reference, ref_views = _run_cell(spans, QUICK_VIEWS, cell)
    assert reference["reachable"].any() and (reference["outcome"] != "collision").sum() >= 3
    assert len(ref_views) == 4 * len(set(reference[["object_id", "placement_id"]].itertuples(index=False)))
    _fresh_worker()
    floating_fresh = _run(spans[:1], QUICK_VIEWS)
    order = np.random.default_rng(3).permutation(len(spans)).tolist()
    _fresh_worker()
    shuffled, views = _run_cell(
        [spans[i] for i in order] + [spans[i] for i in order[::-1]], QUICK_VIEWS, cell
    )
    shuffled = shuffled.drop_duplicates(["object_id", "grasp_id"], keep="last").reset_index(drop=True)
    pd.testing.assert_frame_equal(shuffled, reference, check_exact=True)
    assert views == ref_views
    pd.testing.assert_frame_equal(_run(spans[:1], QUICK_VIEWS), floating_fresh, check_exact=True)
    _fresh_worker()


@pytest.mark.slow
def test_cell_labels_and_views_are_identical_on_any_worker_count(concave, cache, tmp_path):
    """With the objects' shapes in the cache (cold or warm is the test above), one and two workers
    give the same cell rows and view files."""
    import hashlib

    config = tmp_path / "views.toml"
    config.write_text("[kinect]\nviews_color_scale = 0.25\n")
    outs = []
    for workers in (1, 2):
        out = tmp_path / f"w{workers}"
        outs.append(_annotate(concave, out, "--cell", "--views", 1, "--workers", workers, "--config", config))
        digests = {
            str(p.relative_to(out)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted((out / "_views").rglob("*"))
            if p.is_file()
        }
        outs.append(digests)
    pd.testing.assert_frame_equal(outs[2], outs[0], check_exact=True)
    assert outs[1] and outs[3] == outs[1]
