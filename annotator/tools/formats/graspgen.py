"""``--format graspgen``: one JSON file per object (``grasps/<object>.json``: the gripper's base poses
in the object's mesh frame with their success, width, grasp id, score and outcome, the commanded
grasps when the labels record them, the object and the gripper), the objects split 80/20 for
training (``splits/train.txt``, ``splits/valid.txt``) and the gripper's description in GraspGen's
format (``gripper/``: :mod:`annotator.tools.export_graspgen`)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from annotator.tools.formats import Exporter


def write_graspgen(
    folder, stem: str, rows: pd.DataFrame, T_obj_base: np.ndarray, mesh_file: str, extra: dict
) -> Path:
    """``grasps/<stem>.json`` in the export ``folder`` (an :class:`annotator.tools.export.ExportFolder`,
    through its one output writer)."""
    from annotator.tools.export import fill_text

    data = {
        "object": {
            "file": mesh_file,
            "scale": 1.0,
            "mass": extra["mass"],
            "friction": extra["friction"],
            "id": extra["object_id"],
            "mesh_sha256": extra["mesh_sha256"],
        },
        "gripper": {
            "name": extra["gripper_type"],
            "frame": extra["base_frame"],
            "force": extra["grip_force"],
        },
        "grasps": {
            "transforms": T_obj_base.tolist(),
            "object_in_gripper": rows["success"].to_numpy(dtype=bool).tolist(),
            "width": rows["width"].to_numpy().tolist(),
            "grasp_id": rows["grasp_id"].to_numpy().tolist(),
            "score": rows["score"].to_numpy().tolist(),
            "outcome": rows["outcome"].astype(str).tolist(),
            **(
                {
                    "commanded_transforms": extra["commanded"].tolist(),
                    "commanded_width": rows["cmd_width"].to_numpy().tolist(),
                }
                if extra.get("commanded") is not None
                else {}
            ),
            "frame": extra["frame_note"],
        },
    }
    path: Path = folder.write(f"grasps/{stem}.json", fill_text(json.dumps(data, allow_nan=True)))
    return path


def finish_graspgen(folder, depth, config, labels: pd.DataFrame, ids: list[str]) -> None:
    """The gripper's description for GraspGen and the objects' training split (80/20 by object,
    :func:`annotator.dataset.split_by_object`, seed 0)."""
    from annotator.dataset import split_by_object
    from annotator.tools.export import fill_text, object_stem
    from annotator.tools.export_graspgen import write_graspgen_gripper

    write_graspgen_gripper(folder, depth, config.gripper)
    train, val = split_by_object(labels[labels["object_id"].isin(ids)], val_fraction=0.2, seed=0)
    for name, part in (("train", train), ("valid", val)):
        lines = [f"meshes/{object_stem(o)}.obj" for o in sorted(part["object_id"].unique())]
        folder.write(f"splits/{name}.txt", fill_text("".join(f"{x}\n" for x in lines)))


HELP = "one JSON per object and the gripper's description for GraspGen (gripper/)"
FOLDERS = ("grasps", "splits", "gripper")
EXPORTER = Exporter(
    "graspgen", "object", HELP, 1, FOLDERS, write_object=write_graspgen, finish=finish_graspgen
)
