"""VGN's own network trained on our labels and on VGN's own, side by side, judged on objects
neither saw: in VGN's clutter-removal simulation and in ours, piles and packed, grasp success and
percent cleared with 95 % intervals, beside vision-random and the labels oracle.

    python -m bench.peer_network --vgn /path/to/vgn --vgn-python /path/to/venv/bin/python --quick
    python -m bench.peer_network --vgn /path/to/vgn --vgn-python /path/to/venv/bin/python --keep OUT

``--vgn`` is a checkout of github.com/ethz-asl/vgn (branch ``corl2020``, the paper's code; its
commit and licence go into the record; nothing of it is copied here). ``--vgn-python`` runs it:
an interpreter with torch, Open3D, pybullet, scipy, pandas, pytorch-ignite (< 0.5: its
``ModelCheckpoint`` still takes ``save_as_state_dict``), tensorboard and mpi4py, and NumPy 1.23
(VGN's ``get_grid`` assigns a one-element array to a grid cell, which NumPy >= 1.25 refuses, and
its ``Dataset`` uses ``np.long``). VGN's scripts run in WORK/vgn with ``PYTHONPATH=VGN/src``,
through a launcher that seeds ``random``, NumPy and torch and sets torch's threads.

1. **Objects** (:func:`training_meshes`, the sample objects): the training objects are generated
   here, six families with random sizes a Panda (80 mm) and an RG2 (110 mm) can both take:
   boxes, cylinders, mugs (handles), bowls (rims), rings, capsules. The held-out objects are the
   sample objects both grippers take from a table (banana, bottle, bowl, box, can, mug, ring,
   shampoo), of other sizes and shapes. Each is loaded as ``annotate`` loads it (cleaned, its
   mass, its convex parts) and written as VGN's URDF set (``data/urdfs/<set>/<id>.urdf``: the
   mesh as visual, the convex parts as the collision compound, mass and centre of mass), which
   both simulators then load: the same collision shapes and masses in both. VGN's data download
   (its hand, table and tray) is not used: ``data/urdfs/panda/hand.urdf`` is written from our
   shipped Panda (its boxes, VGN's masses, 20 N finger effort and finger contact parameters, its
   base's centre of mass 22 mm behind the palm as VGN's gripper expects), ``setup/plane.urdf`` a
   flat box, ``setup/box.urdf`` a tray of four walls (0.2 m, VGN loads it at scale 1.3).
2. **Labels, twice**, on the training objects, the same number of labelled grasps: (a) VGN's
   ``scripts/generate_data.py`` (piles, its defaults: Poisson(4) + 1 objects, 1 to 6 views, 120
   grasps per scene); (b) ``annotate --scenes S --per-scene 2-8 --n 120 --views V --gripper
   panda`` with VGN's trial (``[scenes] shake = false``: close and lift, as VGN judges a grasp), S
   scenes for as many grasps as VGN wrote, then ``annotator export --format vgn --balance``. VGN's
   raw grasps are cleaned by the same function (:func:`annotator.tools.export_vgn.vgn_clean`:
   VGN's data notebook: 2 cm from the sides, negatives dropped to the positives' count). Both
   raw sets go through VGN's ``scripts/construct_dataset.py``.
3. **Training, twice**: VGN's ``scripts/train_vgn.py`` on each dataset, the same network
   (``conv``), epochs, batch size, learning rate, validation split and seed, on the CPU. The
   curves (loss and accuracy, training and validation split, per epoch) are read from its
   TensorBoard logs.
4. **Judging, twice**, on the held-out objects, the same rounds for every network: VGN's
   ``scripts/sim_grasp.py`` (its simulation and hand, 5 objects, 6 views, pile and packed, one
   seed) and our ``clutter-removal`` on the UR3 with the shipped Panda, each network wrapped as a
   vision policy (:mod:`bench.vgn_policy`), beside ``vision-random`` and the ``labels`` oracle on
   the same rounds; grasp success and percent cleared with 95 % Wilson intervals. Each network
   is judged twice (``--detections``): with VGN's detection (a random one of the local maxima of
   its smoothed quality rated above 0.9) and best-first (its best-rated local maximum whatever
   the rating: in VGN's simulation the launcher orders VGN's own select at threshold 0, in ours
   the policy's ``threshold=0`` and the loop's best-scored reachable grasp). A network trained on
   a few thousand grasps may rate nothing above 0.9 and so never be judged by VGN's detection;
   best-first judges what its ratings chose. Its rows are named ``vgn_net_<labels>_best``.
   Beside them, best-first piles of the training objects in VGN's simulation (``--seen-rounds``,
   sim ``vgn_seen``): what a network learned of the objects it saw, apart from what it carries
   to objects it did not (no target reads them).

``--work OUT`` keeps every file; the same command with the same ``--work`` resumes a run that
stopped: steps that finished are not run again (their rows are kept), VGN's labelling is asked
for the grasps it still owes (it appends), ``annotate`` resumes its own folder. VGN's training
cannot resume: a training cut short starts again. ``--until labels`` (or ``training``) stops after
that stage and writes its record (tagged ``until-labels``), so a run measured in parts has a record
of each part; a ``--quick`` run's record is tagged ``quick``.

Printed against the targets: the network trained on our labels at least as good as the one
trained on VGN's (success and percent cleared, both simulations, piles and packed, >= 100
attempts each); both above vision-random by >= 10 points of percent cleared on piles.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
import re
import resource
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import trimesh

from annotator.config import AnnotatorConfig
from bench import vgn_policy
from bench.arguments import (
    WORKERS_MAX,
    Parser,
    count,
    existing_file,
    existing_folder,
    number,
    seed,
    writable_folder,
)
from bench.harness import Run
from bench.vgn_policy import ROS_STAND_INS

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "objects"
# The sample objects a Panda and an RG2 take from a table (the ball is wider than both strokes;
# the plate's 8 mm edge lies below the pads' reach).
TEST_OBJECTS = (
    "banana.obj",
    "bottle.ply",
    "bowl.obj",
    "box.obj",
    "can.stl",
    "mug.obj",
    "ring.off",
    "urdf/shampoo/shampoo.urdf",
)
FAMILIES = ("box", "cylinder", "mug", "bowl", "ring", "capsule")
LABELS_CONFIG = "[scenes]\nshake = false\n\n[kinect]\nviews_color_scale = 0.1\n"
GRASPS_PER_SCENE = 120  # VGN's generate_data.py GRASPS_PER_SCENE and annotate --scenes' --n default

# Runs a VGN script as its __main__ after seeding random, NumPy and torch, with torch's threads
# set, and closing TensorBoard's writers at exit (train_vgn.py never closes them). Without ROS,
# the ROS modules that VGN's rviz module (vgn.vis, imported by its clutter-removal experiment)
# imports are stand-ins that accept any call: sim_grasp.py runs without --rviz, so nothing of them
# is ever used. Its third argument is the detection VGN's clutter removal runs: ``vgn`` leaves
# VGN's own (a random one of the local maxima rated above 0.9), ``best`` replaces VGN.__call__
# with the same predict, process and select at threshold 0, best-rated first (clutter_removal
# executes the first), so a network whose ratings stay under 0.9 is still judged on its choice.
LAUNCHER = (
    ROS_STAND_INS
    + r"""
