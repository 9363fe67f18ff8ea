"""VGN's network as a vision policy of ``annotator clutter-removal``: the grid the policy is given
goes to VGN's own detection code, run by VGN's Python from a checkout of ethz-asl/vgn, and its
grasps come back in our TCP frame.

    annotator clutter-removal --objects DIR --rounds 20 --policy bench.vgn_policy:vgn \\
        --policy-arg model=vgn_conv.pt --policy-arg vgn=/path/to/vgn --policy-arg python=/venv/bin/python

At every attempt the observation's TSDF grid (40^3 over the workspace, VGN's task frame: its
lower corner, :attr:`~annotator.policies.Observation.T_table_volume`) is sent to a child process
started once per (python, checkout, model, threshold) in the worker. The child imports the checkout's
``vgn.networks.load_network`` and ``vgn.detection.predict``, ``process`` and ``select`` (what
VGN's ``VGN.__call__`` runs: quality above 0.9 after its smoothing, masking and non-maximum
suppression; the ``threshold`` policy argument sets another) and answers each grasp as position
and width in voxels, its quaternion (xyzw) in the task frame and its quality. Nothing of VGN is
copied here: the child runs the checkout given.

Frames: VGN's grasp frame closes along y and has its origin at the palm, its fingertips
``finger_depth`` (0.05 m) ahead (:mod:`annotator.tools.export_vgn`); our TCP is between the pads.
Each grasp becomes ``T_table_tcp = T_table_task T_task_vgn T_tcp_vgn^-1`` with ``T_tcp_vgn`` from
the gripper's fingertip reach at the grasp's width (:func:`annotator.tools.export_vgn.fingertip_reach`),
width = VGN's width in voxels x voxel size, score = VGN's quality. The loop then executes the
best-scored grasp the arm reaches (VGN's own simulation executes a random one of those it selects).
"""

from __future__ import annotations

import atexit
import logging
import os
import subprocess
import tempfile
from functools import lru_cache
from pathlib import Path

import numpy as np

from annotator.geometry import quat_to_matrix
from annotator.policies.records import Grasps, Observation

log = logging.getLogger(__name__)

GRID = 40  # VGN's grid: 40 voxels a side
FINGER_DEPTH = 0.05  # m: VGN's finger depth (its Gripper.finger_depth; workspace size / 6)
THRESHOLD = 0.9  # the quality VGN's detection.select keeps by default

# VGN's rviz module (vgn.vis, imported by its detection and clutter-removal modules) imports ROS.
# Without ROS, those modules are stand-ins that accept any call; nothing of them is used (no rviz).
ROS_STAND_INS = r"""
import sys, types
try:
    import rospy
except ImportError:
    class _Anything:
        def __init__(self, *args, **kwargs):
            pass
        def __call__(self, *args, **kwargs):
            return _Anything()
        def __getattr__(self, name):
            if name.startswith("__"):
                raise AttributeError(name)
            return _Anything()
    class _Stand_in(types.ModuleType):
        def __getattr__(self, name):
            if name.startswith("__"):
                raise AttributeError(name)
            return _Anything()
    for name in ("rospy", "sensor_msgs", "sensor_msgs.msg", "visualization_msgs", "visualization_msgs.msg",
                 "geometry_msgs", "geometry_msgs.msg", "std_msgs", "std_msgs.msg", "tf2_ros"):
        sys.modules[name] = _Stand_in(name)
"""

# Run by VGN's Python with the checkout's src/ on the path (argv: model, torch threads, VGN's
# select threshold): read grids (8-byte length + float32
# bytes), answer rows (8-byte length + float64 (n, 9): i, j, k, qx, qy, qz, qw, width (voxels),
# quality) until stdin closes.
SERVER = (
    ROS_STAND_INS
    + r"""
import numpy as np
import torch
from vgn.detection import predict, process, select
from pathlib import Path
from vgn.networks import load_network

torch.set_num_threads(int(sys.argv[2]))
device = torch.device("cpu")
net = load_network(Path(sys.argv[1]), device)
inp, out = sys.stdin.buffer, sys.stdout.buffer
while True:
    head = inp.read(8)
    if len(head) < 8:
        break
    grid = np.frombuffer(inp.read(int.from_bytes(head, "little")), np.float32).reshape(1, 40, 40, 40).copy()
    qual, rot, width = predict(grid, net, device)
    qual, rot, width = process(grid, qual, rot, width)
    grasps, scores = select(qual.copy(), rot, width, threshold=float(sys.argv[3]))
    rows = [[*g.pose.translation, *g.pose.rotation.as_quat(), g.width, s] for g, s in zip(grasps, scores)]
    data = np.asarray(rows, dtype=np.float64).reshape(-1, 9).tobytes()
    out.write(len(data).to_bytes(8, "little"))
    out.write(data)
    out.flush()
"""
)


