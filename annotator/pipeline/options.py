"""The options every run has, whatever its job: inputs, output folder, workers, seed, trials, the
gripper, the cache. A job's own options are its own record (``ObjectOptions`` of
:mod:`annotator.pipeline.object_job`, ``EvaluateOptions`` of :mod:`annotator.pipeline.evaluate_job`,
``SceneOptions`` of :mod:`annotator.pipeline.scene_job`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from annotator.grippers import GripperDescription


@dataclass(frozen=True)
class RunOptions:
    """``objects_dir``: the objects (``--objects``); ``n``: candidates per unit (object or scene);
    ``out_dir``: the output folder; ``workers`` local processes, or ``scheduler`` a Dask address;
    ``seed``, ``trials`` (K per candidate), ``scale`` (None: the objects' own); ``overwrite`` /
    ``repair`` the folder; ``quiet``; ``gripper`` simulated (a description, a shipped name or a
    folder; None: the RG2); ``cache_dir``: the decomposition cache of every worker (None: default)."""

    objects_dir: Path
    n: int
    out_dir: Path = Path("labels")
    workers: int = 1
    seed: int = 0
    trials: int = 1
    scheduler: str | None = None
    scale: float | None = None
    overwrite: bool = False
    repair: bool = False
    quiet: bool = False
    gripper: GripperDescription | str | None = None
    cache_dir: Path | None = None
