"""``--format acronym``: one HDF5 file per object, as ACRONYM's own files are (``grasps/transforms``:
the gripper's base poses in the object's mesh frame, ``grasps/qualities/flex/object_in_gripper``:
success), with the label's width, grasp id, score and outcome beside each, the commanded grasps
when the labels record them, and the object and the gripper (:mod:`annotator.tools.export`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from annotator.tools.formats import Exporter


def write_acronym(
    folder, stem: str, rows: pd.DataFrame, T_obj_base: np.ndarray, mesh_file: str, extra: dict
) -> Path:
    """``<stem>.h5`` in the export ``folder`` (an :class:`annotator.tools.export.ExportFolder`,
    through its one output writer)."""
    path: Path = folder.write(
        f"{stem}.h5", lambda target: _write_h5(target, rows, T_obj_base, mesh_file, extra)
    )
    return path


def _write_h5(target: Path, rows: pd.DataFrame, T_obj_base: np.ndarray, mesh_file: str, extra: dict) -> None:
    import h5py

    with h5py.File(target, "w") as f:
        g = f.create_group("grasps")
        g.create_dataset("transforms", data=T_obj_base)
        g.create_dataset("qualities/flex/object_in_gripper", data=rows["success"].to_numpy().astype(np.int64))
        g.create_dataset("width", data=rows["width"].to_numpy())
        g.create_dataset("grasp_id", data=rows["grasp_id"].to_numpy())
        g.create_dataset("score", data=rows["score"].to_numpy())
        g.create_dataset("outcome", data=rows["outcome"].to_numpy(dtype=object).astype("S"))
        if extra.get("commanded") is not None:
            g.create_dataset("commanded_transforms", data=extra["commanded"])
            g.create_dataset("commanded_width", data=rows["cmd_width"].to_numpy())
        g.attrs["frame"] = extra["frame_note"]
        o = f.create_group("object")
        o.create_dataset("file", data=mesh_file)
        o.create_dataset("scale", data=1.0)
        o.create_dataset("mass", data=extra["mass"])
        o.create_dataset("friction", data=extra["friction"])
        o.create_dataset("id", data=extra["object_id"])
        o.create_dataset("mesh_sha256", data=extra["mesh_sha256"])
        o.create_dataset("label_scale", data=extra["label_scale"])
        gr = f.create_group("gripper")
        gr.create_dataset("type", data=extra["gripper_type"])
        gr.create_dataset("frame", data=extra["base_frame"])
        gr.create_dataset("force", data=extra["grip_force"])


HELP = "one HDF5 file per object (needs h5py: the 'export' extra)"
NEEDS = ("h5py", "--format acronym writes HDF5: pip install 'rg2-annotator[export]' (h5py)")
EXPORTER = Exporter("acronym", "object", HELP, 0, needs=NEEDS, write_object=write_acronym)