import atexit, random, runpy, sys
import numpy as np
seed, threads, detect = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
random.seed(seed)
np.random.seed(seed)
try:
    import torch
    torch.manual_seed(seed)
    torch.set_num_threads(threads)
    from torch.utils import tensorboard
    writers = []
    init = tensorboard.SummaryWriter.__init__
    def keep(self, *a, **k):
        init(self, *a, **k)
        writers.append(self)
    tensorboard.SummaryWriter.__init__ = keep
    atexit.register(lambda: [w.close() for w in writers])
except ImportError:
    pass
if detect == "best":
    import time
    from vgn import detection
    def best_first(self, state):
        grid, voxel_size = state.tsdf.get_grid(), state.tsdf.voxel_size
        tic = time.time()
        qual, rot, width = detection.predict(grid, self.net, self.device)
        qual, rot, width = detection.process(grid, qual, rot, width)
        grasps, scores = detection.select(qual.copy(), rot, width, threshold=0.0)
        order = np.argsort(-np.asarray(scores), kind="stable")
        grasps = [detection.from_voxel_coordinates(grasps[i], voxel_size) for i in order]
        return grasps, np.asarray(scores)[order], time.time() - tic
    detection.VGN.__call__ = best_first
sys.argv = sys.argv[4:]
runpy.run_path(sys.argv[0], run_name="__main__")
"""
)

CURVES = r"""
import json, sys
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
out = {}
for part in ("train", "validation"):
    acc = EventAccumulator(sys.argv[1] + "/" + part)
    acc.Reload()
    out[part] = {t: [[e.step, e.value] for e in acc.Scalars(t)] for t in acc.Tags()["scalars"]}
print(json.dumps(out))
"""


# --- provenance --------------------------------------------------------------------------------------


VERSIONS = r"""
import importlib.metadata as m, json
names = ("torch", "numpy", "open3d-cpu", "open3d", "pybullet", "scipy", "pandas", "pytorch-ignite",
         "tensorboard")
out = {}
for name in names:
    try:
        out[name] = m.version(name)
    except m.PackageNotFoundError:
        pass
print(json.dumps(out))
"""


def vgn_libraries(python: Path) -> dict:
    """The versions of what VGN runs on in ``python`` (torch, NumPy, Open3D, PyBullet, ...)."""
    out = subprocess.run([str(python), "-c", VERSIONS], capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


def vgn_provenance(checkout: Path) -> dict:
    """The checkout's commit, branch, whether it differs from its commit, and its licence."""

    def git(*args: str) -> str:
        result = subprocess.run(["git", "-C", str(checkout), *args], capture_output=True, text=True)
        return result.stdout.strip()

    licence = checkout / "LICENSE"
    text = licence.read_text() if licence.exists() else ""
    return {
        "commit": git("rev-parse", "HEAD") or "unknown",
        "branch": git("rev-parse", "--abbrev-ref", "HEAD"),
        "dirty": bool(git("status", "--porcelain", "--untracked-files=no")),
        "licence": text.strip().splitlines()[0] if text.strip() else "none found",
        "licence_sha256": hashlib.sha256(text.encode()).hexdigest()[:16] if text else "",
    }


# --- objects -----------------------------------------------------------------------------------------


def _revolve(profile: list[tuple[float, float]]) -> trimesh.Trimesh:
    mesh = trimesh.creation.revolve(np.asarray(profile, dtype=np.float64), sections=40)
    mesh.merge_vertices()
    mesh.fix_normals()
    return mesh


def family_mesh(family: str, rng: np.random.Generator) -> trimesh.Trimesh:
    """One object of ``family`` (FAMILIES) with sizes drawn from ``rng``: metres, standing on z = 0
    of its frame, symmetry axis +z; every one has a part narrower than 70 mm to close on."""
    u = rng.uniform
    if family == "box":
        mesh = trimesh.creation.box(extents=(u(0.03, 0.065), u(0.025, 0.06), u(0.04, 0.12)))
    elif family == "cylinder":
        mesh = trimesh.creation.cylinder(radius=u(0.015, 0.033), height=u(0.05, 0.12), sections=40)
    elif family == "capsule":
        radius = u(0.012, 0.022)
        mesh = trimesh.creation.capsule(height=u(0.05, 0.1), radius=radius, count=[24, 12])
        mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (1, 0, 0)))
    elif family == "ring":
        mesh = trimesh.creation.torus(
            major_radius=u(0.022, 0.034), minor_radius=u(0.006, 0.01), major_sections=40, minor_sections=12
        )
    elif family == "bowl":
        rim, foot, height = u(0.045, 0.065), u(0.025, 0.035), u(0.035, 0.06)
        zs = np.linspace(0.0, height, 11)
        outer = [(foot + (rim - foot) * np.sin(np.pi / 2 * z / height), z) for z in zs]
        inner = [(r - 0.004, max(z, 0.005)) for r, z in outer[::-1]]
        mesh = _revolve([(0.0, 0.0), *outer, *inner[:-1], (inner[-1][0], 0.005), (0.0, 0.005)])
    elif family == "mug":
        r_out, height = u(0.028, 0.04), u(0.07, 0.1)
        r_in = r_out - 0.004
        shell = _revolve([(0, 0), (r_out, 0), (r_out, height), (r_in, height), (r_in, 0.006), (0, 0.006)])
        major, minor = u(0.02, 0.028), u(0.005, 0.007)
        handle = trimesh.creation.torus(
            major_radius=major, minor_radius=minor, major_sections=32, minor_sections=10
        )
        handle.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (1, 0, 0)))
        handle.apply_translation((r_out + major - 0.016, 0, height / 2))
        core = trimesh.creation.cylinder(radius=r_out - 0.002, height=height, sections=40)
        core.apply_translation((0, 0, height / 2))
        mesh = shell.union(handle.difference(core, engine="manifold"), engine="manifold")
    else:
        raise ValueError(f"unknown family {family!r}")
    mesh.apply_translation((0.0, 0.0, -mesh.bounds[0, 2]))
    return mesh


def training_meshes(per_family: int, seed: int) -> dict[str, trimesh.Trimesh]:
    """``per_family`` objects of each of FAMILIES: {id: mesh}."""
    from annotator.rng import keyed_rng

    out = {}
    for family in FAMILIES:
        rng = keyed_rng("peer-network-objects", seed, family)
        for k in range(per_family):
            out[f"{family}_{k:02d}"] = family_mesh(family, rng)
    return out


def _obj_text(parts: list[trimesh.Trimesh]) -> str:
    """An OBJ with one ``o`` object per part (PyBullet loads each as a convex piece of a compound)."""
    lines, offset = [], 1
    for k, part in enumerate(parts):
        lines.append(f"o part_{k}")
        lines += [f"v {x:.7f} {y:.7f} {z:.7f}" for x, y, z in np.asarray(part.vertices)]
        lines += [f"f {a + offset} {b + offset} {c + offset}" for a, b, c in np.asarray(part.faces)]
        offset += len(part.vertices)
    return "\n".join(lines) + "\n"


