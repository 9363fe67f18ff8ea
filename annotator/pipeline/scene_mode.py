"""The scene mode's strategy (:class:`annotator.pipeline.modes.SceneMode`, ``annotate --scenes``):
a span is grasps ``start..stop-1`` of one scene (:class:`annotator.pipeline.tasks.SceneTask`),
``--cell`` adds the UR3's reachability.

The strategy keeps the scenes it built (their records) and the scene it labels now (its trial
world, the arm's world with ``--cell``, and the scene's candidates); the objects of the pool come
from the worker's object cache (:class:`annotator.pipeline.object_cache.ObjectCache`, models with
their convex decompositions from the decomposition cache), as an object mode's do. A span of a
scene the worker holds costs its trials only. The checks every task needs (versions, the gripper,
the cache) are the worker state's (:class:`annotator.pipeline.worker.WorkerState`).

A scene is built (:class:`annotator.scenes.SceneBuilder`) by the worker of its first span, which
also returns the scene's record and views as artifacts. The main process passes the record to the
scene's later spans (read back from the artifact on a resume: the Parquet round trip is exact),
so they do not settle the scene again; a span given no record builds it, bit for bit the same
(the scene depends on (seed, scene id) and the pool only).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Iterator, Mapping
from dataclasses import dataclass

from annotator.config import AnnotatorConfig
from annotator.grippers import GripperDescription
from annotator.objects import ObjectError, ObjectModel, ObjectSource
from annotator.pipeline import status
from annotator.pipeline.loaded import model_record
from annotator.pipeline.modes import Mode, SceneMode
from annotator.pipeline.object_cache import ObjectCache
from annotator.pipeline.scene_artifact import SCENE_FILE, table_bytes
from annotator.pipeline.strategies import Labelled
from annotator.pipeline.tasks import SceneTask, UnusableObject
from annotator.scenes.arrange import SceneBuilder
from annotator.scenes.labels import SceneArm, SceneCandidates, SceneTrials, label_scene
from annotator.scenes.records import SceneRecord
from annotator.scenes.views import render_views, view_files

# Scene records a worker keeps (a few kilobytes each) so that coming back to a scene never settles
# it again.
RECENT_SCENES = 64


class _Pool(Mapping[str, ObjectModel]):
    """The request's objects as a Mapping that takes each from the worker's object cache on first
    use (a scene looks up what it draws) and holds it for the task."""

    def __init__(self, objects: ObjectCache, task: SceneTask) -> None:
        self.objects, self.task = objects, task
        self.sources = {s.object_id: s for s in task.request.pool}
        self.taken: dict[str, ObjectModel] = {}

    def __getitem__(self, object_id: str) -> ObjectModel:
        if object_id not in self.taken:
            self.taken[object_id] = self._get(self.sources[object_id])
        return self.taken[object_id]

    def _get(self, source: ObjectSource) -> ObjectModel:
        """The object ``source`` loaded as the run loads it; UnusableObject."""
        task = self.task
        try:
            return self.objects.get(
                source,
                digest=(task.request.digests or {}).get(source.object_id),
                scale=task.request.scale,
                config=task.config.objects,
                cache_dir=task.cache_dir,
                status_dir=task.status_dir,
            ).model
        except ObjectError as exc:
            raise UnusableObject(source.object_id, str(exc)) from exc

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
        status.write(task.status_dir, f"simulating {span.unit_id}")
        trials = self.trials
        steps0 = trials.world.step_seconds
        rows = label_scene(
            trials, self.candidates, span.start, span.stop, request.seed, request.trials, self.arm
        )
        info = {
            "scene": {"kept": len(trials.record.kept), "built_by_this_span": self.built},
            "objects": {oid: model_record(m) for oid, m in sorted(trials.models.items())},
        }
        return Labelled(rows, artifacts, info, trials.world.step_seconds - steps0)

    def _artifacts(self, task: SceneTask) -> dict[str, bytes]:
        """The scene's table and, with ``views``, its views (rendered from the scene at rest, the
        arm at READY with ``--cell``; the floating gripper waits 2 m up, out of every view)."""
        record = self.trials.record
        files = {SCENE_FILE: table_bytes(record)}
        if task.request.views > 0:
            status.write(task.status_dir, f"rendering {task.span.unit_id}")
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


class SceneLabeller:
    """:class:`annotator.pipeline.modes.SceneMode` (``cell``: with ``--cell``): the built scenes and
    the current scene of this worker, with the run's ``gripper`` (resolved by the worker state). A
    scene's trial world and arm's world are built with the scene (:class:`SceneTrials`,
    :class:`SceneArm`)."""

    def __init__(self, mode: Mode, config: AnnotatorConfig, gripper: GripperDescription) -> None:
        assert isinstance(mode, SceneMode)
        self.world_key = mode.world()
        self.config, self.gripper = config, gripper
        self.records: OrderedDict[tuple, SceneRecord] = OrderedDict()
        self.current: SceneSpanWork | None = None

    # --- scenes -------------------------------------------------------------------------------------

    def record(self, objects: ObjectCache, task: SceneTask) -> tuple[SceneRecord, bool]:
        """The task's scene (given, kept or built) and whether this span built it."""
        key = self._scene_key(task)
        if task.record is not None:
            self.records[key] = task.record
        if key in self.records:
            self.records.move_to_end(key)
            return self.records[key], False
        status.write(task.status_dir, f"building scene {task.span.scene_id}")
        builder = SceneBuilder(
            _Pool(objects, task),
            scenes=task.config.scenes,
            physics=task.config.physics,
            cell=task.config.cell,
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

    def load(self, objects: ObjectCache, task: SceneTask) -> SceneSpanWork:
        """The task's scene loaded for labelling, its candidates made (kept while the spans are of
        it); ObjectError when none of its objects stayed on the table."""
        record, built = self.record(objects, task)
        if not record.kept:
            raise ObjectError(_empty_scene(record))
        key = (self._scene_key(task), task.request.n, task.request.seed)
        if self.current is not None and self.current.key == key:
            self.current.built = built
            return self.current
        self.close()
        pool = _Pool(objects, task)
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
