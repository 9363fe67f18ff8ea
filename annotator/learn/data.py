"""Loading: an ``annotate --scenes ... --views K`` run as the learner reads it.

Through :mod:`annotator.dataset` (:func:`~annotator.dataset.load_scenes`, the scene records;
:func:`~annotator.dataset.scene_labels`, each scene's labels) plus the scene's views (the
``cameras.parquet`` artifact its labels came with, :func:`scene_views`). Each scene becomes the
:class:`~annotator.policies.records.Observation` a policy would get of it, and each labelled grasp
its commanded TCP in the table frame (the pose the arm would be sent to: the label's object frame
pose ``cmd_*`` through the instance's settled pose), its chord ``cmd_width`` and its outcome. Given
the objects, each scene adds the policy's own candidates, tried in simulation
(:mod:`annotator.learn.candidates`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from annotator.dataset import load_scenes, scene_labels
from annotator.geometry import quat_to_matrix
from annotator.learn.candidates import DRAWS, load_models, simulated_candidates
from annotator.learn.features import grasp_features
from annotator.policies.observe import fused_observation
from annotator.policies.records import Observation
from annotator.policies.vision import observed_surface
from annotator.scenes.records import SceneRecord, scenes_from_table

log = logging.getLogger(__name__)


class MeshMismatchError(ValueError):
    """An object of ``--objects`` is not the mesh the labels were made on (its SHA-256 differs)."""


def check_meshes(
    models: dict, labels: pd.DataFrame, labels_dir: str | Path, objects: str | Path | None
) -> None:
    """Every object ``labels`` name is in ``models`` and is the mesh they were labelled on (its
    ``mesh_sha256``): the policy's candidates must be simulated on the shapes the labels saw.
    :class:`MeshMismatchError` (one line) naming the object otherwise."""
    pairs = labels[["object_id", "mesh_sha256"]].drop_duplicates().itertuples(index=False)
    for object_id, digest in pairs:
        model = models.get(str(object_id))
        if model is None:
            raise MeshMismatchError(f"{labels_dir}: object {object_id!r} is not in --objects {objects}")
        if model.mesh_sha256 != digest:
            raise MeshMismatchError(
                f"--objects {objects}: {object_id}'s mesh (sha256 {model.mesh_sha256[:12]}) is not the one "
                f"{labels_dir} was labelled on ({str(digest)[:12]}): give the labels' objects folder"
            )


@dataclass(frozen=True)
class TrainingSet:
    """Features ``X`` (n, F), outcomes ``y`` (n,) bool (held), and per row its ``scene_id`` and
    ``object_id`` (to split by scene or object; a vision candidate's is ``""``) and whether it is a
    simulated vision candidate (``vision``) rather than a label."""

    X: np.ndarray
    y: np.ndarray
    scene_id: np.ndarray
    object_id: np.ndarray
    vision: np.ndarray


def scene_views(labels_dir: str | Path, scene_id: int) -> list:
    """The views of scene ``scene_id`` (:class:`annotator.scenes.views.SceneView`), [] if the run
    rendered none (``annotate`` without ``--views``)."""
    from annotator.scenes.views import read_views
    from annotator.store.names import scene_unit
    from annotator.store.reader import LabelsFolder

    cameras = LabelsFolder.open(labels_dir).artifact(scene_unit(scene_id), "cameras.parquet")
    return [] if cameras is None else read_views(cameras.parent)


def scene_observation(
    record: SceneRecord, views: list, max_width: float, gripper: str = "rg2"
) -> Observation:
    """What a policy would get of the scene from ``views`` (as :func:`annotator.policies.observe.
    observe` builds it: the cloud cropped to the workspace, VGN's grid)."""
    return fused_observation(record, views, attempt=0, max_width=max_width, gripper=gripper)


def commanded_grasps(record: SceneRecord, labels: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """(T_table_tcp (n, 4, 4), chord (n,) m) of the labels' commanded grasps, in row order."""
    T_obj_tcp = np.tile(np.eye(4), (len(labels), 1, 1))
    if len(labels):
        quats = labels[["cmd_qx", "cmd_qy", "cmd_qz", "cmd_qw"]].to_numpy(float)
        T_obj_tcp[:, :3, :3] = quat_to_matrix(quats)
        T_obj_tcp[:, :3, 3] = labels[["cmd_x", "cmd_y", "cmd_z"]].to_numpy(float)
    T_table_obj = np.array(
        [record.instance(int(i)).T_table_obj.as_matrix() for i in labels["instance_id"].to_numpy()]
    ).reshape(-1, 4, 4)
    return T_table_obj @ T_obj_tcp, labels["cmd_width"].to_numpy(dtype=np.float64)


def load_training_set(
    labels_dirs: list[str | Path] | str | Path,
    objects: str | Path | None = None,
    draws: int = DRAWS,
) -> TrainingSet:
    """Every labelled grasp of every scene of the runs in ``labels_dirs`` with its features
    (:func:`annotator.learn.features.grasp_features`); with ``objects`` (the runs' objects folder)
    also ``draws`` draws of the policy's candidates per scene, tried in simulation
    (:func:`annotator.learn.candidates.simulated_candidates`). ValueError if a run has no views."""
    from annotator.config import AnnotatorConfig
    from annotator.policies.gripper_boxes import gripper_boxes

    if isinstance(labels_dirs, (str, Path)):
        labels_dirs = [labels_dirs]
    config = AnnotatorConfig()
    models = load_models(objects, config) if objects is not None else None
    max_width = gripper_boxes().max_width
    X, y, scene_ids, object_ids, vision = [], [], [], [], []

    def add(
        features: np.ndarray, held: np.ndarray, scene: int, objects_of: np.ndarray, simulated: bool
    ) -> None:
        X.append(features)
        y.append(held)
        scene_ids.append(np.full(len(held), scene, dtype=np.int64))
        object_ids.append(objects_of)
        vision.append(np.full(len(held), simulated))

    for n_run, labels_dir in enumerate(labels_dirs):
        records = scenes_from_table(load_scenes(labels_dir))
        for record in records:
            try:
                labels = scene_labels(labels_dir, record.scene_id)
            except KeyError:
                continue
            views = scene_views(labels_dir, record.scene_id)
            if not views:
                raise ValueError(f"{labels_dir}: scene {record.scene_id} has no views (annotate --views K)")
            observation = scene_observation(record, views, max_width)
            surface = observed_surface(observation)
            scene = 1_000_000 * n_run + record.scene_id
            T, width = commanded_grasps(record, labels)
            held, object_id = (
                labels["success"].to_numpy(dtype=bool),
                labels["object_id"].to_numpy(dtype=object),
            )
            add(grasp_features(surface, T, width), held, scene, object_id, False)
            if models is not None:
                check_meshes(models, labels, labels_dir, objects)
                tried = simulated_candidates(record, observation, surface, models, config, draws=draws)
                features = grasp_features(surface, tried.T_table_tcp, tried.width)
                add(features, tried.held, scene, np.full(len(tried.held), "", dtype=object), True)
        log.info("%s: %d scenes read", labels_dir, len(records))
    if not X:
        raise ValueError(f"no labelled scene in {', '.join(map(str, labels_dirs))}")
    return TrainingSet(*(np.concatenate(a) for a in (X, y, scene_ids, object_ids, vision)))
