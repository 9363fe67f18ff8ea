"""The benches that time or measure simulation run it through the runner's execution
(:func:`annotator.pipeline.in_memory.run_in_memory`), with real pybullet: what comes back from a
worker is what the same work gives in this process, and the CPU time a bench reports is the
worker's own."""

from __future__ import annotations

import tempfile
from pathlib import Path

import pandas as pd
import pytest

from annotator.config import AnnotatorConfig
from annotator.objects import discover_objects
from annotator.pipeline.in_memory import ExecutionOptions
from annotator.pipeline.process import current_watch
from annotator.pipeline.tasks import Call, Span, SpanTask
from annotator.pipeline.worker import label_span, label_span_within, perform
from bench import gripper_speed, trials_cost
from bench.experiments import light_objects, light_threshold

SAMPLES = Path(__file__).resolve().parent.parent / "objects"


def sample(*names: str) -> list:
    return [s for s in discover_objects(SAMPLES) if s.object_id in names]


@pytest.mark.slow
def test_trials_costs_labels_are_the_workers_and_its_cpu_is_the_workers_own():
    sources = sample("box", "can")
    config = AnnotatorConfig()
    rows, cpu = trials_cost.label(sources, 4, 2, config, ExecutionOptions(workers=1))
    here = [
        label_span(SpanTask(span=Span(s.object_id, s, None, 0, 4), config=config, seed=0, n=4, trials=2)).rows
        for s in sources
    ]
    assert rows.equals(pd.concat(here, ignore_index=True))
    timed = trials_cost.timed_span(
        SpanTask(span=Span("box", sources[0], None, 0, 4), config=config, seed=0, n=4, trials=2)
    )
    assert timed.result.error is None and timed.cpu_s > 0
    assert 0 < cpu  # the workers' seconds: this process only waited


@pytest.mark.slow
def test_gripper_speed_counts_what_the_worker_labelled():
    sources = sample("box")
    done = gripper_speed.label_all(sources, "panda", 5, AnnotatorConfig(), ExecutionOptions(workers=1))
    assert done.candidates == 5 and 0 <= done.simulated <= 5 and done.cpu_s > 0


@pytest.mark.slow
def test_a_plates_measurement_through_the_runner_is_the_one_made_in_process():
    plate = light_objects.Plate(4.0, 240.0, 30)
    (got,) = light_objects.measure_all([plate], workers=1)
    with tempfile.TemporaryDirectory() as tmp:
        here = light_objects.measure(4.0, 240.0, 30, Path(tmp))
    assert got == here and got.simulated > 0
    assert [(p.grams, p.hz) for p in light_objects.plates([4.0], [240.0, 480.0], 30)] == [
        (4.0, 240.0),
        (4.0, 480.0),
    ]
    physics = AnnotatorConfig().physics
    heavy = light_objects.plates([1000.0], None, 30)
    assert [p.hz for p in heavy] == [1.0 / physics.time_step]  # simulated at time_step: one rate


@pytest.mark.slow
def test_a_light_threshold_cell_through_the_runner_is_the_one_made_in_process():
    """One (shape, mass, seed) of light_threshold's grid: the fine reference and 1/240 s, from a
    worker and in this process, agree row for row (successes, agreement, widths)."""
    cell = ("cube40", 40.0, 0, 6, 4, "", False, [("default", "")])
    (got,) = light_threshold.measure_grid([cell], AnnotatorConfig(), workers=1)
    here = light_threshold.row(cell)
    assert got == here
    (name, shape, grams, seed, simulated, *_), *_ = got
    assert (name, shape, grams, seed) == ("default", "cube40", 40.0, 0) and simulated > 0


def _watch_after(label, task):
    """Label ``task``'s span with ``label``, then what this process watches (a Call's function)."""
    label(task)
    return current_watch()


@pytest.mark.slow
def test_a_span_labelled_within_a_call_keeps_the_calls_stop_folder(tmp_path):
    """A bench's Call that labels a span inside it (trials_cost's timed span) keeps the call's stop
    folder while the span runs, so a Ctrl-C's stop request reaches it; the span as the bench built it
    (no folder of its own) would have cleared it."""
    source = sample("box")[0]
    config = AnnotatorConfig()
    task = SpanTask(span=Span("box", source, None, 0, 2), config=config, seed=0, n=2)
    folder = str(tmp_path / "status")
    within = perform(Call(fn=_watch_after, args=(label_span_within, task), config=config, status_dir=folder))
    plain = perform(Call(fn=_watch_after, args=(label_span, task), config=config, status_dir=folder))
    assert within.error is None and within.value == (None, folder)
    assert plain.error is None and plain.value == (None, None)
