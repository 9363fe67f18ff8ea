"""Per-object cost: the CPU a run spends on each object beyond its candidates' physics, on a folder
of thousands of small convex objects, with an empty decomposition cache (cold) and a filled one
(warm), against the same number of candidates on a few objects.

    python -m bench.object_cost                       # 2,000 objects at --n 5, 20 objects at --n 500
    python -m bench.object_cost --objects 200 --before dfdae73   # and the same on another commit

Writes ``--objects`` closed convex primitives (boxes, cylinders and capsules of 12 to 24 sides,
20-60 mm, one ``.obj`` each with float-exact coordinates; generated, never committed) and runs
``annotate --n N --workers W`` on them twice with one cache folder (cold: empty; warm: filled by the
first run), then ``annotate`` on the first ``--few`` of them with ``--n`` x objects / few candidates
each (the same number of candidates, the per-object cost spread over far fewer objects). Each
command's CPU is user + system of it and its worker processes (``os.wait4``). Recorded: CPU per
candidate of each, their ratios (many objects over few: 1 when objects cost nothing), and the
per-object overhead, (CPU of the many-object run - CPU of the few-object run) / objects. The few
objects are not the many's mix (a 20 mm cube is simulated at a finer step than a 60 mm one), so
their candidates' physics costs differ by more than some objects' overhead: the overhead is also
given with the few-object run's CPU scaled by the physics steps of the two (the labels'
``sim_steps``), (CPU many - CPU few x steps many / steps few) / objects.
``--before REV`` runs the cold and warm pair again on commit REV (its package from ``git archive``,
imported ahead of the installed one) in the same run, for same-run before/after ratios.

A record (bench/harness.py): ``object_cost``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import trimesh

from bench.arguments import N_MAX, WORKERS_MAX, Parser, count, writable_folder
from bench.harness import Run

ROOT = Path(__file__).resolve().parents[1]
SIDES = (12, 16, 20, 24)  # sides of the cylinders and capsules


def primitive(kind: int, sides: int, rng: np.random.Generator) -> trimesh.Trimesh:
    """A closed convex primitive (metres): kind 0 a box, 1 a cylinder, 2 a capsule, 20-60 mm."""
    if kind == 0:
        return trimesh.creation.box(extents=rng.uniform(0.02, 0.06, size=3))
    radius, height = rng.uniform(0.01, 0.025), rng.uniform(0.02, 0.05)
    if kind == 1:
        return trimesh.creation.cylinder(radius=radius, height=height, sections=sides)
    return trimesh.creation.capsule(height=height, radius=radius, count=[sides, sides])


def write_convex_primitives(dest: Path, count: int, seed: int = 0) -> list[Path]:
    """``count`` primitives (:func:`primitive`, kinds in turn, sides drawn from :data:`SIDES`), one
    ``.obj`` each with repr-exact coordinates, 1,000 to a subfolder; their paths."""
    rng = np.random.default_rng(seed)
    paths = []
    for i in range(count):
        mesh = primitive(i % 3, int(rng.choice(SIDES)), rng)
        folder = dest / f"set{i // 1000:04d}"
        folder.mkdir(parents=True, exist_ok=True)
        lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in np.asarray(mesh.vertices, dtype=float).tolist()]
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in np.asarray(mesh.faces).tolist()]
        path = folder / f"convex{i:07d}.obj"
        path.write_text("\n".join(lines) + "\n")
        paths.append(path)
    return paths


@dataclass(frozen=True)
class Measured:
    """One command: its exit code, wall seconds, user and system CPU seconds (with its workers);
    ``steps``: the physics steps of its labels (``sim_steps``, filled in by :func:`annotate`)."""

    code: int
    seconds: float
    user: float
    system: float
    output: str
    steps: int = 0

    @property
    def cpu(self) -> float:
        return self.user + self.system


def measured(cmd: list[str], env: dict[str, str], cwd: Path) -> Measured:
    """Run ``cmd`` in ``cwd``; its exit code, wall time and CPU of its process tree (what it
    waited for)."""
    with tempfile.TemporaryFile("w+") as out:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, env=env, cwd=cwd, stdout=out, stderr=subprocess.STDOUT, text=True)
        _, status, usage = os.wait4(proc.pid, 0)
        seconds = time.perf_counter() - t0
        out.seek(0)
        text = out.read()
    return Measured(os.waitstatus_to_exitcode(status), seconds, usage.ru_utime, usage.ru_stime, text)


def annotate(objects: Path, n: int, out: Path, cache: Path, workers: int, code: Path | None) -> Measured:
    """``annotate`` on ``objects`` at ``--n n``; ``code``: a source tree imported ahead of the
    installed package (another commit), None for this one."""
    env = {**os.environ, "RG2_CACHE_DIR": str(cache)}
    if code is not None:
        env["PYTHONPATH"] = os.pathsep.join([str(code), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    script = "import sys; from annotator.entry import annotate_main as main; sys.argv[0] = 'annotate'; main()"
    cmd = [sys.executable, "-c", script, "--objects", str(objects), "--n", str(n), "--out", str(out)]
    got = measured(cmd + ["--workers", str(workers), "--quiet"], env, cwd=out.parent)
    if got.code != 0:
        raise RuntimeError(f"annotate failed ({got.code}):\n{got.output[-3000:]}")
    steps = int(pd.read_parquet(out, columns=["sim_steps"])["sim_steps"].sum())
    return dataclasses.replace(got, steps=steps)


def parser() -> Parser:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--objects", type=count(1, 1_000_000), default=2000)
    ap.add_argument("--few", type=count(1, 1_000_000), default=20, help="objects of the comparison run")
    ap.add_argument(
        "--n", type=count(1, N_MAX), default=5, help="candidates per object of the many-object runs"
    )
    ap.add_argument("--workers", type=count(1, WORKERS_MAX), default=2)
    ap.add_argument("--before", default=None, help="a commit to measure the cold and warm runs on as well")
    ap.add_argument("--tmp", type=writable_folder, default=None, help="where the temporary folders go")
    return ap


def main() -> None:
    ap = parser()
    args = ap.parse_args()
    if (args.n * args.objects) % args.few:
        ap.error("--n x --objects must be a multiple of --few (the same candidates on fewer objects)")
    with (
        Run("object_cost", config=vars(args)) as run,
        tempfile.TemporaryDirectory(prefix="rg2-object-cost-", dir=args.tmp) as tmp_name,
    ):
        measure(args, Path(tmp_name), run)


def measure(args: argparse.Namespace, tmp: Path, run: Run) -> None:
    many = write_convex_primitives(tmp / "many", args.objects)
    few_dir = tmp / "few"
    for path in many[: args.few]:
        target = few_dir / path.relative_to(tmp / "many")
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(path, target)
    candidates = args.n * args.objects
    n_few = candidates // args.few
    trees: dict[str, Path | None] = {"": None}
    if args.before:  # the package as it was at that commit, imported ahead of the installed one
        (tmp / "before").mkdir()
        git = ["git", "archive", args.before, "annotator"]
        archive = subprocess.run(git, cwd=ROOT, capture_output=True, check=True)
        subprocess.run(["tar", "-x", "-C", str(tmp / "before")], input=archive.stdout, check=True)
        trees["before_"] = tmp / "before"
    rows = []
    results: dict[str, Measured] = {}
    for prefix, code in trees.items():
        cache = tmp / f"{prefix}cache"
        for state in ("cold", "warm"):
            got = annotate(tmp / "many", args.n, tmp / f"{prefix}{state}", cache, args.workers, code)
            results[f"{prefix}{state}"] = got
            print(f"{prefix}{state}: {got.cpu:.1f} CPU-s ({got.system:.1f} system), {got.seconds:.0f} s")
    results["few"] = annotate(few_dir, n_few, tmp / "few-out", tmp / "few-cache", args.workers, None)
    print(f"few: {results['few'].cpu:.1f} CPU-s ({results['few'].system:.1f} system)")
    few = results["few"]
    for name, got in results.items():
        objects = args.few if name == "few" else args.objects
        rows.append(
            {
                "run": name,
                "objects": objects,
                "candidates": candidates,
                "cpu_s": round(got.cpu, 2),
                "system_s": round(got.system, 2),
                "wall_s": round(got.seconds, 1),
                "cpu_ms_per_candidate": round(got.cpu / candidates * 1e3, 3),
                "sim_steps": got.steps,
            }
        )
        if name == "few":
            continue
        run.figure(
            f"{name}_overhead_cpu_s_per_object",
            (got.cpu - few.cpu) / args.objects,
            "s",
            note=f"{name}: (CPU of {args.objects} objects at --n {args.n} - CPU of the same candidates on "
            f"{args.few} objects) / {args.objects}",
        )
        run.figure(
            f"{name}_overhead_cpu_s_per_object_step_normalised",
            (got.cpu - few.cpu * got.steps / few.steps) / args.objects,
            "s",
            note=f"{name}: (CPU of {args.objects} objects - CPU of {args.few} objects x their physics "
            f"steps' ratio, {got.steps} / {few.steps}) / {args.objects}",
        )
        run.ratio(
            f"{name}_vs_few_cpu_per_candidate",
            got.cpu / few.cpu,
            note=f"CPU per candidate, {args.objects} objects ({name}) / {args.few} objects",
        )
    if args.before:
        for state in ("cold", "warm"):
            run.ratio(
                f"{state}_cpu_before_vs_after",
                results[f"before_{state}"].cpu / results[state].cpu,
                note=f"CPU of the {state} run on {args.objects} objects, commit {args.before} / this one",
            )
    run.table("runs", rows, note="user + system CPU of annotate and its workers")


if __name__ == "__main__":
    sys.exit(main())
