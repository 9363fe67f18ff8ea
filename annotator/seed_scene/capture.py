"""Capture by hand: the scene's current grasp -> the batch protocol -> one label row appended to Parquet.

The gripper pose is read from the arm in the scene, relative to the object (the seed's cube, or the
object given with ``--object``); the pads' expected chord is the object's extent along the closing
axis through the TCP (a ray cast on its mesh), or the current opening when the TCP is not between
two of its faces. The candidate then runs through :class:`annotator.trial.GraspTrial` exactly as
in the batch job (its own DIRECT world with the floating gripper and the object at the origin, the
object loaded and weighed by ``annotator.objects``), and the row, in the label schema, is appended
to the capture file (``grasp_id`` counts the object's captures; ``seed`` is 0: nothing is drawn).

The capture file is an output of the command (:class:`annotator.store.outputs.Outputs`): claimed
before the first capture (a second scene writing it is refused), rewritten whole at each capture
and marked. A capture file this tool wrote, unchanged since, is appended to; one it did not write
(or one edited since) is refused unless ``overwrite``, which starts it anew.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pybullet_data
import trimesh

from annotator.config import AnnotatorConfig
from annotator.dataset import validate_labels
from annotator.geometry import Transform
from annotator.grippers import GripperDescription, load_gripper
from annotator.label_row import TrialsResult, label_row
from annotator.objects import ObjectModel, create_body, get_object_pose, load_object, physics_for
from annotator.outcome import Outcome, Stage
from annotator.sim.hand import FloatingGripper
from annotator.sim.world import World
from annotator.store.outputs import Outputs, written_here
from annotator.trial import GraspTrial, TrialResult

log = logging.getLogger(__name__)

CAPTURE_SEED = 0  # the seed column of a captured row: a captured trial draws nothing
PARKED = Transform([0.0, 0.0, 2.0], [0.0, 0.0, 0.0, 1.0])  # the floating hand out of the way, as the batch


@dataclass(frozen=True)
class Candidate:
    """A captured grasp: ``T_obj_tcp`` in the object's mesh frame at the expected ``width`` (m)."""

    T_obj_tcp: Transform
    width: float
    chord_found: bool  # the width is the object's chord (else the gripper's opening at capture)


