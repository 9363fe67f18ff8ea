"""Run a labelling job: :func:`run` picks the job for the job's own options (``annotate``,
``annotate --cell``, ``annotator evaluate``, ``annotate --scenes``) and runs it through the one
lifecycle (:mod:`annotator.pipeline.lifecycle`) on the one execution (local worker processes or a
Dask cluster, :mod:`annotator.pipeline.execution`).

The jobs: :class:`~annotator.pipeline.object_job.ObjectJob` (objects, sampled candidates),
:class:`~annotator.pipeline.evaluate_job.EvaluateJob` (objects, given grasps) and
:class:`~annotator.pipeline.scene_job.SceneJob` (scenes). This module only chooses among them; none of
them imports another, or this module.

Faults (README "Reliability"): a worker process that dies costs the spans it had one retry each,
run alone on a fresh worker; a span that kills its worker again fails its object with the reason
and the run goes on. A full disk, a read-only or forbidden folder stops the run with one line and
exit code 3; a lost Dask scheduler with one line and exit code 4; both keep what was written, and
the same command resumes. Local workers exit within about a second of the main process.
"""

from __future__ import annotations

from annotator.config import AnnotatorConfig
from annotator.pipeline.evaluate_job import EvaluateJob, EvaluateOptions
from annotator.pipeline.execution import SchedulerLost, UsageError, Workers, execute
from annotator.pipeline.lifecycle import Job, Terminated, run_job
from annotator.pipeline.object_job import ObjectJob, ObjectOptions
from annotator.pipeline.options import RunOptions
from annotator.pipeline.scene_job import SceneJob, SceneOptions
from annotator.pipeline.summary import Summary

__all__ = [
    "EvaluateOptions",
    "ObjectOptions",
    "RunOptions",
    "SceneOptions",
    "SchedulerLost",
    "Terminated",
    "UsageError",
    "Workers",
    "execute",
    "job_for",
    "run",
]

JobOptions = ObjectOptions | EvaluateOptions | SceneOptions


def job_for(config: AnnotatorConfig, own: JobOptions | None = None) -> Job:
    """The job that runs with ``own`` options (None: ``annotate``'s defaults, floating)."""
    if own is None or isinstance(own, ObjectOptions):
        return ObjectJob(config, own)
    if isinstance(own, EvaluateOptions):
        return EvaluateJob(config, own)
    if isinstance(own, SceneOptions):
        return SceneJob(config, own)
    raise TypeError(f"no job runs with {type(own).__name__}")


def run(options: RunOptions, config: AnnotatorConfig, own: JobOptions | None = None) -> Summary:
    """The whole job that ``own`` options choose, with the run's ``options``; returns the summary
    (also printed). Raises UsageError (exit 2); OutputError (3) and SchedulerLost (4) after
    printing the summary of what was done; KeyboardInterrupt (130) and Terminated (143) after
    saving."""
    return run_job(options, job_for(config, own))
