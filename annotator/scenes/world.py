"""A recorded scene loaded into a world: the seed's table and every kept instance at its pose.

The bodies are created at the recorded poses with zero velocity, so a scene is the same however
many times and in whatever world it is loaded (views, and later the trials among neighbours).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from annotator.cell.world import Cell, build_cell
from annotator.config import AnnotatorConfig, CellConfig, GripperConfig, KinectConfig
from annotator.grippers import GripperDescription
from annotator.objects import ObjectModel, create_body
from annotator.scenes.records import SceneRecord
from annotator.sim.world import World

log = logging.getLogger(__name__)

# The rebuilt table must be where the scene was built: a different [cell] table pose is an error.
TABLE_TOLERANCE = 1e-9  # m


@dataclass
class LoadedScene:
    """``record`` in ``cell.world``: ``uids`` maps each kept instance id to its body id."""

    record: SceneRecord
    cell: Cell
    uids: dict[int, int]

    @property
    def client(self) -> int:
        return self.cell.client

    def instance_of(self, uid: int) -> int | None:
        """The instance id of body ``uid`` (None for the table, the robot or anything else)."""
        for instance_id, body in self.uids.items():
            if body == uid:
                return instance_id
        return None


def load_scene(
    world: World,
    record: SceneRecord,
    models: Mapping[str, ObjectModel],
    *,
    cell_config: CellConfig | None = None,
    robot: bool = False,
    kinect: bool = False,
    gripper: GripperConfig | None = None,
    kinect_config: KinectConfig | None = None,
    description: GripperDescription | str | None = None,
) -> LoadedScene:
    """Build the cell's table (and the arm with the gripper ``description``, default the RG2, and
    the Kinect if asked) in ``world`` and create every kept instance of ``record`` at its recorded
    pose. ``models`` maps object ids to loaded objects."""
    cell = build_cell(
        world,
        cell_config,
        robot=robot,
        kinect=kinect,
        gripper=gripper,
        kinect_config=kinect_config,
        description=description,
    )
    offset = float(np.abs(cell.top.T_world_top.pos - record.T_world_table.pos).max())
    if offset > TABLE_TOLERANCE:
        raise ValueError(f"scene {record.scene_id} was built on a table {offset:.3g} m from this cell's")
    uids = {}
    for inst in record.kept:
        if inst.object_id not in models:
            raise KeyError(f"scene {record.scene_id}: object {inst.object_id!r} is not loaded")
        T_world_obj = record.T_world_table * inst.T_table_obj
        uids[inst.instance_id] = create_body(world.client, models[inst.object_id], T_world_obj)
    return LoadedScene(record, cell, uids)


def load_scene_with_arm(
    world: World,
    record: SceneRecord,
    models: Mapping[str, ObjectModel],
    config: AnnotatorConfig,
    description: GripperDescription | str | None = None,
) -> LoadedScene:
    """:func:`load_scene` with the UR3 and the gripper ``description`` in the cell (no Kinect):
    the world in which the arm reaches for a scene's grasps (labels of ``--scenes --cell``,
    clutter removal). ``config`` gives the cell, the gripper's settings and the Kinect's pose."""
    return load_scene(
        world,
        record,
        models,
        cell_config=config.cell,
        robot=True,
        gripper=config.gripper,
        kinect_config=config.kinect,
        description=description,
    )
