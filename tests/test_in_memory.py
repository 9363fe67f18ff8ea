"""Simulation without an output folder runs through the runner's execution: the same worker entry
points with the context every task carries (versions, the main process, the status folder, the
cache), results in the order of the tasks, a worker that dies retried once and then reported, and
what a call raises raised again where its result is taken."""

from __future__ import annotations

import os
from pathlib import Path

import pandas as pd
import pytest

from annotator.config import AnnotatorConfig
from annotator.objects import discover_objects
from annotator.pipeline.in_memory import ExecutionOptions, Failed, call_values, run_in_memory
from annotator.pipeline.tasks import Call, Span, SpanResult, SpanTask
from annotator.pipeline.worker import label_span

SAMPLES = Path(__file__).resolve().parent.parent / "objects"
CONFIG = AnnotatorConfig()


def context_of(what: str) -> dict:
    """A call that says what context its task came with (run in a worker)."""
    return {"pid": os.getpid(), "what": what}


def raise_value_error(what: str) -> None:
    raise ValueError(f"no {what}")


def die(code: int) -> None:
    os._exit(code)  # as a segfault would end the worker


@pytest.mark.slow
def test_spans_in_memory_are_the_workers_labels_in_task_order():
    box = next(s for s in discover_objects(SAMPLES) if s.object_id == "box")
    spans = [Span("box", box, None, a, a + 5) for a in (10, 0, 5)]
    tasks = [SpanTask(span=s, config=CONFIG, seed=0, n=15) for s in spans]
    results = run_in_memory(tasks, ExecutionOptions(workers=2))
    assert [r.span.start for r in results] == [10, 0, 5]
    assert all(isinstance(r, SpanResult) and r.error is None for r in results)
    here = [label_span(t) for t in tasks]  # this process, no context
    for a, b in zip(results, here, strict=True):
        pd.testing.assert_frame_equal(a.rows, b.rows, check_exact=True)


def test_calls_come_back_in_order_from_workers_with_their_errors():
    tasks = [
        Call(fn=context_of, args=("first",), config=CONFIG),
        Call(fn=raise_value_error, args=("second",), config=CONFIG),
        Call(fn=context_of, args=("third",), config=CONFIG),
    ]
    first, second, third = run_in_memory(tasks)
    assert (first["what"], third["what"]) == ("first", "third") and first["pid"] != os.getpid()
    assert isinstance(second, Failed) and isinstance(second.exception, ValueError)
    assert second.error == "ValueError: no second"


def test_a_worker_of_other_versions_refuses_the_call():
    (refused,) = run_in_memory([Call(fn=context_of, args=("x",), config=CONFIG, versions={"numpy": "0.0"})])
    assert isinstance(refused, Failed) and "has other versions: numpy" in refused.error


@pytest.mark.slow
def test_a_call_that_kills_its_worker_twice_is_reported_and_the_others_come_back():
    tasks = [Call(fn=context_of, args=("a",), config=CONFIG), Call(fn=die, args=(11,), config=CONFIG)]
    kept, dead = run_in_memory(tasks, ExecutionOptions(workers=2), names=["kept", "round 1"])
    assert kept["what"] == "a"
    assert isinstance(dead, Failed) and "a worker process died twice while running round 1" in dead.error


def test_call_values_are_the_functions_values_and_raise_what_a_call_raised():
    """call_values: the values in the order of the calls; what a function raised is raised again in
    this process, a call whose worker died twice a RuntimeError naming it."""
    calls = [Call(fn=context_of, args=(w,), config=CONFIG) for w in ("a", "b")]
    assert [v["what"] for v in call_values(calls)] == ["a", "b"]
    with pytest.raises(ValueError, match="no second"):
        call_values([calls[0], Call(fn=raise_value_error, args=("second",), config=CONFIG)])
    with pytest.raises(RuntimeError, match="a worker process died twice while running round 7"):
        call_values([Call(fn=die, args=(11,), config=CONFIG)], names=["round 7"])