def write_urdf_object(model, folder: Path, name: str) -> Path:
    """``model`` (an ObjectModel, metres, mesh frame) as ``folder/name.urdf``: the cleaned mesh as
    visual, its convex parts as collision, its mass at its centre of mass, its friction."""
    folder.mkdir(parents=True, exist_ok=True)
    model.mesh.export(folder / f"{name}_visual.obj")
    parts = model.parts or [model.mesh.convex_hull]
    (folder / f"{name}_collision.obj").write_text(_obj_text(parts))
    c, inertia = np.asarray(model.center_mass), np.asarray(model.inertia)
    urdf = f"""<?xml version="1.0"?>
<!-- written by bench/peer_network.py from {model.object_id} as rg2-annotator loads it -->
<robot name="{name}">
  <link name="base_link">
    <contact><lateral_friction value="{model.friction:.4f}"/></contact>
    <inertial>
      <origin xyz="{c[0]:.6f} {c[1]:.6f} {c[2]:.6f}"/>
      <mass value="{model.mass:.6f}"/>
      <inertia ixx="{inertia[0, 0]:.4e}" ixy="{inertia[0, 1]:.4e}" ixz="{inertia[0, 2]:.4e}" iyy="{inertia[1, 1]:.4e}" iyz="{inertia[1, 2]:.4e}" izz="{inertia[2, 2]:.4e}"/>
    </inertial>
    <visual><geometry><mesh filename="{name}_visual.obj"/></geometry></visual>
    <collision><geometry><mesh filename="{name}_collision.obj"/></geometry></collision>
  </link>
</robot>
"""  # noqa: E501
    path = folder / f"{name}.urdf"
    path.write_text(urdf)
    return path


def write_hand(path: Path) -> None:
    """VGN's ``data/urdfs/panda/hand.urdf`` from our shipped Panda (module docstring, step 1).

    VGN's gripper places the base's centre of mass 22 mm behind its TCP (the palm: the fingertips
    ``finger_depth`` = 50 mm ahead) and closes along its y. The inertial frame is turned -90 deg
    about z (its y is our closing x) and put at our fingertips' end (112.9 mm from the mounting
    face) less 50 mm less 22 mm. Masses and finger contacts are VGN's hand's (0.81 kg, 0.1 kg a
    finger, stiffness 30000, damping 1000, lateral friction 1.0, spinning 0.1, friction anchor);
    the finger joints' effort is its 20 N."""
    import xml.etree.ElementTree as ET

    from annotator.grippers import load_gripper
    from annotator.tools.export_vgn import fingertip_reach

    panda = load_gripper("panda")
    tree = ET.parse(panda.urdf)
    robot = tree.getroot()
    tcp_z = 0.10365  # our TCP in panda_hand_base (gripper.toml)
    tip = tcp_z + float(fingertip_reach("panda")(np.array([0.04]))[0])
    com_z = tip - 0.05 - 0.022
    for link in list(robot.findall("link")):
        name = link.get("name")
        if name == "panda_tcp":
            robot.remove(link)
            continue
        inertial = link.find("inertial")
        origin = inertial.find("origin")
        if name == "panda_hand_base":
            origin.set("xyz", f"0 0 {com_z:.6f}")
            origin.set("rpy", f"0 0 {-math.pi / 2:.9f}")
            inertial.find("mass").set("value", "0.81")
        else:
            inertial.find("mass").set("value", "0.095" if not name.endswith("_pad") else "0.005")
            contact = ET.SubElement(link, "contact")
            ET.SubElement(contact, "friction_anchor")
            for tag, value in (
                ("stiffness", "30000.0"),
                ("damping", "1000.0"),
                ("spinning_friction", "0.1"),
                ("lateral_friction", "1.0"),
            ):
                ET.SubElement(contact, tag).set("value", value)
    for joint in list(robot.findall("joint")):
        if joint.get("name") == "panda_tcp_joint":
            robot.remove(joint)
        elif joint.get("type") == "prismatic":
            joint.find("limit").set("effort", "20.0")
            mimic = joint.find("mimic")
            if mimic is not None:
                joint.remove(mimic)  # PyBullet ignores it; VGN couples the fingers with a gear
    path.parent.mkdir(parents=True, exist_ok=True)
    tree.write(path, encoding="unicode", xml_declaration=True)


PLANE = """<?xml version="1.0"?>
<robot name="plane">
  <link name="base_link">
    <contact><lateral_friction value="1.0"/></contact>
    <inertial><mass value="0"/><inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial>
    <visual><origin xyz="0 0 -0.01"/><geometry><box size="1 1 0.02"/></geometry></visual>
    <collision><origin xyz="0 0 -0.01"/><geometry><box size="1 1 0.02"/></geometry></collision>
  </link>
</robot>
"""


def _tray() -> str:
    walls = [((0.1, -0.0025, 0.075), (0.205, 0.005, 0.15)), ((0.1, 0.2025, 0.075), (0.205, 0.005, 0.15))]
    walls += [((-0.0025, 0.1, 0.075), (0.005, 0.205, 0.15)), ((0.2025, 0.1, 0.075), (0.005, 0.205, 0.15))]
    shapes = "".join(
        f'    <collision><origin xyz="{x} {y} {z}"/><geometry><box size="{a} {b} {c}"/></geometry></collision>\n'  # noqa: E501
        for (x, y, z), (a, b, c) in walls
    )
    return (
        '<?xml version="1.0"?>\n<robot name="tray">\n  <link name="base_link">\n'
        '    <inertial><mass value="0"/><inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial>\n'  # noqa: E501
        f"{shapes}  </link>\n</robot>\n"
    )


def prepare_objects(args, work: Path, record: Run) -> tuple[Path, Path, list]:
    """Step 1: the URDF sets ``work/vgn/data/urdfs/{train,test}`` and VGN's setup files. Returns
    (train folder, test folder, the test objects' sources for our loop)."""
    from annotator.objects import default_cache_dir, discover_objects, load_object

    config = AnnotatorConfig().objects
    cache = str(default_cache_dir())
    urdfs = work / "vgn" / "data" / "urdfs"
    meshes = work / "meshes" / "train"
    meshes.mkdir(parents=True, exist_ok=True)
    for name, mesh in training_meshes(args.per_family, args.seed).items():
        mesh.export(meshes / f"{name}.obj")
    test_meshes = work / "meshes" / "test"
    for rel in TEST_OBJECTS:
        src = SAMPLES / rel
        dst = test_meshes / Path(rel).name
        dst.parent.mkdir(parents=True, exist_ok=True)
        if src.suffix == ".urdf":
            for f in src.parent.iterdir():
                shutil.copy(f, test_meshes / f.name)
        else:
            shutil.copy(src, dst)
    rows = []
    for split, folder in (("train", meshes), ("test", test_meshes)):
        for source in discover_objects(folder, config):
            model = load_object(source, config, cache_dir=cache)
            name = source.object_id.replace("/", "_")
            write_urdf_object(model, urdfs / split, name)
            extent = np.sort(model.mesh.extents)
            rows.append(
                {
                    "split": split,
                    "object": name,
                    "mass_g": round(1000 * model.mass, 1),
                    "extent_mm": "x".join(f"{1000 * e:.0f}" for e in extent[::-1]),
                    "convex_parts": len(model.parts) or 1,
                }
            )
    write_hand(urdfs / "panda" / "hand.urdf")
    (urdfs / "setup").mkdir(parents=True, exist_ok=True)
    (urdfs / "setup" / "plane.urdf").write_text(PLANE)
    (urdfs / "setup" / "box.urdf").write_text(_tray())
    record.table("objects", rows, note="training objects generated here; held-out: the sample objects")
    print(
        f"objects: {sum(r['split'] == 'train' for r in rows)} training, {sum(r['split'] == 'test' for r in rows)} held out"  # noqa: E501
    )
    test_sources = tuple(discover_objects(urdfs / "test", config))
    return urdfs / "train", urdfs / "test", test_sources


# The bench's stages, in order (--until).
STAGES = ("labels", "training", "judging")


