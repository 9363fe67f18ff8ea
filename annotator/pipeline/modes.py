"""The worker's modes, one small object each behind the one worker state
(:class:`annotator.pipeline.worker.WorkerState`): ``floating`` (the gripper alone around the
object), ``cell`` (the object resting on the seed's table in its placements, the UR3's
reachability), ``resting`` (the object resting on the table in given orientations), all three in
:mod:`annotator.pipeline.object_modes`, and ``scene`` (a cluttered scene, with ``--cell`` the arm's
reachability too: :mod:`annotator.pipeline.scene_mode`).

A mode is built with its world for the task's mode key
(:func:`annotator.pipeline.worker.build_mode`, the key a task names:
``SpanTask.mode_key``, ``SceneTask.mode_key``); it loads the task's unit (:meth:`WorkerMode.load`:
the object placed in its world, or the scene built, and the unit's candidates), and the unit
loaded makes the span's rows (:meth:`LoadedUnit.label`). The worker state makes the checks every
task needs (versions, the gripper, the cache) once, and turns a unit's error into the span's
one-line error, for every mode.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import pandas as pd

from annotator.config import AnnotatorConfig
from annotator.geometry import Transform
from annotator.objects import ObjectModel
from annotator.sampler import Candidates
from annotator.trial import GraspTrial

if TYPE_CHECKING:
    from annotator.pipeline.worker import WorkerState


@dataclass(frozen=True)
class Labelled:
    """A span's work done: its label ``rows``, the files that belong with them (``artifacts``: file
    name -> bytes, the views it rendered, a scene's table; None: none), what the manifest records of
    its unit (``info``) and the seconds spent inside stepSimulation (``step_seconds``)."""

    rows: pd.DataFrame
    artifacts: dict[str, bytes] | None
    info: dict[str, Any]
    step_seconds: float


class LoadedUnit(Protocol):
    """A unit of work loaded in a mode's world (an object placed, a scene built), its candidates
    made: it makes the rows of a span of it."""

    def label(self, task: Any) -> Labelled:
        """The rows of ``task``'s span (the task the unit was loaded for)."""
        ...


class WorkerMode(Protocol):
    """A mode of the worker: ``key`` identifies it (a task of another key rebuilds it and its
    world). ``load``: the task's unit in the mode (``task`` a ``SpanTask`` for the object modes,
    a ``SceneTask`` for the scene), with ``state``'s objects; ObjectError when it cannot be (an
    unusable mesh, no stable placement on the table, a scene with no object left on it)."""

    key: tuple

    def load(self, state: WorkerState, task: Any) -> LoadedUnit: ...

    def close(self) -> None:
        """Free the mode's world and what it holds."""


class PlacedObject(Protocol):
    """An object in an object mode's world. ``mode``: its rows' mode (:data:`annotator.schema.MODES`)."""

    mode: str

    def candidates(
        self, model: ObjectModel, n: int, seed: int, config: AnnotatorConfig, max_width: float
    ) -> Candidates:
        """The object's N candidates (the same on every worker)."""
        ...

    def trial_for(
        self, T: Transform, placement: int | None, rest: np.ndarray | None
    ) -> tuple[GraspTrial, int]:
        """The trial the grasp ``T`` (object mesh frame) runs in, and its cell placement (0 outside
        the cell); ``placement``: the one it was sampled for (None: given), ``rest``: the
        orientation it rests in (resting only)."""
        ...

    def grasp(self, rest: np.ndarray | None, T: Transform) -> Transform:
        """The pose the trial runs the grasp ``T`` at."""
        ...

    def columns(
        self, placement: int, T: Transform, width: float, grasp_id: int, rest: np.ndarray | None
    ) -> dict[str, Any] | None:
        """The row's columns of the mode (None: none)."""
        ...

    def views(
        self, start: int, stop: int, n: int, views: int, seed: int, status_dir: str | None
    ) -> dict[str, bytes] | None:
        """The files of the Kinect views a span of grasps ``start..stop-1`` (of ``n``) renders."""
        ...

    def info(self) -> dict[str, Any]:
        """What the manifest records of the object placed, beside the object itself."""
        ...

    def release(self) -> None:
        """Free its trials and snapshots (the body in the trial world is the worker's)."""
