"""A PyBullet multibody whose joints and links are looked up by name, never by index."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pybullet as pb

from annotator.geometry import Transform

JOINT_TYPES = {
    pb.JOINT_REVOLUTE: "revolute",
    pb.JOINT_PRISMATIC: "prismatic",
    pb.JOINT_SPHERICAL: "spherical",
    pb.JOINT_PLANAR: "planar",
    pb.JOINT_FIXED: "fixed",
}


@dataclass(frozen=True)
class Joint:
    """One joint of a body; ``index`` is also the index of its child link."""

    index: int
    name: str
    kind: str
    lower: float
    upper: float
    max_force: float
    max_velocity: float
    child_link: str

    @property
    def movable(self) -> bool:
        """A revolute or prismatic joint (one degree of freedom)."""
        return self.kind in ("revolute", "prismatic")


class Body:
    """A loaded multibody in one physics client (the client id is explicit on every call)."""

    def __init__(self, client: int, uid: int) -> None:
        self.client = client
        self.uid = uid
        base_name = pb.getBodyInfo(uid, physicsClientId=client)[0].decode()
        self.joints: dict[str, Joint] = {}
        self.links: dict[str, int] = {base_name: -1}
        for i in range(pb.getNumJoints(uid, physicsClientId=client)):
            info = pb.getJointInfo(uid, i, physicsClientId=client)
            joint = Joint(
                index=i,
                name=info[1].decode(),
                kind=JOINT_TYPES[info[2]],
                lower=float(info[8]),
                upper=float(info[9]),
                max_force=float(info[10]),
                max_velocity=float(info[11]),
                child_link=info[12].decode(),
            )
            self.joints[joint.name] = joint
            self.links[joint.child_link] = i
        local = pb.getDynamicsInfo(uid, -1, physicsClientId=client)[3:5]
        # the base link frame in the base's inertial (COM) frame, the frame PyBullet moves
        self.T_com_base = Transform(local[0], local[1]).inverse()

    @classmethod
    def load(
        cls,
        client: int,
        urdf: Path | str,
        T_world_body: Transform | None = None,
        *,
        fixed_base: bool = False,
        flags: int = 0,
        scale: float = 1.0,
    ) -> Body:
        """Load a URDF; inertia always comes from the file (PyBullet ignores it otherwise)."""
        T = T_world_body or Transform.identity()
        uid = pb.loadURDF(
            str(urdf),
            T.pos.tolist(),
            T.quat.tolist(),
            useFixedBase=fixed_base,
            flags=flags | pb.URDF_USE_INERTIA_FROM_FILE,
            globalScaling=scale,
            physicsClientId=client,
        )
        return cls(client, uid)

    @property
    def movable_joints(self) -> list[Joint]:
        """The joints with one degree of freedom, in index order."""
        return [j for j in self.joints.values() if j.movable]

    def joint_positions(self, names: list[str] | tuple[str, ...]) -> np.ndarray:
        """Positions of the named joints, (len(names),) float."""
        idx = [self.joints[n].index for n in names]
        states = pb.getJointStates(self.uid, idx, physicsClientId=self.client)
        return np.array([s[0] for s in states])

    def joint_position(self, name: str) -> float:
        """The position of joint ``name`` (rad or m)."""
        return float(pb.getJointState(self.uid, self.joints[name].index, physicsClientId=self.client)[0])

    def joint_velocity(self, name: str) -> float:
        """The velocity of joint ``name`` (rad/s or m/s)."""
        return float(pb.getJointState(self.uid, self.joints[name].index, physicsClientId=self.client)[1])

    def joint_states(self) -> dict[str, tuple[float, float]]:
        """Every joint's position (rad or m) and velocity, by name: what
        :meth:`reset_joint_states` puts back."""
        idx = [j.index for j in self.joints.values()]
        states = pb.getJointStates(self.uid, idx, physicsClientId=self.client)
        return {name: (s[0], s[1]) for name, s in zip(self.joints, states, strict=True)}

    def reset_joint_states(self, states: dict[str, tuple[float, float]]) -> None:
        """Put the named joints back at their positions and velocities (:meth:`joint_states`)."""
        for name, (position, velocity) in states.items():
            pb.resetJointState(
                self.uid, self.joints[name].index, position, velocity, physicsClientId=self.client
            )

    def reset_joints(self, positions: dict[str, float]) -> None:
        """Teleport joints (zero velocity); for set-up only, not during a dynamic phase."""
        for name, q in positions.items():
            pb.resetJointState(self.uid, self.joints[name].index, q, 0.0, physicsClientId=self.client)

    def position_control(self, targets: dict[str, float], forces: dict[str, float] | None = None) -> None:
        """Position-control the named joints to ``targets`` (rad or m).

        ``forces`` per joint default to the URDF effort limits.
        """
        joints = [self.joints[n] for n in targets]
        pb.setJointMotorControlArray(
            self.uid,
            [j.index for j in joints],
            pb.POSITION_CONTROL,
            targetPositions=[float(q) for q in targets.values()],
            forces=[(forces or {}).get(j.name, j.max_force) for j in joints],
            physicsClientId=self.client,
        )

    def disable_motor(self, name: str) -> None:
        """Switch off the default velocity motor that PyBullet puts on every joint."""
        pb.setJointMotorControl2(
            self.uid, self.joints[name].index, pb.VELOCITY_CONTROL, force=0.0, physicsClientId=self.client
        )

    def link_pose(self, name: str) -> Transform:
        """World pose of a link frame (URDF link frame, not the inertial frame)."""
        i = self.links[name]
        if i == -1:
            return self.base_pose()
        s = pb.getLinkState(self.uid, i, computeForwardKinematics=1, physicsClientId=self.client)
        return Transform(np.asarray(s[4]), np.asarray(s[5]))

    def base_pose(self) -> Transform:
        """World pose of the base link frame."""
        pos, orn = pb.getBasePositionAndOrientation(self.uid, physicsClientId=self.client)
        return Transform(pos, orn) * self.T_com_base

    def reset_base_pose(self, T_world_base: Transform) -> None:
        """Teleport the base link frame to ``T_world_base`` (zero velocity)."""
        T_world_com = T_world_base * self.T_com_base.inverse()
        pb.resetBasePositionAndOrientation(
            self.uid, T_world_com.pos.tolist(), T_world_com.quat.tolist(), physicsClientId=self.client
        )
        pb.resetBaseVelocity(self.uid, [0, 0, 0], [0, 0, 0], physicsClientId=self.client)