# --- running VGN's scripts ---------------------------------------------------------------------------


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


class Steps:
    """Runs commands, logs their output under ``work/logs``, and keeps each command and its CPU."""

    def __init__(self, args, work: Path) -> None:
        self.args, self.work = args, work
        self.logs = work / "logs"
        self.logs.mkdir(parents=True, exist_ok=True)
        self.rows: list[dict] = []

    def run(self, step: str, cmd: list[str], *, cwd: Path | None = None, env: dict | None = None,
            shown: str | None = None) -> float:  # fmt: skip
        """Run ``cmd`` (its output to logs/STEP.log); its CPU seconds. A failure stops the bench."""
        return self.run_many([(step, cmd, cwd, env, shown)])[0]

    def run_many(self, jobs: list[tuple]) -> list[float]:
        """Run the ``(step, cmd, cwd, env, shown)`` jobs at once, each niced, its output to
        logs/STEP.log; the CPU seconds of each (itself and the children it waited for, from its
        own resource usage). A failure stops the bench."""
        t0 = time.perf_counter()
        running: dict[int, tuple] = {}
        saved = {job[0]: self.saved(job[0]) for job in jobs}
        for step, row in saved.items():
            if row is not None:  # finished by an earlier run of this --work: its row as it was
                print(f"[{step}] done in an earlier run ({row['seconds']:.0f} s, {row['cpu_s']:.0f} CPU-s)")
                self.rows.append(row | {"resumed": True})
        for step, cmd, cwd, env, shown in jobs:
            if saved[step] is not None:
                continue
            print(f"[{step}] {shown or shlex.join(cmd)}", flush=True)
            out = (self.logs / f"{step}.log").open("w")
            process = subprocess.Popen(
                ["nice", "-n", str(self.args.nice), *cmd],
                cwd=cwd,
                env=env,
                stdout=out,
                stderr=subprocess.STDOUT,
            )
            running[process.pid] = (step, shown or shlex.join(cmd), process, out, time.perf_counter())
        done: dict[int, tuple[float, float]] = {}
        order = list(running)
        while len(done) < len(order):
            pid, status, usage = os.wait4(-1, 0)
            if pid not in running:
                continue
            step, shown, process, out, started = running[pid]
            process.returncode = code = os.waitstatus_to_exitcode(status)
            out.close()
            done[pid] = (usage.ru_utime + usage.ru_stime, time.perf_counter() - started)
            if code != 0:
                log = self.logs / f"{step}.log"
                tail = log.read_text(errors="replace").splitlines()[-15:]
                raise SystemExit(f"[{step}] exit {code}; the end of {log}:\n" + "\n".join(tail))
            row = {
                "step": step,
                "command": shown,
                "cpu_s": round(done[pid][0], 1),
                "seconds": round(done[pid][1], 1),
            }
            (self.logs / f"{step}.done.json").write_text(json.dumps(row))
            self.rows.append(row)
            print(f"[{step}] {done[pid][1]:.0f} s, {done[pid][0]:.0f} CPU-s", flush=True)
        if len(order) > 1:
            print(f"  ({time.perf_counter() - t0:.0f} s wall for {len(order)} side by side)", flush=True)
        cpu = {running[pid][0]: done[pid][0] for pid in order}
        return [cpu[step] if row is None else row["cpu_s"] for step, row in saved.items()]

    def forget(self, step: str) -> None:
        """Make ``step`` run again: its row from an earlier run of this --work is dropped."""
        (self.logs / f"{step}.done.json").unlink(missing_ok=True)

    def saved(self, step: str) -> dict | None:
        """The row of ``step`` if an earlier run of this --work finished it, else None."""
        path = self.logs / f"{step}.done.json"
        return json.loads(path.read_text()) if path.exists() else None

    def vgn_job(
        self, step: str, script: str, argv: list[str], seed: int, threads: int = 1, detect: str = "vgn"
    ) -> tuple:
        """The job running VGN's ``scripts/SCRIPT`` with ``argv`` through LAUNCHER in WORK/vgn;
        ``detect``: VGN's detection or ``best`` (LAUNCHER)."""
        env = dict(os.environ, PYTHONPATH=str(self.args.vgn / "src"), OMP_NUM_THREADS=str(threads))
        cmd = [str(self.args.vgn_python), "-W", "ignore", "-c", LAUNCHER, str(seed), str(threads), detect]
        cmd += [str(self.args.vgn / "scripts" / script), *argv]
        shown = shlex.join([str(self.args.vgn_python), f"scripts/{script}", *argv])
        shown += f"  (seeded {seed}, {threads} torch thread(s), cwd WORK/vgn, PYTHONPATH=VGN/src"
        shown += ", best-first detection)" if detect == "best" else ")"
        return (step, cmd, self.work / "vgn", env, shown)

    def vgn(self, step: str, script: str, argv: list[str], seed: int, threads: int = 1) -> float:
        """Run VGN's ``scripts/SCRIPT`` (:meth:`vgn_job`); its CPU seconds."""
        return self.run_many([self.vgn_job(step, script, argv, seed, threads)])[0]


def _exe(name: str) -> str:
    exe = shutil.which(name, path=str(Path(sys.executable).parent)) or shutil.which(name)
    if exe is None:
        raise SystemExit(f"the {name} command is not installed (pip install -e .)")
    return exe


# --- step 2: labels ----------------------------------------------------------------------------------


def clean_vgn_raw(raw: Path, size: float) -> dict:
    """VGN's data notebook's cleanup of its own raw grasps, in place (the same function as our
    export's ``--balance``); the counts before and after."""
    from annotator.tools.export_vgn import vgn_clean

    df = pd.read_csv(raw / "grasps.csv")
    shutil.copy(raw / "grasps.csv", raw / "grasps_before_cleanup.csv")  # VGN reads grasps.csv only
    before = {"grasps": len(df), "positives": int(df["label"].sum())}
    side, dropped = vgn_clean(df[["x", "y", "z"]].to_numpy(), df["label"].to_numpy(), size)
    kept = df[~side & ~dropped]
    kept.to_csv(raw / "grasps.csv", index=False)  # VGN's write_df
    scenes = set(kept["scene_id"])
    for f in (raw / "scenes").glob("*.npz"):  # the notebook's "remove unreferenced scenes"
        if f.stem not in scenes:
            f.unlink()
    return before | {
        "near_side": int(side.sum()),
        "dropped": int(dropped.sum()),
        "kept": len(kept),
        "kept_positives": int(kept["label"].sum()),
    }


def positive_widths(grasps_csv: Path) -> dict:
    """The widths (mm) of the positives a network trains its width on (VGN's loss weighs width
    on positives only): 5th percentile, median and 95th percentile of a raw ``grasps.csv``."""
    widths = pd.read_csv(grasps_csv).query("label == 1")["width"]
    p05, median, p95 = _mm_percentiles(widths, (5, 50, 95))
    return {"positive_width_p05_mm": p05, "positive_width_median_mm": median, "positive_width_p95_mm": p95}


def _mm_percentiles(widths: pd.Series, qs: tuple[float, ...]) -> list[float]:
    """Percentiles ``qs`` of ``widths`` (m) in mm, to 0.1 mm; NaN each for no width."""
    if len(widths) == 0:
        return [float("nan")] * len(qs)
    return [round(float(v), 1) for v in 1000 * np.percentile(widths.to_numpy(dtype=float), qs)]


