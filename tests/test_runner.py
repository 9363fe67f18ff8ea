"""The runner: the CLI's options records choose the job, each job checks its own options, and the
run binds what it always bound (a folder made before the jobs were split still resumes)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_import_cycles import import_graph

from annotator.config import AnnotatorConfig
from annotator.pipeline.evaluate_job import EvaluateJob, EvaluateOptions
from annotator.pipeline.object_job import ObjectJob, ObjectOptions
from annotator.pipeline.options import RunOptions
from annotator.pipeline.run import UsageError, job_for
from annotator.pipeline.scene_job import SceneJob, SceneOptions
from annotator.pipeline.source import GivenCandidates
from annotator.pipeline.summary import Summary
from annotator.pipeline.tasks import GivenGrasps

CONFIG = AnnotatorConfig()
SAMPLES = Path(__file__).resolve().parent.parent / "objects"
JOB_MODULES = {
    "annotator.pipeline.object_job",
    "annotator.pipeline.evaluate_job",
    "annotator.pipeline.scene_job",
}


def _given() -> GivenCandidates:
    T = np.eye(4)[None]
    return GivenCandidates({"box": GivenGrasps(T, np.array([0.03]))}, "digest")


def test_the_options_record_chooses_the_job():
    assert isinstance(job_for(CONFIG), ObjectJob)
    assert isinstance(job_for(CONFIG, ObjectOptions(cell=True)), ObjectJob)
    assert isinstance(job_for(CONFIG, EvaluateOptions(_given())), EvaluateJob)
    assert isinstance(job_for(CONFIG, SceneOptions(3)), SceneJob)
    with pytest.raises(TypeError, match="no job runs with"):
        job_for(CONFIG, RunOptions(SAMPLES, 10))  # type: ignore[arg-type]


def test_no_job_module_imports_another_or_the_chooser():
    graph = import_graph()
    for module in JOB_MODULES:
        assert not graph[module] & (JOB_MODULES | {"annotator.pipeline.run"}), module
    for shared in ("lifecycle", "execution", "options"):
        shared = f"annotator.pipeline.{shared}"
        assert not graph[shared] & (JOB_MODULES | {"annotator.pipeline.run"}), shared


def test_each_job_checks_its_own_options():
    options = RunOptions(SAMPLES, 10)
    with pytest.raises(UsageError, match="needs --cell"):
        ObjectJob(CONFIG, ObjectOptions(views=2)).check(options)
    with pytest.raises(UsageError, match="--n must be between"):
        ObjectJob(CONFIG).check(RunOptions(SAMPLES, 0))
    with pytest.raises(UsageError, match="--gripper"):
        SceneJob(CONFIG, SceneOptions(2)).check(RunOptions(SAMPLES, 10, gripper="no_such_gripper"))
    SceneJob(CONFIG, SceneOptions(2)).check(RunOptions(SAMPLES, 10, gripper="panda"))
    with pytest.raises(UsageError, match="--arrangement"):
        SceneJob(CONFIG, SceneOptions(2, arrangement="heap")).check(options)
    ObjectJob(CONFIG, ObjectOptions(cell=True, views=2)).check(options)


def test_a_run_binds_what_it_always_bound():
    """A floating run binds no mode (folders from before the modes resume); the cell its views;
    evaluate its grasps' digest and counts, and resting as True for "object"."""
    summary = Summary()
    options = RunOptions(SAMPLES, 10)
    floating = ObjectJob(CONFIG)
    floating.check(options)
    spec, units = floating.bind(options, summary)
    assert spec.inputs == {} and set(units) >= {"box", "mug"} and not summary.failed
    cell = ObjectJob(CONFIG, ObjectOptions(cell=True, views=1))
    cell.check(options)
    assert cell.bind(options, summary)[0].inputs == {"cell": {"views": 1}}
    resting = EvaluateJob(CONFIG, EvaluateOptions(_given(), resting=True))
    resting.check(options)
    spec, units = resting.bind(options, summary)
    assert spec.inputs == {"given_sha256": "digest", "counts": {"box": 1}, "resting": True}
    assert list(units) == ["box"]
