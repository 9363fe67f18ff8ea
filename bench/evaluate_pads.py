"""Off-centre grasps given without a width: ``evaluate`` opens over the pads' faces, not along the
TCP's line.

    python -m bench.evaluate_pads                       # the sample objects, 40 candidates each
    python -m bench.evaluate_pads --n 60 --miss 0.003 --workers 2

A real grasp is often off the object's centre line: the pads (20.2 x 29.8 mm on the RG2) overlap
the object while the TCP's own closing line misses it. This bench makes such grasps from labels
that held: ``annotate --n N`` on the objects, then every success's commanded grasp moved along the
TCP's y (across the pads' width) until that line misses the object by ``--miss`` (the first shift,
in 0.5 mm steps, with no chord on the line, plus the miss), kept only where the pads still overlap
the object. They go to ``annotator evaluate`` twice, without a width: once as given (the opening
measured over the pads' faces, swept exactly), once with the width the TCP's line measures (0:
the opening the line-only measure gave, the behaviour before the pads' faces were swept). Prints
and records the outcomes of both and the share of ``collision`` rows and, for each collision,
its stage and what was hit; asserts nothing.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from annotator.dataset import load_labels
from bench.arguments import N_MAX, WORKERS_MAX, Parser, count, existing_folder, number
from bench.harness import ROOT, Run

STEP = 0.0005  # m, the shift's search step along the TCP's y
POSE = ["x", "y", "z", "qx", "qy", "qz", "qw"]


def annotator(*args: object) -> None:
    """Run the CLI as a user does (the installed entry point's module), quietly; raise on failure."""
    script = "import sys; from annotator.entry import main; sys.argv[0] = 'annotator'; main()"
    command = [sys.executable, "-c", script, *map(str, args)]
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)


def off_centre(labels: pd.DataFrame, folder: Path, objects: Path, miss: float) -> pd.DataFrame:
    """The successes' commanded grasps (``labels``, read from ``folder``, made of ``objects``) moved
    along their TCP y until the TCP's line misses the object by ``miss`` (m) while a pad still
    overlaps it; columns object_id, grasp_id, pose, shift."""
    from annotator.geometry import matrix_to_quat, quat_to_matrix
    from annotator.tools.common import object_mesh
    from annotator.tools.evaluate import expected_width, pad_face

    pads = pad_face("rg2")
    meshes = {
        oid: object_mesh(folder, oid, objects, labels[labels["object_id"] == oid])
        for oid in sorted(set(labels["object_id"]))
    }
    rows = []
    held = labels[labels["outcome"] == "success"]
    for row in held.itertuples():
        mesh = meshes[row.object_id]
        T = np.eye(4)
        T[:3, :3] = quat_to_matrix(np.array([row.cmd_qx, row.cmd_qy, row.cmd_qz, row.cmd_qw]))
        T[:3, 3] = [row.cmd_x, row.cmd_y, row.cmd_z]
        for sign in (1.0, -1.0):
            shifts = np.arange(1, int(0.06 / STEP)) * STEP
            moved = np.repeat(T[None], len(shifts), axis=0)
            moved[:, :3, 3] += sign * shifts[:, None] * T[:3, 1]
            line = expected_width(mesh, moved, 0.11)
            first = int(np.argmax(line == 0.0)) if (line == 0.0).any() else -1
            if first < 0:
                continue
            shift = shifts[first] + miss
            G = T.copy()
            G[:3, 3] += sign * shift * T[:3, 1]
            if expected_width(mesh, G[None], 0.11, pads)[0] <= 0.0:  # the pads miss it too
                continue
            q = matrix_to_quat(G[:3, :3])
            rows.append(
                {
                    "object_id": row.object_id,
                    "grasp_id": int(row.grasp_id),
                    **dict(zip(POSE, [*G[:3, 3], *q], strict=True)),
                    "shift": sign * shift,
                }
            )
            break
    return pd.DataFrame(rows)


def parser() -> Parser:
    ap = Parser(description=__doc__.splitlines()[0])
    ap.add_argument("--objects", type=existing_folder, default=ROOT / "objects")
    ap.add_argument(
        "--n", type=count(1, N_MAX), default=40, help="candidates per object to find successes among"
    )
    ap.add_argument(
        "--miss", type=number(0.0, 0.1), default=0.003, help="m the TCP's line misses the object by"
    )
    ap.add_argument("--workers", type=count(1, WORKERS_MAX), default=2)
    return ap


def main() -> None:
    args = parser().parse_args()
    with Run("evaluate_pads", config={k: str(v) for k, v in vars(args).items()}) as record:
        with tempfile.TemporaryDirectory() as tmp:
            work = Path(tmp)
            labels = work / "labels"
            annotator(
                "annotate", "--objects", args.objects, "--n", args.n, "--out", labels,
                "--workers", args.workers, "--quiet",
            )  # fmt: skip
            grasps = off_centre(load_labels(labels), labels, args.objects, args.miss)
            print(f"{len(grasps)} off-centre grasps from the successes of annotate --n {args.n}")
            given = work / "given.csv"
            grasps.drop(columns=["shift"]).to_csv(given, index=False)
            line = work / "line.csv"
            grasps.drop(columns=["shift"]).assign(width=0.0).to_csv(line, index=False)
            rows = []
            for name, path in (("pads' faces (no width given)", given), ("the TCP's line (width 0)", line)):
                out = work / f"ev_{path.stem}"
                annotator(
                    "evaluate", path, "--objects", args.objects, "--out", out, "--workers", args.workers,
                    "--quiet",
                )  # fmt: skip
                result = load_labels(out)
                counts = result["outcome"].value_counts().to_dict()
                collisions = result[result["outcome"] == "collision"]
                stages = collisions.groupby(["collision_stage", "collided_with"]).size().to_dict()
                where = "; ".join(f"{stage}/{hit}: {k}" for (stage, hit), k in sorted(stages.items()))
                share = len(collisions) / len(result)
                print(f"{name}: {counts}; collision {100 * share:.1f} % ({where})")
                key = "pads" if path is given else "line"
                record.figure(f"{key}_collision_share", 100 * share, "%", note=f"{len(result)} grasps")
                record.figure(
                    f"{key}_success_share",
                    100 * counts.get("success", 0) / len(result),
                    "%",
                    note="of the off-centre grasps (each a success at its centred pose)",
                )
                rows.append(
                    {
                        "opening": name,
                        "grasps": len(result),
                        **{o: int(counts.get(o, 0)) for o in ("success", "collision", "no_contact")},
                        "slipped": int(counts.get("slipped_lift", 0) + counts.get("slipped_shake", 0)),
                        "collision_stages": where,
                    }
                )
            per_object = grasps.groupby("object_id").size().to_dict()
            record.table("evaluate_off_centre", rows, note=f"off-centre grasps per object: {per_object}")


if __name__ == "__main__":
    main()