def widths_by_family(labels: pd.DataFrame) -> list[dict]:
    """Our labels' positives (``success``) per training-object family (the ``object_id``'s letters
    before its number, as :func:`training_meshes` names them): count, share of all positives,
    and the 25th, 50th and 75th percentile of their widths (mm)."""
    held = labels[labels["success"].astype(bool)]
    family = held["object_id"].str.extract(r"^([a-z]+)", expand=False)
    rows = []
    for name, widths in held["width"].groupby(family):
        q1, median, q3 = _mm_percentiles(widths, (25, 50, 75))
        rows.append(
            {
                "family": name,
                "positives": len(widths),
                "share": round(100 * len(widths) / len(held), 1),
                "width_q1_mm": q1,
                "width_median_mm": median,
                "width_q3_mm": q3,
            }
        )
    return rows


def make_labels(args, steps: Steps, work: Path, train: Path, record: Run) -> dict[str, Path]:
    """Step 2: VGN's labels and ours on the training objects, cleaned; VGN's datasets of both."""
    vgn_raw, ours_labels, ours_raw = work / "raw_vgn", work / "labels_ours", work / "raw_ours"
    rows = []
    # ours: as many scenes of 120 grasps as VGN is asked for (it may skip a scene whose cloud is empty)
    scenes = max(1, math.ceil(args.grasps / GRASPS_PER_SCENE))
    config = work / "labels.toml"
    config.write_text(LABELS_CONFIG)
    cmd = [
        _exe("annotate"), "--objects", str(train), "--scenes", str(scenes), "--per-scene", "2-8",
        "--n", str(GRASPS_PER_SCENE), "--views", str(args.views), "--gripper", "panda", "--seed",
        str(args.seed), "--config", str(config), "--workers", str(args.workers), "--out",
        str(ours_labels), "--quiet",
    ]  # fmt: skip
    asked, seed = args.grasps, args.seed
    if steps.saved("labels_vgn") is None and (vgn_raw / "grasps.csv").exists():
        # an earlier run of this --work stopped while VGN labelled: it appends, so ask for the rest
        # (whole scenes of 120), seeded anew so that it does not label the same piles again
        written = len(pd.read_csv(vgn_raw / "grasps.csv"))
        asked = GRASPS_PER_SCENE * round(max(0, args.grasps - written) / GRASPS_PER_SCENE)
        seed = args.seed + 1000 + written
    vgn_job = steps.vgn_job(
        "labels_vgn",
        "generate_data.py",
        [str(vgn_raw), "--scene", "pile", "--object-set", "train", "--num-grasps", str(asked)],
        seed,
    )
    cpu_vgn, cpu = steps.run_many([vgn_job, ("labels_ours", cmd, None, None, None)])
    # the grasps the timed run of VGN's generator was asked for (a resumed labelling times its last
    # part only): from the command its step kept
    timed_vgn = int(re.search(r"--num-grasps (\d+)", steps.saved("labels_vgn")["command"]).group(1))
    counts_file = work / "labels_vgn_cleanup.json"
    if counts_file.exists():
        scenes_vgn, counts = json.loads(counts_file.read_text())
    else:
        scenes_vgn = int(pd.read_csv(vgn_raw / "grasps.csv")["scene_id"].nunique())
        counts = clean_vgn_raw(vgn_raw, 0.3)
        counts_file.write_text(json.dumps([scenes_vgn, counts]))
    rows.append(
        {
            "labels": "vgn",
            "scenes": scenes_vgn,
            "cpu_s": round(cpu_vgn, 1),
            "timed_grasps": timed_vgn,
            **counts,
            **positive_widths(vgn_raw / "grasps.csv"),
        }
    )
    labels = pd.read_parquet(ours_labels)
    cmd = [
        _exe("annotator"),
        "export",
        str(ours_labels),
        "--format",
        "vgn",
        "--balance",
        "--out",
        str(ours_raw),
    ]
    steps.run("export_ours", cmd)
    exported = json.loads((ours_raw / "_export.json").read_text())
    left = {x["reason"]: x["grasps"] for x in exported.get("left_out", [])}
    kept = pd.read_csv(ours_raw / "grasps.csv")
    rows.append(
        {
            "labels": "ours",
            "scenes": scenes,
            "cpu_s": round(cpu, 1),
            "timed_grasps": len(labels),
            "grasps": len(labels),
            "positives": int(labels["success"].sum()),
            "outside_grid": next((v for k, v in left.items() if k.startswith("outside")), 0),
            "near_side": next((v for k, v in left.items() if k.startswith("within")), 0),
            "dropped": next((v for k, v in left.items() if k.startswith("negatives")), 0),
            "kept": len(kept),
            "kept_positives": int(kept["label"].sum()),
            **positive_widths(ours_raw / "grasps.csv"),
        }
    )
    for row in rows:
        print(
            f"labels {row['labels']}: {row['grasps']} grasps of {row['scenes']} scenes, {row['positives']} held "  # noqa: E501
            f"({100 * row['positives'] / max(row['grasps'], 1):.1f} %); after VGN's cleanup {row['kept']} "
            f"({row['kept_positives']} positives)"
        )
        record.figure(f"labels_{row['labels']}_grasps", row["grasps"], note=f"{row['scenes']} pile scenes")
        record.figure(
            f"labels_{row['labels']}_positive_share", 100 * row["positives"] / max(row["grasps"], 1), "%"
        )
        record.figure(
            f"labels_{row['labels']}_train_grasps", row["kept"], note="after VGN's cleanup (balanced)"
        )
        record.figure(
            f"labels_{row['labels']}_cpu_s",
            row["cpu_s"],
            "CPU-s",
            note=f"the last run of the step, which labelled {row['timed_grasps']} grasps",
        )
        record.figure(
            f"labels_{row['labels']}_cpu_s_per_grasp",
            row["cpu_s"] / max(row["timed_grasps"], 1),
            "CPU-s",
            note="CPU-seconds per labelled grasp, over the step's last run",
        )
    for row in rows:
        record.figure(
            f"labels_{row['labels']}_positive_width_median",
            row["positive_width_median_mm"],
            "mm",
            spread=(row["positive_width_p05_mm"], row["positive_width_p95_mm"]),
            note="the widths of the positives left to train on: median, 5th to 95th percentile",
        )
    record.table("labels", rows, note="before and after VGN's data notebook's cleanup")
    record.table(
        "ours_positive_widths",
        widths_by_family(labels),
        note="our labels' positives by training-object family: how many and their widths (mm); "
        "VGN's generator does not record which object a grasp is on",
    )
    datasets = {}
    for name, raw in (("vgn", vgn_raw), ("ours", ours_raw)):
        datasets[name] = work / f"dataset_{name}"
        if datasets[name].exists() and steps.saved(f"dataset_{name}") is None:
            shutil.rmtree(datasets[name])
        steps.vgn(f"dataset_{name}", "construct_dataset.py", [str(raw), str(datasets[name])], args.seed)
    return datasets


# --- step 3: training --------------------------------------------------------------------------------