class VgnServer:
    """A child process of VGN's Python answering grids with VGN's detections (module docstring)."""

    def __init__(
        self, python: str, checkout: str, model: str, threads: int = 1, threshold: float = THRESHOLD
    ) -> None:
        env = dict(os.environ)
        env["PYTHONPATH"] = str(Path(checkout) / "src")
        self.errors = tempfile.TemporaryFile()
        self.process = subprocess.Popen(
            [python, "-W", "ignore", "-c", SERVER, str(model), str(int(threads)), repr(float(threshold))],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self.errors,
            env=env,
        )
        atexit.register(self.close)

    def detect(self, grid: np.ndarray) -> np.ndarray:
        """VGN's grasps for ``grid`` (40, 40, 40) float32: (n, 9) rows (module docstring)."""
        data = np.ascontiguousarray(grid, dtype=np.float32).reshape(GRID, GRID, GRID).tobytes()
        assert self.process.stdin is not None and self.process.stdout is not None
        try:
            self.process.stdin.write(len(data).to_bytes(8, "little") + data)
            self.process.stdin.flush()
            head = self.process.stdout.read(8)
        except BrokenPipeError:
            head = b""
        if len(head) < 8:
            self.errors.seek(0)
            tail = self.errors.read().decode(errors="replace").strip().splitlines()[-5:]
            raise RuntimeError(
                f"VGN's detection process ended (exit code {self.process.wait()}): " + " | ".join(tail)
            )
        body = self.process.stdout.read(int.from_bytes(head, "little"))
        return np.frombuffer(body, np.float64).reshape(-1, 9).copy()

    def close(self) -> None:
        if self.process.poll() is None:
            assert self.process.stdin is not None
            self.process.stdin.close()
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()


_SERVERS: dict[tuple, VgnServer] = {}


def server(
    python: str, checkout: str, model: str, threads: int = 1, threshold: float = THRESHOLD
) -> VgnServer:
    """This process's :class:`VgnServer` for the arguments (started once)."""
    key = (python, checkout, model, threads, threshold)
    if key not in _SERVERS:
        _SERVERS[key] = VgnServer(python, checkout, model, threads, threshold)
    return _SERVERS[key]


def close_servers() -> None:
    """End this process's detection children (waited for: their CPU counts as the caller's
    children's); the next call starts them again."""
    for key in list(_SERVERS):
        _SERVERS.pop(key).close()


@lru_cache(maxsize=4)
def _reach(gripper: str):
    from annotator.tools.export_vgn import fingertip_reach

    return fingertip_reach(gripper)


def to_tcp(rows: np.ndarray, observation: Observation) -> Grasps:
    """VGN's rows (voxels, task frame, palm origin, closing along y) as our TCP grasps in the
    table frame (module docstring)."""
    from annotator.tools.export_vgn import tcp_to_vgn

    rows = np.asarray(rows, dtype=np.float64).reshape(-1, 9)
    voxel = float(observation.voxel_size)
    width = rows[:, 7] * voxel
    T_task_vgn = np.tile(np.eye(4), (len(rows), 1, 1))
    T_task_vgn[:, :3, :3] = quat_to_matrix(rows[:, 3:7]).reshape(-1, 3, 3)
    T_task_vgn[:, :3, 3] = rows[:, :3] * voxel
    offset = _reach(observation.gripper)(width) - FINGER_DEPTH if len(rows) else np.zeros(0)
    T_tcp_vgn = tcp_to_vgn(offset).reshape(-1, 4, 4)
    T_table_tcp = observation.T_table_volume.as_matrix() @ T_task_vgn @ np.linalg.inv(T_tcp_vgn)
    return Grasps(T_table_tcp, np.clip(width, 0.0, observation.max_width), rows[:, 8].copy())


def vgn(
    observation: Observation,
    model: str,
    vgn: str,
    python: str,
    threads: str = "1",
    threshold: str = str(THRESHOLD),
) -> Grasps:
    """The vision policy: VGN's detections on the observation's grid (module docstring).
    ``model``: a state dict saved by VGN's ``train_vgn.py``; ``vgn``: the checkout; ``python``:
    the interpreter that runs it (with torch, scipy, Open3D); ``threshold``: the quality a
    detection needs (VGN's 0.9; 0 keeps every local maximum, so the loop executes the
    best-rated grasp the arm reaches whatever its quality)."""
    rows = server(python, vgn, model, int(threads), float(threshold)).detect(observation.tsdf)
    log.info("VGN proposed %d grasps", len(rows))
    return to_tcp(rows, observation)