def ray_distances(mesh: trimesh.Trimesh, origin: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Distances (k,) along the unit ``direction`` (3,) from ``origin`` (3,) at which the ray crosses
    the mesh's triangles (Moller-Trumbore over all faces; a few thousand faces take ~1 ms)."""
    tri = np.asarray(mesh.triangles, dtype=np.float64)  # (f, 3, 3)
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    p = np.cross(direction, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-15
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = origin - tri[:, 0]
    u = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    v = (q @ direction) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
    return t[hit]


def expected_chord(mesh: trimesh.Trimesh, T_obj_tcp: Transform) -> float | None:
    """The object's extent along the TCP's closing axis (x) through the TCP, or None if the TCP
    is not between two faces of the mesh (mesh frame, metres)."""
    origin = T_obj_tcp.pos
    x = T_obj_tcp.rotation[:, 0]
    ends = []
    for direction in (x, -x):
        hits = ray_distances(mesh, origin, direction)
        if len(hits) == 0:
            return None
        ends.append(float(hits.min()))
    return ends[0] + ends[1]


def candidate_from_scene(scene, T_world_obj: Transform, mesh: trimesh.Trimesh) -> Candidate:
    """The scene's current gripper pose as a candidate on the object at ``T_world_obj``."""
    gripper = scene.gripper
    T_world_base = gripper.base_pose()
    opening = gripper.measured_width()
    T_obj_base = T_world_obj.inverse() * T_world_base
    chord = expected_chord(mesh, T_obj_base * gripper.T_base_tcp(opening))
    width = chord if chord is not None else opening
    width = float(np.clip(width, 0.0, gripper.max_width))
    return Candidate(T_obj_base * gripper.T_base_tcp(width), width, chord is not None)


class Capturer:
    """Runs captured candidates through the batch protocol and appends their rows to ``out``.

    ``gripper``: the gripper's description (a name or folder is loaded; default the RG2), the one
    on the scene's arm. ``outputs``: the command's claimed outputs, ``out`` among them as
    ``--capture-out``; without them ``out`` is claimed here (``overwrite``: a file this tool did
    not write, or one edited since, is replaced) and released by :meth:`close`. Raises
    :class:`annotator.store.outputs.OutputRefusedError`, :class:`annotator.store.LockedError` or
    :class:`annotator.store.OutputError` when ``out`` cannot be claimed.
    """

    OPTION = "--capture-out"

    def __init__(
        self,
        model: ObjectModel,
        config: AnnotatorConfig,
        out: Path,
        gripper: GripperDescription | str | None = None,
        *,
        outputs: Outputs | None = None,
        overwrite: bool = False,
    ) -> None:
        self.model = model
        self.config = config
        self.out = Path(out)
        self.gripper = load_gripper(gripper)
        self._trial: GraspTrial | None = None
        self._world: World | None = None
        self.written = self.out  # where the last capture went (beside it if it changed meanwhile)
        self._own_outputs = outputs is None
        self.outputs = outputs or Outputs.claim(
            "annotator scene", {self.OPTION: self.out}, overwrite=overwrite
        )
        # the rows kept: those of a capture file this tool wrote (its mark's digest is its content);
        # another file is refused by the claim, or replaced with overwrite
        self._rows = read_captures(self.out) if written_here(self.out) else None

    def _ensure_trial(self) -> GraspTrial:
        """The floating gripper and the object in their own DIRECT world, set up as a batch worker does."""
        if self._trial is None:
            world = World(physics_for(self.model, self.config.physics))  # a light object: finer step
            hand = FloatingGripper(world, self.config.gripper, self.gripper)
            hand.teleport(PARKED, hand.gripper.max_width)
            uid = create_body(world.client, self.model)
            world.set_gravity(False)
            self._world, self._trial = world, GraspTrial(world, hand, uid, self.config)
        return self._trial

    def run(self, candidate: Candidate) -> TrialResult:
        return self._ensure_trial().run(candidate.T_obj_tcp, candidate.width)

    def row(self, result: TrialResult, grasp_id: int, candidate: Candidate) -> pd.DataFrame:
        """The label row of ``candidate``'s trial ``result``: the columns the batch job writes
        (:func:`annotator.label_row.label_row`, mode ``capture``), its commanded grasp included."""
        held = result.outcome == Outcome.SUCCESS or result.stage >= Stage.from_label(
            self.config.protocol.gate
        )
        trials = TrialsResult(
            result.outcome,
            result.T_obj_tcp,
            result.width,
            result.steps,
            result.slip,
            int(held),
            None,
            held,
            str(int(result.stage)),
        )
        data = label_row(
            "capture",
            object_id=self.model.object_id,
            grasp_id=grasp_id,
            result=trials,
            trials=1,
            T_cmd=candidate.T_obj_tcp,
            cmd_width=candidate.width,
            model=self.model,
            seed=CAPTURE_SEED,
            gripper=self.gripper.name,
        )
        return validate_labels(pd.DataFrame([data]))

    def capture(self, candidate: Candidate) -> pd.DataFrame:
        """Run ``candidate`` and append its row to the capture file (written whole, through the
        command's outputs); returns the row."""
        existing = self._rows
        grasp_id = int((existing["object_id"] == self.model.object_id).sum()) if existing is not None else 0
        row = self.row(self.run(candidate), grasp_id, candidate)
        table = row if existing is None else validate_labels(pd.concat([existing, row], ignore_index=True))
        self.written = self.outputs.write(self.OPTION, lambda tmp: table.to_parquet(tmp, index=False))
        self._rows = table
        return row

    def close(self) -> None:
        if self._trial is not None:
            self._trial.close()
        if self._world is not None:
            self._world.close()
        self._trial = self._world = None
        if self._own_outputs:
            self.outputs.release()


def read_captures(path: Path) -> pd.DataFrame | None:
    """The capture file's rows (validated), or None if it does not exist yet."""
    path = Path(path)
    if not path.exists():
        return None
    return validate_labels(pd.read_parquet(path))


def load_capture_object(
    path: Path | None, config: AnnotatorConfig, cube_urdf: str = "cube_small.urdf"
) -> ObjectModel:
    """The object captures refer to: ``path`` (a mesh or object URDF), or pybullet_data's seed cube,
    loaded and weighed as the batch job does (``annotator.objects.load_object``)."""
    if path is None:
        path = Path(pybullet_data.getDataPath()) / cube_urdf
    return load_object(Path(path), config.objects)


def capture_now(scene, capturer: Capturer) -> tuple[Candidate, pd.DataFrame]:
    """What the capture key does: the scene's current grasp on its object, run and appended."""
    T_world_obj = get_object_pose(scene.client, scene.cube.uid)
    candidate = candidate_from_scene(scene, T_world_obj, capturer.model.mesh)
    return candidate, capturer.capture(candidate)