def train(args, steps: Steps, work: Path, datasets: dict[str, Path], record: Run) -> dict[str, Path]:
    """Step 3: VGN's train_vgn.py on each dataset; the last epoch's model of each and the curves."""
    models, rows, jobs, logdirs = {}, [], [], {}
    for name, dataset in datasets.items():
        logdirs[name] = logdir = work / "runs" / name
        if logdir.exists() and steps.saved(f"train_{name}") is None:
            shutil.rmtree(logdir)
        argv = [
            "--dataset", str(dataset), "--logdir", str(logdir), "--description", name, "--net", "conv",
            "--epochs", str(args.epochs), "--batch-size", str(args.batch_size), "--lr", "3e-4",
            "--val-split", str(args.val_split),
        ]  # fmt: skip
        jobs.append(steps.vgn_job(f"train_{name}", "train_vgn.py", argv, args.seed, args.threads))
    cpus = steps.run_many(jobs) if args.parallel else [steps.run_many([job])[0] for job in jobs]
    for (name, logdir), cpu in zip(logdirs.items(), cpus, strict=True):
        run_dir = next(p for p in logdir.iterdir() if p.is_dir())
        checkpoints = sorted(run_dir.glob("*.pt"), key=lambda p: (p.stat().st_mtime, p.name))
        models[name] = checkpoints[-1]
        env = dict(os.environ, PYTHONPATH=str(args.vgn / "src"))
        out = subprocess.run(
            [str(args.vgn_python), "-W", "ignore", "-c", CURVES, str(run_dir)],
            capture_output=True,
            text=True,
            check=True,
            env=env,
        )
        curves = json.loads(out.stdout)
        epochs = sorted({s for part in curves.values() for tag in part.values() for s, _ in tag})
        for epoch in epochs:
            row = {"labels": name, "epoch": epoch}
            for part, short in (("train", "train"), ("validation", "val")):
                for tag in ("loss", "accuracy"):
                    values = dict(map(tuple, curves.get(part, {}).get(tag, [])))
                    row[f"{short}_{tag}"] = values.get(epoch)
            rows.append(row)
        last = rows[-1]
        print(
            f"training {name}: {len(epochs)} epochs, {cpu:.0f} CPU-s; last epoch: loss {last['train_loss']}, "
            f"validation loss {last['val_loss']}, validation accuracy {last['val_accuracy']}"
        )
        record.figure(f"train_{name}_cpu_s", cpu, "CPU-s")
        record.figure(
            f"train_{name}_val_accuracy",
            100 * (last["val_accuracy"] or float("nan")),
            "%",
            note="the last epoch, VGN's accuracy of the rounded quality on its validation split",
        )
        record.figure(f"train_{name}_val_loss", last["val_loss"] or float("nan"), note="the last epoch")
    record.table("training_curves", rows, note="per epoch, from train_vgn.py's TensorBoard logs")
    return models


# --- step 4: judging ---------------------------------------------------------------------------------


def _row(
    sim: str, arrangement: str, policy: str, rounds: int, objects: int, attempts: int, successes: int, **extra
) -> dict:
    from annotator.policies.clutter import wilson

    lo, hi = wilson(successes, attempts)
    clo, chi = wilson(successes, objects)
    return {
        "sim": sim,
        "arrangement": arrangement,
        "policy": policy,
        "rounds": rounds,
        "objects": objects,
        "attempts": attempts,
        "successes": successes,
        "success": round(100 * successes / attempts, 2) if attempts else float("nan"),
        "success_lo": round(100 * lo, 2),
        "success_hi": round(100 * hi, 2),
        "cleared": round(100 * successes / objects, 2) if objects else float("nan"),
        "cleared_lo": round(100 * clo, 2),
        "cleared_hi": round(100 * chi, 2),
        **extra,
    }


def judge_vgn(args, steps: Steps, work: Path, models: dict[str, Path]) -> list[dict]:
    """VGN's sim_grasp.py with each network, piles and packed, the same seed (the same piles); an
    arrangement's networks judged side by side (one process each). Then, with ``--seen-rounds``,
    best-first piles of the training objects (rows of sim ``vgn_seen``): what each network learned
    of the objects it saw, apart from what it carries to others."""
    rows = []
    passes = [
        ("test", a, d, args.rounds, "vgn", "")
        for a, d in itertools.product(args.arrangements, args.detections)
    ]
    if args.seen_rounds:
        passes.append(("train", "pile", "best", args.seen_rounds, "vgn_seen", "seen_"))
    for object_set, arrangement, detect, rounds_asked, sim, prefix in passes:
        jobs, logdirs = [], {}
        for name, model in models.items():
            name = _judged(name, detect)
            step = f"sim_vgn_{prefix}{arrangement}_{name}"
            logdir = logdirs[name] = work / "sim_vgn" / f"{prefix}{arrangement}_{name}"
            saved = steps.saved(step)
            if saved is not None and rounds_of(saved["command"]) != rounds_asked:
                before = rounds_of(saved["command"])
                print(f"[{step}] judged over {before} rounds before, {rounds_asked} asked: again")
                steps.forget(step)
            if logdir.exists() and steps.saved(step) is None:
                shutil.rmtree(logdir)
            argv = [
                "--model", str(model), "--logdir", str(logdir), "--description", name, "--scene", arrangement,
                "--object-set", object_set, "--num-objects", "5", "--num-rounds", str(rounds_asked),
                "--seed", str(args.seed + 1),
            ]  # fmt: skip
            jobs.append(steps.vgn_job(step, "sim_grasp.py", argv, args.seed, args.threads, detect))
        for (name, logdir), cpu in zip(logdirs.items(), steps.run_many(jobs), strict=True):
            run_dir = next(p for p in logdir.iterdir() if p.is_dir())
            rounds = pd.read_csv(run_dir / "rounds.csv")
            grasps = pd.read_csv(run_dir / "grasps.csv")
            row = _row(
                sim,
                arrangement,
                f"vgn_net_{name}",
                len(rounds),
                int(rounds["object_count"].sum()),
                len(grasps),
                int(grasps["label"].sum()),
                cpu_s=round(cpu, 1),
                **ratings(grasps),
            )
            rows.append(row)
            _print(row)
    return rows


def judge_ours(args, work: Path, models: dict[str, Path]) -> list[dict]:
    """Our clutter removal on the UR3 with the Panda: each network, vision-random and the labels
    oracle on the same rounds."""
    from annotator.grippers import load_gripper
    from annotator.objects import default_cache_dir, discover_objects
    from annotator.pipeline.in_memory import ExecutionOptions
    from annotator.policies.clutter import ClutterSetup
    from annotator.tools.clutter_runs import run_clutter_removal

    config = AnnotatorConfig()
    sources = tuple(discover_objects(work / "vgn" / "data" / "urdfs" / "test", config.objects))
    panda = load_gripper("panda")
    policies = [
        (f"vgn_net_{_judged(name, detect)}", "bench.vgn_policy:vgn", model, detect)
        for detect in args.detections
        for name, model in models.items()
    ]
    policies += [("vision_random", "vision-random", None, None), ("labels_oracle", "labels", None, None)]
    rows = []
    for arrangement in args.arrangements:
        for label, policy, model, detect in policies:
            extra = ()
            if model is not None:
                extra = (
                    ("model", str(model)),
                    ("vgn", str(args.vgn)),
                    ("python", str(args.vgn_python)),
                    ("threads", str(args.threads)),
                    *((("threshold", "0"),) if detect == "best" else ()),
                )
            rounds = args.oracle_rounds if policy == "labels" else args.rounds
            keep = work / "sim_ours" / f"{arrangement}_{label}"
            kept = json.loads((keep / "row.json").read_text()) if (keep / "row.json").exists() else None
            if kept is not None and kept["rounds"] != rounds:
                print(f"[{keep.name}] judged over {kept['rounds']} rounds before, {rounds} asked: again")
                shutil.rmtree(keep)
            elif kept is not None:  # finished by an earlier run of this --work
                row = kept | {"resumed": True}
                rows.append(row | (_kept_ratings(keep / "grasps.csv") if model is not None else {}))
                _print(rows[-1])
                continue
            job = ClutterSetup(
                sources,
                5,
                args.seed,
                policy,
                config,
                gripper=panda,
                cache_dir=str(default_cache_dir()),
                policy_args=extra,
                views=args.views,
                arrangement=arrangement,
            )
            t0, c0 = time.perf_counter(), time.process_time() + _children_cpu()
            summary = run_clutter_removal(job, rounds, ExecutionOptions(args.workers))
            vgn_policy.close_servers()  # waited for: its CPU is counted below
            cpu = time.process_time() + _children_cpu() - c0
            keep.mkdir(parents=True, exist_ok=True)
            rounds_table, grasps = summary.tables()
            rounds_table.to_csv(keep / "rounds.csv", index=False)
            grasps.to_csv(keep / "grasps.csv", index=False)
            row = _row(
                "ours",
                arrangement,
                label,
                len(summary.rounds),
                summary.objects,
                summary.attempts,
                summary.successes,
                cpu_s=round(cpu, 1),
                seconds=round(time.perf_counter() - t0, 1),
                **(ratings(grasps) if model is not None else {}),
            )
            (keep / "row.json").write_text(json.dumps(row))
            rows.append(row)
            _print(row)
    return rows


