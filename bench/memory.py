"""Peak memory of loading one object, by face count: convex spheres of about 20 k, 200 k and 2 M
faces, against the estimate the memory budget is checked with.

    python -m bench.memory                      # 20 k, 200 k, 2 M faces
    python -m bench.memory --faces 20000 200000 --format obj

Each sphere (a UV sphere: convex, closed, so its collision shape is its hull and the collision
error check meets a hull of as many faces as the mesh keeps) is written as binary STL (or OBJ) to a
scratch folder and loaded by ``annotator.objects.load_object`` in a child process of its own with
an empty decomposition cache and no memory budget; printed per size: the faces of the file and as
loaded, the child's peak RSS (``ru_maxrss`` from ``wait4``: the child and the processes it waited
for), its CPU seconds, and the estimate ``annotator.objects.memory.estimate_mb`` gives before a load
(the figure ``ObjectConfig.memory_budget`` is checked against). Peak RSS includes the interpreter
and its libraries (about 110 MB with trimesh, SciPy and PyBullet imported). Writes a record
(bench/harness.py): per size the peak, the estimate and their ratio (the estimate's margin, which
no machine's speed moves); asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from bench.arguments import Parser, count
from bench.harness import Run

CHILD = r"""
import json, sys, time, resource, dataclasses
from pathlib import Path
from annotator.config import ObjectConfig
from annotator.objects import load_object
config = ObjectConfig()
if "memory_budget" in {f.name for f in dataclasses.fields(config)}:
    config = dataclasses.replace(config, memory_budget=1e9)
t0 = time.process_time()
model = load_object(Path(sys.argv[1]), config, cache_dir=Path(sys.argv[2]))
print(json.dumps({"faces_loaded": len(model.mesh.faces), "method": model.collision_method,
                  "error_max_mm": model.collision_error.max * 1e3, "cpu_s": time.process_time() - t0}))
"""


def sphere_count(target: int) -> int:
    """n for a UV sphere of count [n, n] with about ``target`` faces (trimesh gives 4 n (n - 2))."""
    return max(4, round(1 + math.sqrt(1 + target / 4)))


def write_sphere(folder: Path, target: int, fmt: str) -> tuple[Path, int]:
    import trimesh

    n = sphere_count(target)
    unit = trimesh.creation.uv_sphere(radius=1.0, count=[n, n])  # made at 1 m: no pole vertex merged
    mesh = trimesh.Trimesh(unit.vertices * 0.1, unit.faces, process=False)  # a 20 cm ball
    path = folder / f"sphere_{len(mesh.faces)}.{fmt}"
    mesh.export(path)
    return path, len(mesh.faces)


def measure_one(path: Path, cache: Path) -> dict:
    """Load ``path`` in a child; its JSON line plus its peak RSS (MB, from wait4) and exit code."""
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen([sys.executable, "-c", CHILD, str(path), str(cache)], stdout=out, stderr=err)
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        lines, errors = out.read().strip().splitlines(), err.read().strip().splitlines()
    result = {"returncode": proc.returncode, "peak_rss_mb": usage.ru_maxrss / 1024.0}
    if proc.returncode == 0 and lines:
        result.update(json.loads(lines[-1]))
    else:
        result["error"] = (errors or ["?"])[-1][:160]
    return result


def parser() -> Parser:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--faces", type=count(100, 50_000_000), nargs="+", default=[20_000, 200_000, 2_000_000])
    ap.add_argument("--format", choices=["stl", "obj"], default="stl")
    return ap


def main() -> None:
    args = parser().parse_args()
    with Run("memory", config=vars(args)) as run:
        measure(args, run)


def measure(args: argparse.Namespace, run: Run) -> None:
    from annotator.objects import memory

    print(f"load average {os.getloadavg()[0]:.2f}")
    print(f"{'faces':>10} {'loaded':>8} {'method':>6} {'peak RSS MB':>12} {'estimate MB':>12} {'CPU-s':>7}")
    rows = []
    for target in sorted(args.faces):
        with tempfile.TemporaryDirectory(prefix="rg2-memory-") as tmp:
            path, faces = write_sphere(Path(tmp), target, args.format)
            r = measure_one(path, Path(tmp) / "cache")
        estimate = memory.estimate_mb(faces)
        if r["returncode"] != 0:
            peak = r["peak_rss_mb"]
            print(f"{faces:>10,} failed ({r['returncode']}): {r.get('error')}; peak {peak:.0f} MB")
            rows.append({"faces": faces, "failed": r.get("error"), "peak_rss_mb": r["peak_rss_mb"]})
            continue
        print(
            f"{faces:>10,} {r['faces_loaded']:>8,} {r['method']:>6} {r['peak_rss_mb']:>12,.0f} "
            f"{estimate:>12,.0f} {r['cpu_s']:>7.1f}"
        )
        rows.append(
            {
                "faces": faces,
                "faces_loaded": r["faces_loaded"],
                "method": r["method"],
                "peak_rss_mb": r["peak_rss_mb"],
                "estimate_mb": estimate,
                "cpu_s": r["cpu_s"],
            }
        )
        run.figure(f"peak_rss_mb_{faces}_faces", r["peak_rss_mb"], "MB", note="binary sphere, empty cache")
        run.ratio(
            f"estimate_vs_peak_{faces}_faces",
            estimate / r["peak_rss_mb"],
            note="memory.estimate_mb before the load / the load's measured peak RSS",
        )
    run.table("loads", rows, note="one load per size, each in a process of its own with an empty cache")


if __name__ == "__main__":
    main()
