"""One round's world of clutter removal (:mod:`annotator.policies.clutter`): the settled scene with
the UR3 and its gripper, objects dynamic (:class:`Round`); the arm executes a policy's proposal, an
object held is taken away, the scene settles. The policies propose for a round through this
module's :class:`Round`, never through the benchmark that plays it.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass

from annotator.cell.reach import READY, Reach, check_reach
from annotator.config import AnnotatorConfig
from annotator.geometry import Transform
from annotator.grippers import GripperDescription
from annotator.objects import ObjectModel, get_object_pose, physics_for
from annotator.policies.records import Proposal
from annotator.scenes.records import KEPT, Instance, SceneRecord
from annotator.scenes.world import LoadedScene, load_scene_with_arm
from annotator.sim import rigid
from annotator.sim.contacts import closest_points
from annotator.sim.world import World

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Executed:
    """What executing one proposal did: ``held``; ``target``, the instance the arm went for (the
    proposal's, or the one nearest its TCP; -1: none within the gripper's reach); ``why`` a failure
    failed (:data:`annotator.policies.clutter.FAILURES`), empty for a held object."""

    held: bool
    target: int
    why: str = ""


class Round:
    """One round's world: the settled scene with the UR3 and its gripper, objects dynamic."""

    def __init__(
        self,
        record: SceneRecord,
        models: Mapping[str, ObjectModel],
        config: AnnotatorConfig,
        gripper: GripperDescription,
    ) -> None:
        self.record = record
        self.models = models
        self.config = config
        self.gripper = gripper
        self.world = World(config.physics.whole_linkage())
        try:
            self.scene: LoadedScene = load_scene_with_arm(self.world, record, models, config, gripper)
            self.present: dict[int, int] = dict(self.scene.uids)  # instance -> body, still on the table
            self._home()
        except BaseException:
            self.world.close()
            raise

    @property
    def cell(self):
        return self.scene.cell

    def close(self) -> None:
        self.world.close()

    def _home(self) -> None:
        cell = self.cell
        cell.reset_arm(READY)
        cell.command_arm(READY)
        cell.gripper.reset_width(cell.gripper.max_width)

    def now(self) -> SceneRecord:
        """The scene as it is: the objects still present at their poses now (table frame)."""
        T_table_world = self.record.T_world_table.inverse()
        instances = []
        for inst in self.record.instances:
            uid = self.present.get(inst.instance_id)
            if uid is None:
                continue
            T = T_table_world * get_object_pose(self.world.client, uid)
            instances.append(
                Instance(
                    inst.instance_id,
                    inst.object_id,
                    KEPT,
                    Transform.exact(T.pos, T.quat),
                    inst.scale,
                    inst.mass,
                )
            )
        return dataclasses.replace(self.record, instances=tuple(instances))

    def reach(self, T_table_tcp: Transform, width: float, instance_id: int) -> Reach:
        """Can the arm execute the grasp in the scene as it is?"""
        protocol, cell = self.config.protocol, self.cell
        first = self.present.get(instance_id)
        bodies = ([first] if first is not None else []) + [
            u for i, u in sorted(self.present.items()) if i != instance_id
        ]
        return check_reach(
            cell,
            self.record.T_world_table * T_table_tcp,
            width,
            open_width=min(cell.gripper.max_width, width + 2 * protocol.pregrasp_clearance),
            approach_distance=protocol.approach_distance,
            approach_step=protocol.approach_step,
            obj=tuple(bodies),
            q_seed=READY,
        )

    def execute(self, proposal: Proposal) -> Executed:
        """Execute ``proposal`` on the arm from a snapshot of the scene as it is."""
        from annotator.cell.execute import Plan, execute_plan

        target = proposal.instance_id if proposal.instance_id in self.present else self._nearest(proposal)
        if target < 0:
            return Executed(False, -1, "nothing_there")
        self._use_physics_of(target)
        state = self.world.save_state()
        self.world.restore_state(state)  # no contact memory: the attempt depends on the scene only
        self.world.remove_state(state)
        lift = dataclasses.replace(self.config.protocol, lift_height=self.config.scenes.clutter_lift_height)
        config = dataclasses.replace(self.config, protocol=lift)
        uid = self.present[target]
        T_world_tcp = self.record.T_world_table * proposal.T_table_tcp
        open_width = min(self.cell.gripper.max_width, proposal.width + 2 * lift.pregrasp_clearance)
        plan = Plan(
            get_object_pose(self.world.client, uid),
            T_world_tcp,
            proposal.width,
            open_width,
            proposal.reach,
            "",
        )
        result = execute_plan(self.cell, uid, plan, config)
        held = result.held(lift.lift_height, lift.max_slip)
        if held:
            self.world.remove_body(uid)
            del self.present[target]
        self._home()
        self.settle()
        pads = self.cell.gripper.description.pad_links
        return Executed(held, target, "" if held else _failure(result, lift.lift_height, pads))

    def _nearest(self, proposal: Proposal) -> int:
        """The object nearest the proposal's TCP (a file's grasp names none); -1 if none is within
        the gripper's reach of it."""
        point = (self.record.T_world_table * proposal.T_table_tcp).pos
        return nearest_instance(self.world.client, self.present, point, self.cell.gripper.max_width)

    def _use_physics_of(self, instance_id: int) -> None:
        model = self.models[self.record.instance(instance_id).object_id]
        physics = physics_for(model, self.config.physics.whole_linkage())
        if self.world.physics != physics:
            self.world.physics = physics
            self.world.configure()

    def settle(self) -> None:
        """VGN's remove_and_wait: settle; remove objects whose centre of mass left the workspace."""
        scenes = self.config.scenes
        chunk = max(1, round(scenes.rest_check_time / self.world.dt))
        limit = round(scenes.settle_time / self.world.dt)
        T_table_world = self.record.T_world_table.inverse()
        self.world.set_gravity(True)
        for _ in range(scenes.settle_rounds):
            elapsed = 0
            while elapsed < limit and not self._at_rest():
                for _ in range(chunk):
                    self.cell.command_arm(READY)
                    self.world.step()
                elapsed += chunk
            gone = [
                i
                for i, uid in self.present.items()
                if not self.record.workspace.contains(
                    T_table_world.apply(get_object_pose(self.world.client, uid).pos)
                )[0]
            ]
            for instance_id in gone:
                self.world.remove_body(self.present.pop(instance_id))
            if not gone:
                return

    def _at_rest(self) -> bool:
        speed = self.config.scenes.rest_speed
        for uid in self.present.values():
            linear, angular = rigid.velocity(self.world.client, uid)
            if math.sqrt(sum(v * v for v in (*linear, *angular))) >= speed:
                return False
        return True