def ratings(grasps: pd.DataFrame) -> dict:
    """The network's ratings of the grasps it executed (a clutter removal's ``grasps.csv``, its
    ``score`` column: VGN's quality of each): their median and the share rated at least 0.9 (what
    VGN's detection keeps), and the executed widths' median (mm, its ``width``); NaN with no
    attempt."""
    if len(grasps) == 0 or "score" not in grasps:
        return {"rating_median": float("nan"), "rated_0_9": float("nan"), "width_median_mm": float("nan")}
    scores = grasps["score"].to_numpy(dtype=float)
    return {
        "rating_median": round(float(np.median(scores)), 3),
        "rated_0_9": round(100 * float(np.mean(scores >= 0.9)), 1),
        "width_median_mm": round(1000 * float(np.median(grasps["width"].to_numpy(dtype=float))), 1),
    }


def _kept_ratings(path: Path) -> dict:
    """:func:`ratings` of a kept ``grasps.csv`` (an empty file: no attempt)."""
    try:
        return ratings(pd.read_csv(path))
    except (pd.errors.EmptyDataError, FileNotFoundError):
        return ratings(pd.DataFrame())


def rounds_of(command: str) -> int | None:
    """The rounds a kept sim_grasp.py command asked for (its ``--num-rounds``); None if none."""
    found = re.search(r"--num-rounds (\d+)", command)
    return int(found.group(1)) if found else None


def _judged(name: str, detect: str) -> str:
    """The name a network trained on ``name``'s labels is judged under: ``name`` with VGN's
    detection, ``name_best`` with the best-first one."""
    return name if detect == "vgn" else f"{name}_{detect}"


def ours_by_object(work: Path, arrangements: list[str]) -> list[dict]:
    """Our clutter removal's attempts per policy, arrangement and the object each went for (its
    ``target_object``): attempts, successes and the failures by cause, read from the kept
    ``sim_ours/<arrangement>_<policy>/grasps.csv`` (where a network trained on our labels loses
    to the one trained on VGN's, object by object)."""
    rows = []
    for arrangement in arrangements:
        for folder in sorted((work / "sim_ours").glob(f"{arrangement}_*")):
            if not (folder / "row.json").exists():  # not finished
                continue
            try:
                grasps = pd.read_csv(folder / "grasps.csv")
            except pd.errors.EmptyDataError:  # no attempt at all (a network that proposed nothing)
                continue
            policy = folder.name.removeprefix(f"{arrangement}_")
            for target, attempts in grasps.groupby("target_object"):
                causes = attempts["failure"].dropna().value_counts()
                rows.append(
                    {
                        "arrangement": arrangement,
                        "policy": policy,
                        "object": target,
                        "attempts": len(attempts),
                        "successes": int(attempts["label"].sum()),
                        "failures": "; ".join(f"{cause}: {n}" for cause, n in causes.items()),
                    }
                )
    return rows


def _print(row: dict) -> None:
    print(
        f"{row['sim']:>4} {row['arrangement']:<6} {row['policy']:<16} success {row['success']:.1f} % "
        f"({row['success_lo']:.1f}-{row['success_hi']:.1f}), {row['successes']} of {row['attempts']}; cleared "  # noqa: E501
        f"{row['cleared']:.1f} % ({row['cleared_lo']:.1f}-{row['cleared_hi']:.1f}) of {row['objects']}, "
        f"{row['rounds']} rounds"
        + (
            f"; rated: median {row['rating_median']:.3f}, {row['rated_0_9']:.1f} % at least 0.9"
            if "rating_median" in row
            else ""
        ),
        flush=True,
    )


def targets(rows: list[dict]) -> list[str]:
    """The targets (module docstring), one line each: with VGN's detection, and with the
    best-first one (``_best``) where it was judged."""
    out = []
    by = {(r["sim"], r["arrangement"], r["policy"]): r for r in rows}
    for detect, suffix in (("VGN's detection", ""), ("best-first", "_best")):
        for sim, arrangement in sorted(
            {(r["sim"], r["arrangement"]) for r in rows if r["sim"] != "vgn_seen"}
        ):
            ours = by.get((sim, arrangement, f"vgn_net_ours{suffix}"))
            theirs = by.get((sim, arrangement, f"vgn_net_vgn{suffix}"))
            if ours and theirs:
                enough = min(ours["attempts"], theirs["attempts"]) >= 100
                met = _at_least(ours, theirs, "success") and _at_least(ours, theirs, "cleared") and enough
                out.append(
                    f"{sim} {arrangement} ({detect}): trained on ours {ours['success']:.1f} % success, "
                    f"{ours['cleared']:.1f} % cleared; on VGN's {theirs['success']:.1f} %, {theirs['cleared']:.1f} %; "  # noqa: E501
                    f"{min(ours['attempts'], theirs['attempts'])} attempts (>= 100): target {'met' if met else 'NOT met'}"  # noqa: E501
                )
        rand = by.get(("ours", "pile", "vision_random"))
        for name in ("ours", "vgn"):
            net = by.get(("ours", "pile", f"vgn_net_{name}{suffix}"))
            if net and rand:
                gain = net["cleared"] - rand["cleared"]
                out.append(
                    f"ours pile ({detect}): network trained on {name} clears {gain:+.1f} points vs "
                    f"vision-random (>= 10): {'met' if gain >= 10 else 'NOT met'}"
                )
    return out


def _at_least(ours: dict, theirs: dict, key: str) -> bool:
    """``ours[key] >= theirs[key]``, a figure of no attempt (NaN) never at least another."""
    return not math.isnan(ours[key]) and (math.isnan(theirs[key]) or ours[key] >= theirs[key])


def record_judged(record: Run, rows: list[dict]) -> None:
    """Each judged row's success and percent cleared as figures of ``record``, named
    ``<sim>_<arrangement>_<policy>_success`` and ``_cleared``, with their 95 % Wilson intervals."""
    for row in rows:
        key = f"{row['sim']}_{row['arrangement']}_{row['policy']}"
        for figure, out_of in (("success", "attempts"), ("cleared", "objects")):
            record.figure(
                f"{key}_{figure}",
                row[figure],
                "%",
                spread=(row[f"{figure}_lo"], row[f"{figure}_hi"]),
                note=f"95 % Wilson, {row['successes']} of {row[out_of]} {out_of}",
            )


