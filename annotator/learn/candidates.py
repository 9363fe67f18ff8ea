"""The policy's own candidates in the training scenes, labelled by simulation.

The labels of ``annotate --scenes`` are grasps sampled around the true meshes: on piles nine in
ten collide with the target, a neighbour or the table, and nearly all that do not collide hold. A
model of them learns to tell collisions; but the learned policy scores vision candidates, which
already clear the observed cloud (:mod:`annotator.policies.vision`), and among those "far from
the cloud" is no sign of a hold. So the learner is also shown what it will score: in each training
scene, the vision candidates of the scene's own views (:func:`annotator.policies.vision.
sample_grasps` with the learned policy's SEEDS, ``draws`` draws keyed on (seed, scene, draw)), each
tried by the floating gripper among the neighbours as ``annotate --scenes`` tries its own
(:class:`annotator.scenes.labels.SceneTrials`, one unperturbed trial; a collision is a failure), on
the object nearest its TCP (as the clutter-removal loop picks its target).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from annotator.config import AnnotatorConfig
from annotator.geometry import Transform
from annotator.learn.policy import CANDIDATES, SEEDS
from annotator.objects import ObjectModel
from annotator.outcome import Outcome
from annotator.policies.records import Observation
from annotator.policies.round_world import nearest_instance
from annotator.policies.vision import ObservedSurface, sample_grasps
from annotator.rng import keyed_rng
from annotator.scenes.labels import SceneTrials
from annotator.scenes.records import SceneRecord

log = logging.getLogger(__name__)

DRAWS = 1  # draws of the policy's candidates per training scene (up to CANDIDATES each)


@dataclass(frozen=True)
class SimulatedCandidates:
    """Vision candidates of one scene: ``T_table_tcp`` (n, 4, 4) table frame, chords ``width`` (n,)
    m, ``held`` (n,) bool (the trial's outcome was a success), ``outcome`` (n,) the outcome's label
    (``"none"``: no object within the stroke of the TCP)."""

    T_table_tcp: np.ndarray
    width: np.ndarray
    held: np.ndarray
    outcome: np.ndarray


def load_models(objects_dir: str | Path, config: AnnotatorConfig) -> dict[str, ObjectModel]:
    """The objects of ``objects_dir`` loaded (the cache of ``annotate``), by object id."""
    from annotator.objects import default_cache_dir, discover_objects, load_object

    cache = Path(default_cache_dir())
    return {
        s.object_id: load_object(s, config.objects, cache_dir=cache)
        for s in discover_objects(Path(objects_dir), config.objects)
    }


def simulated_candidates(
    record: SceneRecord,
    observation: Observation,
    surface: ObservedSurface,
    models: Mapping[str, ObjectModel],
    config: AnnotatorConfig,
    *,
    draws: int = DRAWS,
    seed: int = 0,
) -> SimulatedCandidates:
    """The vision candidates of ``observation`` (its ``surface``) in ``record``'s scene, each tried
    (module docstring)."""
    Ts, widths = [], []
    for draw in range(draws):
        rng = keyed_rng("learn-candidates", int(seed), int(record.scene_id), draw)
        grasps = sample_grasps(observation, rng, seeds=SEEDS, limit=CANDIDATES, surface=surface)
        Ts.append(grasps.T_table_tcp)
        widths.append(grasps.width)
    T_table_tcp, width = np.concatenate(Ts), np.concatenate(widths)
    outcome = np.full(len(width), "none", dtype=object)
    with SceneTrials(record, models, config) as trials:
        T_world_table = record.T_world_table.as_matrix()
        within = trials.hand.gripper.max_width  # as the loop picks its target
        for k in range(len(width)):
            point = (T_world_table @ T_table_tcp[k])[:3, 3]
            target = nearest_instance(trials.world.client, trials.scene.uids, point, within)
            if target < 0:
                continue
            T_table_obj = record.instance(target).T_table_obj
            assert T_table_obj is not None
            T_obj_tcp = Transform.from_matrix(np.linalg.inv(T_table_obj.as_matrix()) @ T_table_tcp[k])
            trials.reset()
            outcome[k] = trials.run(target, T_obj_tcp, float(width[k])).result.outcome.label
    log.info("scene %d: %d vision candidates tried", record.scene_id, len(width))
    return SimulatedCandidates(T_table_tcp, width, outcome == Outcome.SUCCESS.label, outcome)
