"""The scene mode (:mod:`annotator.pipeline.modes`) of ``annotate --scenes``: a span is grasps
``start..stop-1`` of one scene (:class:`annotator.pipeline.tasks.SceneTask`), ``--cell`` adds the
UR3's reachability.

The mode keeps what it loaded between spans: the objects of the pool it has met (models, with
their convex decompositions from the cache), the scenes it built (their records), and the scene it
labels now (its trial world, the arm's world with ``--cell``, and the scene's candidates). A span
of a scene the worker holds costs its trials only. The checks every task needs (versions, the
gripper, the cache) are the worker state's (:class:`annotator.pipeline.worker.WorkerState`).

A scene is built (:class:`annotator.scenes.SceneBuilder`) by the worker of its first span, which
also returns the scene's record and views as artifacts. The main process passes the record to the
scene's later spans (read back from the artifact on a resume: the Parquet round trip is exact),
so they do not settle the scene again; a span given no record builds it, bit for bit the same
(the scene depends on (seed, scene id) and the pool only).
"""

from __future__ import annotations

import io
from collections import OrderedDict
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

import pandas as pd

from annotator.config import AnnotatorConfig
from annotator.grippers import GripperDescription
from annotator.objects import ObjectError, ObjectModel, ObjectSource
from annotator.pipeline import status
from annotator.pipeline.loaded import load_model, object_info
from annotator.pipeline.modes import Labelled
from annotator.pipeline.tasks import SceneTask, UnusableObject
from annotator.scenes.arrange import SceneBuilder
from annotator.scenes.labels import SceneArm, SceneCandidates, SceneTrials, label_scene
from annotator.scenes.records import SceneRecord, scene_table, scenes_from_table
from annotator.scenes.views import render_views, view_files

if TYPE_CHECKING:
    from annotator.pipeline.worker import WorkerState

# The scene table of a scene, an artifact of its first span (beside its views).
SCENE_FILE = "scene.parquet"
# Scene records a worker keeps (a few kilobytes each) so that coming back to a scene never settles
# it again.
RECENT_SCENES = 64
# Objects a worker keeps loaded, at most: the sample objects are 10; a large pool is loaded again
# as scenes draw it (each model is a few MB with its decomposition).
RECENT_MODELS = 32


def record_from_artifact(data: bytes) -> SceneRecord:
    """The scene of a :data:`SCENE_FILE` artifact's bytes."""
    records = scenes_from_table(pd.read_parquet(io.BytesIO(data)))
    if len(records) != 1:
        raise ValueError(f"a scene file holds one scene, this one {len(records)}")
    return records[0]


def _table_bytes(record: SceneRecord) -> bytes:
    buffer = io.BytesIO()
    scene_table([record]).to_parquet(buffer, index=False)
    return buffer.getvalue()


class _Pool(Mapping[str, ObjectModel]):
    """The request's objects as a Mapping that loads each on first use (a scene looks up what it draws)."""

    def __init__(self, mode: SceneMode, task: SceneTask) -> None:
        self.mode, self.task = mode, task
        self.sources = {s.object_id: s for s in task.request.pool}

    def __getitem__(self, object_id: str) -> ObjectModel:
        try:
            return self.mode.model(self.task, self.sources[object_id])
        except UnusableObject:
            raise
        except ObjectError as exc:
            raise UnusableObject(object_id, str(exc)) from exc

    def __iter__(self) -> Iterator[str]:
        return iter(self.sources)

    def __len__(self) -> int:
        return len(self.sources)


@dataclass
class SceneSpanWork:
    """The scene a worker labels now: its trials, arm (``--cell``), candidates; ``built``: the
    current span built the scene (the manifest says so)."""

    key: tuple
    trials: SceneTrials
    arm: SceneArm | None
    candidates: SceneCandidates
    built: bool = False

    def close(self) -> None:
        self.trials.close()
        if self.arm is not None:
            self.arm.close()

    def label(self, task: SceneTask) -> Labelled:
        """The span's rows; the scene's first span also returns its table and views."""
        span, request = task.span, task.request
        artifacts = self._artifacts(task) if span.start == 0 else None
        status.write(task.status_dir, f"simulating {span.object_id}")
        trials = self.trials
        steps0 = trials.world.step_seconds
        rows = label_scene(
            trials, self.candidates, span.start, span.stop, request.seed, request.trials, self.arm
        )
        info = {
            "scene": {"kept": len(trials.record.kept), "built_by_this_span": self.built},
            "objects": {oid: object_info(m) for oid, m in sorted(trials.models.items())},
        }
        return Labelled(rows, artifacts, info, trials.world.step_seconds - steps0)

    def _artifacts(self, task: SceneTask) -> dict[str, bytes]:
        """The scene's table and, with ``views``, its views (rendered from the scene at rest, the
        arm at READY with ``--cell``; the floating gripper waits 2 m up, out of every view)."""
        record = self.trials.record
        files = {SCENE_FILE: _table_bytes(record)}
        if task.request.views > 0:
            status.write(task.status_dir, f"rendering {task.span.object_id}")
            if self.arm is not None:
                self.arm.reset()
                loaded = self.arm.scene
            else:
                self.trials.reset()
                loaded = self.trials.scene
            kinect = task.config.kinect
            views = render_views(
                loaded,
                task.request.views,
                scenes=task.config.scenes,
                kinect_config=kinect,
                noise=kinect.views_depth_noise,
                color_scale=kinect.views_color_scale,
            )
            files.update(view_files(views))
        return files


