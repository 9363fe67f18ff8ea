"""Helpers for the scene tests: sample objects loaded once, scenes built and loaded, grasps on them."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from annotator.config import ObjectConfig
from annotator.geometry import quat_to_matrix
from annotator.objects import ObjectModel, load_object
from annotator.scenes import SceneRecord
from annotator.tools.export_vgn import SceneGrasps

REPO = Path(__file__).resolve().parents[1]
CONCAVE = ("mug.obj", "bowl.obj", "banana.obj", "ring.off")  # CoACD parts (cached after the first run)
CONVEX = ("box.obj", "can.stl", "plate.obj")  # hulls: no decomposition, cheap on a cold machine


def load_models(names: tuple[str, ...]) -> dict[str, ObjectModel]:
    """Sample objects by file name -> {object id (the stem): model}."""
    return {Path(n).stem: load_object(REPO / "objects" / n, ObjectConfig()) for n in names}


def grasps_on(
    record: SceneRecord, models: dict[str, ObjectModel], per_instance: int, seed: int
) -> SceneGrasps:
    """Synthetic grasps (no simulation): TCPs at each kept instance's centre of mass in random
    orientations, random widths, about half of them successes; grasp ids count per scene."""
    rng = np.random.default_rng(seed)
    T, inst = [], []
    for i in record.kept:
        com_table = i.T_table_obj.apply(np.asarray(models[i.object_id].center_mass))
        for _ in range(per_instance):
            M = np.eye(4)
            M[:3, :3] = quat_to_matrix(rng.standard_normal(4))
            M[:3, 3] = com_table + rng.normal(0.0, 0.005, 3)
            T.append(M)
            inst.append(i.instance_id)
    n = len(T)
    return SceneGrasps(
        record.scene_id,
        np.array(T).reshape(-1, 4, 4),
        rng.uniform(0.01, 0.1, n),
        rng.uniform(size=n) < 0.5,
        np.array(inst, dtype=np.int64),
        np.arange(n, dtype=np.int64),
    )
