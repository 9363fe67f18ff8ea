"""A scene's record as it travels between the pipeline's two sides: the scene table of one scene
(:func:`annotator.scenes.records.scene_table`), written as the :data:`SCENE_FILE` artifact of its
first span by the worker that built it, read back by the main process (and from the folder on a
resume: the Parquet round trip is exact) and passed to the scene's later spans."""

from __future__ import annotations

import io

import pandas as pd

from annotator.scenes.records import SceneRecord, scene_table, scenes_from_table

# The scene table of a scene, an artifact of its first span (beside its views).
SCENE_FILE = "scene.parquet"


def record_from_artifact(data: bytes) -> SceneRecord:
    """The scene of a :data:`SCENE_FILE` artifact's bytes."""
    records = scenes_from_table(pd.read_parquet(io.BytesIO(data)))
    if len(records) != 1:
        raise ValueError(f"a scene file holds one scene, this one {len(records)}")
    return records[0]


def table_bytes(record: SceneRecord) -> bytes:
    """The :data:`SCENE_FILE` artifact of ``record``."""
    buffer = io.BytesIO()
    scene_table([record]).to_parquet(buffer, index=False)
    return buffer.getvalue()