def nearest_instance(client: int, bodies: Mapping[int, int], point_world, within: float) -> int:
    """The instance (of ``bodies``: instance -> body) whose body is nearest ``point_world`` (3,) m,
    world frame; -1 if none is within ``within`` m of it."""
    best, who = within, -1
    probe = rigid.collision_shape(client, "sphere", radius=1e-4)
    body = rigid.multibody(
        client,
        baseMass=0.0,
        baseCollisionShapeIndex=probe,
        baseVisualShapeIndex=-1,
        basePosition=list(map(float, point_world)),
    )
    try:
        for instance_id, uid in sorted(bodies.items()):
            pts = closest_points(client, body, uid, best)
            if pts and min(p.distance for p in pts) < best:
                best, who = min(p.distance for p in pts), instance_id
    finally:
        rigid.remove(client, body)
    return who


def _failure(result, lift_height: float, pads: tuple[str, ...]) -> str:
    """The :data:`FAILURES` key of an execution that did not hold (``result``: an Execution;
    ``pads``: the gripper's pad links, which may touch the object on the way in)."""
    if result.table_touched:
        return "arm_touched_table"
    if result.links_on_object - set(pads):
        return "gripper_pushed_object"
    if result.pads_touching < 2:
        return "no_contact"
    if not result.lifted(lift_height):
        return "not_lifted"
    return "slipped"
