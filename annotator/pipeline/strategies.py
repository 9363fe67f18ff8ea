"""The worker's side of a mode (:mod:`annotator.pipeline.modes`): its *strategy*, built in the worker
from the task's mode record (:func:`build_strategy`) with its world, and what it hands back.

A strategy loads the task's unit (:meth:`Strategy.load`: the object placed in its world, or the
scene built, its candidates made) with the worker's objects (:class:`annotator.pipeline.
object_cache.ObjectCache`, never the worker's state), and the unit loaded makes the span's rows
(:meth:`LoadedUnit.label`). The worker state makes the checks every task needs (versions, the
gripper, the cache) once, and turns a unit's error into the span's one-line error, for every mode.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any, Protocol

import pandas as pd

from annotator.config import AnnotatorConfig
from annotator.grippers import GripperDescription
from annotator.pipeline.modes import Mode
from annotator.pipeline.object_cache import ObjectCache


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
    """A unit of work loaded in a strategy's world (an object placed, a scene built), its candidates
    made: it makes the rows of a span of it."""

    def label(self, task: Any) -> Labelled:
        """The rows of ``task``'s span (the task the unit was loaded for)."""
        ...


class Strategy(Protocol):
    """A mode's strategy in the worker, built with its world for a mode record, the configuration
    and the gripper. ``world``: what its world depends on (the record's :meth:`Mode.world`; a task
    whose mode gives another rebuilds it). ``load``: the task's unit (``task`` a ``SpanTask`` for
    the object modes, a ``SceneTask`` for a scene) with the worker's ``objects``; ObjectError when
    it cannot be (an unusable mesh, no stable placement on the table, a scene with no object left
    on it)."""

    world_key: Any

    def load(self, objects: ObjectCache, task: Any) -> LoadedUnit: ...

    def close(self) -> None:
        """Free the strategy's world and what it holds."""


def build_strategy(mode: Mode, config: AnnotatorConfig, gripper: GripperDescription) -> Strategy:
    """The strategy of ``mode`` (its :attr:`Mode.strategy`, imported here, in the worker) with its
    world, for ``config`` and the resolved ``gripper``."""
    module, _, name = type(mode).strategy.partition(":")
    cls = getattr(importlib.import_module(module), name)
    strategy: Strategy = cls(mode, config, gripper)
    return strategy