def whole_bench(commands: list[dict], judged: list[dict]) -> dict:
    """The whole bench's cost across every run of one --work: the CPU seconds and wall seconds of
    every step (``commands``, rows kept from earlier runs included) and of our judging (``judged``
    rows with ``seconds``). Steps run side by side are each counted whole, so the wall is an upper
    bound of the time the bench took."""
    rows = [*commands, *(r for r in judged if "seconds" in r)]
    return {
        "cpu_s": round(sum(r["cpu_s"] for r in rows), 1),
        "seconds": round(sum(r["seconds"] for r in rows), 1),
        "steps": len(rows),
    }


def run_tag(quick: bool, until: str) -> str | None:
    """The record's tag: ``quick`` for a --quick run and ``until-STAGE`` for a run stopped after a
    stage (so that neither stands for the full run on the performance page); None for a full run."""
    parts = ["quick"] if quick else []
    if until != STAGES[-1]:
        parts.append(f"until-{until}")
    return "-".join(parts) or None


def parser() -> Parser:
    parser = Parser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--vgn", type=existing_folder, required=True, help="a checkout of ethz-asl/vgn (branch corl2020)"
    )
    parser.add_argument("--vgn-python", type=existing_file, required=True, help="the Python that runs VGN")
    parser.add_argument("--quick", action="store_true", help="every step, small (under 20 minutes)")
    parser.add_argument(
        "--grasps",
        type=count(1, 10_000_000),
        default=None,
        help="VGN's --num-grasps (default 3600; quick 240)",
    )
    parser.add_argument(
        "--per-family", type=count(1, 10_000), default=None, help="training objects per family (4; quick 1)"
    )
    parser.add_argument(
        "--epochs", type=count(1, 10_000), default=None, help="training epochs (default 3; quick 1)"
    )
    parser.add_argument(
        "--batch-size", type=count(1, 100_000), default=None, help="default VGN's 32; quick 2"
    )
    parser.add_argument(
        "--val-split",
        type=number(0.0, 1.0, low_open=True, high_open=True),
        default=None,
        help="train_vgn.py's validation share (VGN's 0.1; quick 0.5)",
    )
    parser.add_argument(
        "--rounds", type=count(1, 100_000), default=None, help="clutter rounds per network (40; quick 2)"
    )
    parser.add_argument(
        "--oracle-rounds",
        type=count(1, 100_000),
        default=None,
        help="the labels oracle's rounds (20; quick 1)",
    )
    parser.add_argument(
        "--seen-rounds",
        type=count(0, 100_000),
        default=None,
        help="best-first piles of the training objects in VGN's simulation per network (20; quick 1; 0 none)",
    )
    parser.add_argument(
        "--views", type=count(1, 100), default=3, help="our scenes' depth views, labels and policies"
    )
    parser.add_argument("--arrangements", nargs="+", default=["pile", "packed"], choices=["pile", "packed"])
    parser.add_argument(
        "--detections",
        nargs="+",
        default=["vgn", "best"],
        choices=["vgn", "best"],
        help="how each network is judged: vgn = VGN's detection (a random one of its local maxima "
        "rated above 0.9), best = its best-rated local maximum whatever the rating (both by default)",
    )
    parser.add_argument("--seed", type=seed, default=0)
    parser.add_argument(
        "--workers", type=count(1, WORKERS_MAX), default=1, help="annotate's and our clutter loop's workers"
    )
    parser.add_argument(
        "--threads", type=count(1, 1024), default=1, help="torch threads in VGN's training and detection"
    )
    parser.add_argument("--nice", type=count(0, 19), default=15, help="niceness of every subprocess")
    parser.add_argument(
        "--serial", dest="parallel", action="store_false", help="train the two networks one after the other"
    )
    parser.add_argument(
        "--work", type=writable_folder, default=None, help="working folder (default: a temporary one)"
    )
    parser.add_argument(
        "--until",
        choices=STAGES,
        default=STAGES[-1],
        help="stop after this stage and write the record of what was run (its own, tagged until-STAGE): "
        "a long run measured in parts, each finished step of a --work resumed, not run again",
    )
    return parser


def main() -> None:
    args = parser().parse_args()
    quick = {"grasps": 240, "per_family": 1, "epochs": 1, "batch_size": 2, "val_split": 0.5, "rounds": 2,
             "oracle_rounds": 1, "seen_rounds": 1}  # fmt: skip
    full = {"grasps": 9600, "per_family": 4, "epochs": 3, "batch_size": 32, "val_split": 0.1, "rounds": 40,
            "oracle_rounds": 20, "seen_rounds": 20}  # fmt: skip
    for key, value in (quick if args.quick else full).items():
        if getattr(args, key) is None:
            setattr(args, key, value)
    args.vgn, args.vgn_python = args.vgn.resolve(), args.vgn_python.absolute()
    provenance = vgn_provenance(args.vgn)
    recorded = {k: str(v) for k, v in vars(args).items()} | {f"vgn_{k}": v for k, v in provenance.items()}
    recorded["vgn_libraries"] = vgn_libraries(args.vgn_python)
    print(
        f"VGN: {args.vgn} at {provenance['commit']} ({provenance['branch']}), licence: {provenance['licence']}"  # noqa: E501
    )
    tag = run_tag(args.quick, args.until)
    with Run("peer_network", config=recorded, tag=tag) as record, tempfile.TemporaryDirectory() as tmp:
        work = (args.work or Path(tmp)).resolve()
        work.mkdir(parents=True, exist_ok=True)
        steps = Steps(args, work)
        train_set, _, _ = prepare_objects(args, work, record)
        datasets = make_labels(args, steps, work, train_set, record)
        if args.until == "labels":
            record.table("commands", steps.rows, note="every subprocess, its CPU (itself and its children)")
            return
        models = train(args, steps, work, datasets, record)
        if args.until == "training":
            record.table("commands", steps.rows, note="every subprocess, its CPU (itself and its children)")
            return
        rows = judge_vgn(args, steps, work, models)
        rows += judge_ours(args, work, models)
        record_judged(record, rows)
        record.table("clutter_removal", rows, note="grasp success and percent cleared, 95 % Wilson intervals")
        record.table(
            "ours_by_object",
            ours_by_object(work, args.arrangements),
            note="our clutter removal's attempts by the object each went for: successes, failures by cause",
        )
        record.table("commands", steps.rows, note="every subprocess, its CPU (itself and its children)")
        whole = whole_bench(steps.rows, rows)
        record.figure(
            "whole_bench_cpu_s",
            whole["cpu_s"],
            "CPU-s",
            note=f"{whole['steps']} steps, every run of this --work",
        )
        record.figure(
            "whole_bench_s",
            whole["seconds"],
            "s",
            note="the steps' walls summed (side-by-side steps each counted whole: an upper bound), every run of this --work",  # noqa: E501
        )
        for line in targets(rows):
            print(line)
        hours = whole["seconds"] / 3600
        cpu_hours = whole["cpu_s"] / 3600
        print(
            f"whole bench: {hours:.1f} h of summed step walls, {cpu_hours:.1f} CPU-h (< 8 h on 2 cores): "
            f"{'met' if hours < 8 else 'NOT met'}"
        )


if __name__ == "__main__":
    main()
