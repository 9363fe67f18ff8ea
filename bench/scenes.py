"""Scenes: labelled grasps per CPU-second on piles, an independent collision check of the successes,
and clutter removal on the UR3 with the labels policy and the random baseline.

    python -m bench.scenes                          # all three parts
    python -m bench.scenes --parts throughput collisions --scenes 20
    python -m bench.scenes --parts clutter --rounds 30 --workers 2

- ``throughput``: ``annotate --objects objects/ --scenes S --n 120`` (piles of 5 sample objects,
  VGN's 120 grasps per scene) as a subprocess: every scene is settled by the run itself (cold scene
  generation included; convex decompositions come from the cache). Labelled grasps per CPU-second
  of the command and its workers (what one core delivers), and the cost of a grasp in free steps of
  the gripper (bench/reference.py, measured before and after), the ratio that survives a busier
  machine.
- ``collisions``: every success of that run checked again without PyBullet's collision detection:
  the gripper's collision boxes (posed by its model's kinematics) as meshes in trimesh's collision
  manager (FCL) against the neighbours' *meshes* and the table top's box, at the commanded grasp
  closed on its chord, and open (the chord + 2 x the clearance) at the grasp and every 2.5 mm back
  along the 10 cm approach. A neighbour's collision shape differs from its mesh by up to its
  recorded collision error, so intersections are reported with their depth.
- ``clutter``: ``annotator clutter-removal`` rounds (piles of 5) with the ``labels`` policy and the
  ``random`` baseline, on the sample objects and on those the RG2 can take from a table (without the
  160 mm ball, wider than its 110 mm stroke, and the 8 mm plate, which lies flat), with 95 %
  Wilson intervals.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from annotator.config import AnnotatorConfig
from annotator.geometry import Transform
from bench.arguments import N_MAX, WORKERS_MAX, Parser, count, existing_folder, seed, writable_folder
from bench.harness import Run
from bench.reference import free_step, median_step

ROOT = Path(__file__).resolve().parents[1]
APPROACH_STEP = 0.0025  # m between the approach poses checked (the trial checks every 10 mm)
TABLE_THICKNESS = 0.05  # m, the seed table's top (pybullet_data table/table.urdf)
NOT_FROM_A_TABLE = ("big_ball", "plate")  # wider than the RG2's stroke; lying flat, 8 mm thick


# --- throughput ----------------------------------------------------------------------------------------


def annotate_scenes(
    objects: Path, out: Path, scenes: int, n: int, workers: int | None
) -> tuple[float, float, str]:
    """``annotate --scenes`` as a subprocess: (wall s, CPU s of it and the workers it reaped, last line)."""
    exe = shutil.which("annotate", path=str(Path(sys.executable).parent)) or shutil.which("annotate")
    if exe is None:
        raise SystemExit("the annotate command is not installed (pip install -e .)")
    args = [
        exe,
        "--objects",
        str(objects),
        "--scenes",
        str(scenes),
        "--n",
        str(n),
        "--out",
        str(out),
        "--quiet",
    ]
    args += ["--workers", str(workers)] if workers else []
    with tempfile.TemporaryFile("w+") as log:
        t0 = time.perf_counter()
        proc = subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT, text=True)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        log.seek(0)
        text = log.read()
    if os.waitstatus_to_exitcode(status) not in (0, 1):
        raise SystemExit(f"annotate failed:\n{text[-2000:]}")
    return wall, usage.ru_utime + usage.ru_stime, text.strip().splitlines()[-1]


def throughput(args, record: Run, out: Path) -> None:
    config = AnnotatorConfig()
    references = [free_step(config)]
    wall, cpu, last = annotate_scenes(args.objects, out, args.scenes, args.n, args.workers)
    references.append(free_step(config))
    ref = median_step(references)
    labels = pd.read_parquet(out)
    grasps = len(labels)
    print(last)
    print(f"{grasps} grasps in {wall:.1f} s wall, {cpu:.1f} CPU-s: {grasps / cpu:.1f} grasps per CPU-second")
    print(f"one grasp costs {cpu / grasps / ref.cpu:.0f} free steps ({ref.cpu_ms:.3f} CPU ms each)")
    record.ratio(
        "free_steps_per_grasp",
        cpu / grasps / ref.cpu,
        note="CPU time of annotate --scenes (and its workers) per labelled grasp / CPU time of a free step",
    )
    record.figure("grasps_per_cpu_second", grasps / cpu, note="labelled grasps per CPU-second (per core)")
    record.figure(
        "grasps_per_wall_second", grasps / wall, note=f"with {args.workers or os.cpu_count()} workers"
    )
    record.figure("free_step_cpu_ms", ref.cpu_ms, "ms", note="the reference, median of two, before and after")
    outcomes = labels["outcome"].value_counts()
    record.table(
        "labels",
        [
            {
                "scenes": int(labels["scene_id"].nunique()),
                "grasps": grasps,
                "successes": int(labels["success"].sum()),
                "simulated": int((labels["outcome"] != "collision").sum()),
                "collision_neighbour": int((labels["collided_with"] == "neighbour").sum()),
                "collision_object": int((labels["collided_with"] == "object").sum()),
                "collision_table": int((labels["collided_with"] == "table").sum()),
                "disturbed": int(labels["disturbed"].sum()),
                **{f"outcome_{k}": int(v) for k, v in outcomes.items()},
            }
        ],
    )


# --- the independent collision check ---------------------------------------------------------------------


class GripperBoxes:
    """The gripper's collision boxes in its TCP frame at any opening (the model's kinematics, read
    once per opening from a private PyBullet client: only the poses come from PyBullet)."""

    def __init__(self) -> None:
        from annotator.grippers import load_gripper
        from annotator.sim.body import Body
        from annotator.sim.gripper import ParallelGripper
        from annotator.sim.world import World

        self.world = World()
        description = load_gripper(None)
        self.body = Body.load(self.world.client, description.urdf, fixed_base=True)
        self.gripper = ParallelGripper(self.body, description, AnnotatorConfig().gripper)

    def at(self, width: float, placed_for: float) -> list[tuple[np.ndarray, np.ndarray]]:
        """(extents (3,), T_tcp_box (4, 4)) of every collision box, the gripper placed so that its TCP
        at opening ``placed_for`` is the frame's origin, the fingers at opening ``width`` (m): as the
        trial places it, for the chord, and opens it for the approach (a linkage's pads then sit
        higher than the TCP)."""
        from annotator.sim import pb

        g = self.gripper
        self.body.reset_base_pose(g.T_base_tcp(placed_for).inverse())
        g.reset_width(width)
        out = []
        client, uid = self.world.client, self.body.uid
        for index in [-1, *self.body.links.values()]:
            if index == -1:
                pos, orn = pb.getBasePositionAndOrientation(uid, physicsClientId=client)
            else:
                pos, orn = pb.getLinkState(uid, index, computeForwardKinematics=1, physicsClientId=client)[:2]
            T_com = Transform(pos, orn)
            for shape in pb.getCollisionShapeData(uid, index, physicsClientId=client):
                if shape[2] != pb.GEOM_BOX:
                    continue
                out.append((np.asarray(shape[3]), (T_com * Transform(shape[5], shape[6])).as_matrix()))
        return out

    def close(self) -> None:
        self.world.close()


def _scene_manager(record, meshes, target: int, table_half: np.ndarray):
    """trimesh's collision manager with the target's neighbours (meshes, table frame) and the table
    top (a box of half size ``table_half`` (2,) m, its top face the table frame's z = 0)."""
    import trimesh

    manager = trimesh.collision.CollisionManager()
    for inst in record.kept:
        if inst.instance_id != target:
            manager.add_object(
                f"instance {inst.instance_id}", meshes[inst.object_id], inst.T_table_obj.as_matrix()
            )
    table = trimesh.creation.box(extents=[2 * table_half[0], 2 * table_half[1], TABLE_THICKNESS])
    manager.add_object("table", table, Transform([0, 0, -TABLE_THICKNESS / 2], [0, 0, 0, 1]).as_matrix())
    return manager


def collisions(record_run: Path, record: Run, config: AnnotatorConfig) -> None:
    from annotator.cell.world import build_cell
    from annotator.sim.world import World
    from annotator.tools.common import object_mesh
    from annotator.tools.scene_labels import open_scene_labels

    with World() as world:
        table_half = build_cell(world, config.cell, robot=False, kinect=False).top.half_size
    scenes = open_scene_labels(record_run, "bench")
    labels = scenes.labels
    meshes = {oid: object_mesh(record_run, oid) for oid in sorted(labels["object_id"].unique())}
    error = labels.groupby("object_id")["collision_error"].max().to_dict()  # m, each object's
    boxes = GripperBoxes()
    p = config.protocol
    backs = np.arange(0.0, p.approach_distance + 1e-9, APPROACH_STEP)
    hits, checked, worst = [], 0, 0.0
    try:
        for scene_id in scenes.scene_ids():
            rec = scenes.records[scene_id]
            rows = scenes.rows(scene_id)
            for row in rows[rows["success"]].itertuples():
                manager = _scene_manager(rec, meshes, int(row.instance_id), table_half)
                T_obj_tcp = Transform.exact(
                    [row.cmd_x, row.cmd_y, row.cmd_z], [row.cmd_qx, row.cmd_qy, row.cmd_qz, row.cmd_qw]
                )
                T_table_tcp = rec.instance(int(row.instance_id)).T_table_obj * T_obj_tcp
                chord = float(row.cmd_width)
                open_width = min(boxes.gripper.max_width, chord + 2 * p.pregrasp_clearance)
                poses = [(chord, T_table_tcp, "closed")]
                approach = T_table_tcp.rotation[:, 2]
                poses += [
                    (
                        open_width,
                        Transform(T_table_tcp.pos - b * approach, T_table_tcp.quat),
                        f"open {b * 1000:.1f} mm back",
                    )
                    for b in backs
                ]
                checked += 1
                for width, T, where in poses:
                    found = _touching(manager, boxes.at(width, chord), T.as_matrix())
                    if found:
                        name, depth = found
                        worst = max(worst, depth)
                        tolerance = _tolerance(name, rec, error)
                        hits.append(
                            {
                                "scene_id": scene_id,
                                "grasp_id": int(row.grasp_id),
                                "object_id": row.object_id,
                                "hit": name,
                                "where": where,
                                "depth_mm": round(1000 * depth, 3),
                                "collision_error_mm": round(1000 * tolerance, 3),
                                "beyond_collision_error": bool(depth > tolerance),
                            }
                        )
                        break
    finally:
        boxes.close()
    beyond = [h for h in hits if h["beyond_collision_error"]]
    print(f"{checked} successes checked on the meshes: {len(hits)} intersect a neighbour or the table,")
    print(f"{len(beyond)} deeper than the neighbour's collision error (its shape's distance from its mesh)")
    for hit in hits[:40]:
        print("  ", hit)
    record.figure("successes_checked", checked, note="successes of the throughput run, every scene")
    record.figure(
        "successes_intersecting", len(hits), note="gripper boxes vs neighbour meshes and the table (FCL)"
    )
    record.figure(
        "successes_intersecting_beyond_collision_error",
        len(beyond),
        note="deeper than the neighbour's recorded collision error (the table: any depth)",
    )
    record.figure("deepest_intersection_mm", 1000 * worst, "mm", note="the deepest of those, 0 without any")
    record.table("intersections", hits or [{"scene_id": None}], note="one row per success that intersects")


def _tolerance(names: str, record, error: dict[str, float]) -> float:
    """How deep an intersection with what ``names`` names can be and still be the neighbour's collision
    shape differing from its mesh: its object's recorded collision error (the table: 0)."""
    for name in names.split(", "):
        if name.startswith("instance "):
            return float(error.get(record.instance(int(name.split()[1])).object_id, 0.0))
    return 0.0


def _touching(manager, boxes, T_table_tcp: np.ndarray):
    """(name, depth m) of the first box that intersects something in ``manager``, or None."""
    import trimesh

    for extents, T_tcp_box in boxes:
        box = trimesh.creation.box(extents=extents)
        hit, contacts = manager.in_collision_single(box, T_table_tcp @ T_tcp_box, return_data=True)
        if hit:
            depth = max((c.depth for c in contacts), default=0.0)
            names = sorted(set(n for c in contacts for n in c.names) - {"__external"})
            return ", ".join(names), float(depth)
    return None


# --- clutter removal ---------------------------------------------------------------------------------


def clutter(args, record: Run) -> None:
    from annotator.objects import default_cache_dir, discover_objects
    from annotator.pipeline.in_memory import ExecutionOptions
    from annotator.policies.clutter import ClutterSetup, wilson
    from annotator.tools.clutter_runs import run_clutter_removal

    config = AnnotatorConfig()
    everything = tuple(discover_objects(args.objects))
    sets = {
        "sample": everything,
        "from_a_table": tuple(s for s in everything if s.object_id not in NOT_FROM_A_TABLE),
    }
    rows = []
    for set_name, sources in sets.items():
        for policy in ("labels", "random"):
            t0 = time.perf_counter()
            job = ClutterSetup(sources, 5, args.seed, policy, config, cache_dir=str(default_cache_dir()))
            summary = run_clutter_removal(
                job, args.rounds, ExecutionOptions(args.workers or os.cpu_count() or 1)
            )
            lo, hi = wilson(summary.successes, summary.attempts)
            clo, chi = wilson(summary.successes, summary.objects)
            for line in summary.lines(f"{policy} ({set_name})"):
                print(line)
            print(f"  {time.perf_counter() - t0:.0f} s")
            rows.append(
                {
                    "objects": set_name,
                    "policy": policy,
                    "rounds": len(summary.rounds),
                    "objects_in_piles": summary.objects,
                    "attempts": summary.attempts,
                    "successes": summary.successes,
                    "success_rate": summary.success_rate,
                    "success_lo": lo,
                    "success_hi": hi,
                    "cleared": summary.percent_cleared,
                    "cleared_lo": clo,
                    "cleared_hi": chi,
                    "rounds_cleared": sum(r.ended == "cleared" for r in summary.rounds),
                    "seconds": round(time.perf_counter() - t0, 1),
                }
            )
            key = f"{set_name}_{policy}"
            record.figure(
                f"{key}_success_rate",
                100 * summary.success_rate,
                "%",
                note=f"95 % Wilson {100 * lo:.1f}-{100 * hi:.1f} %, {summary.attempts} attempts",
                spread=(100 * lo, 100 * hi),
            )
            record.figure(
                f"{key}_percent_cleared",
                100 * summary.percent_cleared,
                "%",
                note=f"95 % Wilson {100 * clo:.1f}-{100 * chi:.1f} %, {summary.objects} objects",
                spread=(100 * clo, 100 * chi),
            )
    record.table(
        "clutter_removal", rows, note=f"{args.rounds} rounds of 5-object piles per row, seed {args.seed}"
    )


def parser() -> Parser:
    parser = Parser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--parts",
        nargs="+",
        default=["throughput", "collisions", "clutter"],
        choices=["throughput", "collisions", "clutter"],
    )
    parser.add_argument("--objects", type=existing_folder, default=ROOT / "objects")
    parser.add_argument("--scenes", type=count(1, 1_000_000), default=20, help="throughput: pile scenes of 5")
    parser.add_argument("--n", type=count(1, N_MAX), default=120, help="throughput: grasps per scene")
    parser.add_argument(
        "--rounds", type=count(1, 100_000), default=30, help="clutter: rounds per policy and object set"
    )
    parser.add_argument("--seed", type=seed, default=0)
    parser.add_argument("--workers", type=count(1, WORKERS_MAX), default=None)
    parser.add_argument(
        "--keep", type=writable_folder, default=None, help="keep the throughput run's labels here"
    )
    return parser


def main() -> None:
    ap = parser()
    args = ap.parse_args()
    if "collisions" in args.parts and "throughput" not in args.parts and args.keep is None:
        ap.error("collisions checks the throughput run's labels: run both, or give --keep DIR of one")
    config = AnnotatorConfig()
    with (
        Run("scenes", config={k: str(v) for k, v in vars(args).items()}, annotator=config) as record,
        tempfile.TemporaryDirectory() as tmp,
    ):
        out = args.keep if args.keep is not None else Path(tmp) / "labels"
        if "throughput" in args.parts:
            if out.exists():
                raise SystemExit(f"--keep {out} exists; give a new folder")
            throughput(args, record, out)
        if "collisions" in args.parts:
            collisions(out, record, config)
        if "clutter" in args.parts:
            clutter(args, record)


if __name__ == "__main__":
    main()