class SceneMode:
    """``annotate --scenes`` (``cell``: with ``--cell``): the pool's objects, built scenes and the
    current scene of this worker, with the run's ``gripper`` (resolved by the worker state). A
    scene's trial world and arm's world are built with the scene (:class:`SceneTrials`,
    :class:`SceneArm`)."""

    def __init__(self, config: AnnotatorConfig, gripper: GripperDescription, cell: bool) -> None:
        self.key = ("scene", cell)
        self.config, self.gripper = config, gripper
        self.models: OrderedDict[tuple, ObjectModel] = OrderedDict()
        self.records: OrderedDict[tuple, SceneRecord] = OrderedDict()
        self.current: SceneSpanWork | None = None

    # --- objects and scenes -----------------------------------------------------------------------

    def model(self, task: SceneTask, source: ObjectSource) -> ObjectModel:
        """The object ``source`` loaded as the run loads it (kept: RECENT_MODELS); ObjectError."""
        digest = (task.request.digests or {}).get(source.object_id)
        key = (
            source.object_id,
            str(source.path),
            digest,
            task.request.scale,
            source.properties,
            task.config.objects,
        )
        if key in self.models:
            self.models.move_to_end(key)
            return self.models[key]
        model = load_model(source, task.config.objects, task.request.scale, task.cache_dir, task.status_dir)
        self.models[key] = model
        while len(self.models) > RECENT_MODELS:
            self.models.popitem(last=False)
        return model

    def record(self, task: SceneTask) -> tuple[SceneRecord, bool]:
        """The task's scene (given, kept or built) and whether this span built it."""
        key = self._scene_key(task)
        if task.record is not None:
            self.records[key] = task.record
        if key in self.records:
            self.records.move_to_end(key)
            return self.records[key], False
        status.write(task.status_dir, f"building scene {task.span.scene_id}")
        builder = SceneBuilder(
            _Pool(self, task), scenes=task.config.scenes, physics=task.config.physics, cell=task.config.cell
        )
        record = builder.build(task.request.spec(task.span.scene_id))
        self.records[key] = record
        while len(self.records) > RECENT_SCENES:
            self.records.popitem(last=False)
        return record, True

    @staticmethod
    def _scene_key(task: SceneTask) -> tuple:
        request = task.request
        pool = tuple((s.object_id, str(s.path), s.properties) for s in request.pool)
        digests = tuple(sorted((request.digests or {}).items()))
        return (task.span.scene_id, request.spec(0), pool, digests, request.scale, task.config)

    def load(self, state: WorkerState, task: SceneTask) -> SceneSpanWork:
        """The task's scene loaded for labelling, its candidates made (kept while the spans are of
        it); ObjectError when none of its objects stayed on the table."""
        record, built = self.record(task)
        if not record.kept:
            raise ObjectError(_empty_scene(record))
        key = (self._scene_key(task), task.request.n, task.request.seed)
        if self.current is not None and self.current.key == key:
            self.current.built = built
            return self.current
        self.close()
        pool = _Pool(self, task)
        models = {i.object_id: pool[i.object_id] for i in record.kept}
        trials = SceneTrials(record, models, task.config, self.gripper)
        try:
            arm = SceneArm(record, models, task.config, self.gripper) if task.request.cell else None
            candidates = trials.candidates(task.request.n, task.request.seed)
        except BaseException:
            trials.close()
            raise
        self.current = SceneSpanWork(key, trials, arm, candidates, built)
        return self.current

    def close(self) -> None:
        """Free the current scene's worlds (the records and models are kept)."""
        if self.current is not None:
            self.current.close()
            self.current = None


def _empty_scene(record: SceneRecord) -> str:
    why = ", ".join(f"{i.object_id} {i.status}" for i in record.instances)
    return f"no object stayed on the table ({why}); nothing to label"
