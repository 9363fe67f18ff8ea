"""A labels folder of ``annotate --scenes`` as the tools read it: labels, scenes, views, grasps.

Read through the one validated reader (:func:`annotator.tools.common.open_labels`); every problem
is one line (:class:`annotator.tools.common.ToolError`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from annotator.scenes.labels import TABLE_TCP_COLUMNS
from annotator.scenes.records import SceneRecord, scenes_from_table
from annotator.tools.common import LabelsRun, ToolError, open_labels

log = logging.getLogger(__name__)


@dataclass
class SceneLabels:
    """A scene run: its validated ``run`` (labels and manifest) and its scenes' ``records`` by id."""

    path: Path
    run: LabelsRun
    records: dict[int, SceneRecord]

    @property
    def labels(self) -> pd.DataFrame:
        return self.run.labels

    @property
    def gripper(self) -> str:
        """The gripper the labels were made with (the rows' ``gripper``)."""
        names = sorted(self.labels["gripper"].unique())
        if len(names) != 1:
            raise ToolError(f"{self.path}: labels of several grippers ({', '.join(names)})")
        return str(names[0])

    def scene_ids(self) -> list[int]:
        """The scenes that have labels (and a record), by id."""
        return sorted(set(int(s) for s in self.labels["scene_id"].unique()) & set(self.records))

    def rows(self, scene_id: int) -> pd.DataFrame:
        """A scene's labels by grasp id; ToolError naming the known scenes if it has none."""
        rows = self.labels[self.labels["scene_id"] == scene_id]
        if rows.empty or scene_id not in self.records:
            known = self.scene_ids()
            shown = ", ".join(map(str, known[:8])) + (
                f", ... ({len(known)} in all)" if len(known) > 8 else ""
            )
            raise ToolError(f"{self.path} has no scene {scene_id}; its scenes: {shown}")
        return rows.sort_values("grasp_id", kind="stable").reset_index(drop=True)

    def views(self, scene_id: int) -> list:
        """The scene's views (:class:`annotator.scenes.views.SceneView`), [] if made without --views."""
        from annotator.scenes.views import read_views

        folder = self._artifact_folder(scene_id, "cameras.parquet")
        if folder is None:
            return []
        try:
            return read_views(folder)
        except (OSError, ValueError, KeyError) as exc:
            raise ToolError(f"{folder}: the scene's views cannot be read ({exc})") from None

    def _artifact_folder(self, scene_id: int, name: str) -> Path | None:
        from annotator.store.names import scene_unit

        manifest = self.run.manifest or {}
        unit = scene_unit(scene_id)
        records = []
        if unit in manifest.get("objects_done", {}):
            records.append(manifest["objects_done"][unit])
        records += list(manifest.get("chunks_done", {}).get(unit, {}).get("files", {}).values())
        for record in records:
            artifact = (record.get("artifacts") or {}).get(name)
            if artifact is not None:
                return (self.path / artifact["file"]).parent
        return None

    def grasps(self, scene_id: int):
        """The scene's grasps for the exports (:class:`annotator.tools.export_vgn.SceneGrasps`)."""
        from annotator.geometry import quat_to_matrix
        from annotator.tools.export_vgn import SceneGrasps

        rows = self.rows(scene_id)
        values = rows[list(TABLE_TCP_COLUMNS)].to_numpy(dtype=np.float64)
        T = np.zeros((len(rows), 4, 4))
        if len(rows):
            T[:, :3, :3] = quat_to_matrix(values[:, 3:7])
        T[:, :3, 3] = values[:, :3]
        T[:, 3, 3] = 1.0
        return SceneGrasps(
            scene_id,
            T,
            rows["width"].to_numpy(dtype=np.float64),
            rows["success"].to_numpy(dtype=bool),
            rows["instance_id"].to_numpy(dtype=np.int64),
            rows["grasp_id"].to_numpy(dtype=np.int64),
        )


def open_scene_labels(labels: str | Path, command: str) -> SceneLabels:
    """The scene run in ``labels`` (a folder); ToolError if it is not one (``command`` says who asks)."""
    from annotator.dataset import load_scenes

    path = Path(labels)
    run = open_labels(path)
    inputs = ((run.manifest or {}).get("run") or {}).get("inputs") or {}
    if not path.is_dir() or "scenes" not in inputs or "scene_id" not in run.labels.columns:
        raise ToolError(f"{command}: {path} holds no scenes (labels of annotate --scenes and their manifest)")
    try:
        table = load_scenes(path)
    except (OSError, ValueError) as exc:
        raise ToolError(f"{path}: the scene records cannot be read ({exc})") from None
    records = {r.scene_id: r for r in scenes_from_table(table)}
    return SceneLabels(path, run, records)
