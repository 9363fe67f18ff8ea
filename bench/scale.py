"""Scale: a folder with thousands of objects, and a mesh with millions of faces.

    python -m bench.scale folder                  # 2,000 objects: discovery, digests, peak memory
    python -m bench.scale folder --run 200        # ... and `annotate --n 1` on the first 200 ids
    python -m bench.scale big-mesh                # a 2,000,000-face ring, end to end

``folder`` writes, in a temporary folder, pybullet_data's 1,000 random_urdfs (a URDF and its mesh
each) and copies of the sample objects (every format, the URDF with its two meshes) until there
are ``--objects`` objects, then times what the main process of a run does before any work starts:
discovering the objects and hashing every source (the manifest's digests), with its peak memory.

``big-mesh`` writes a torus of 2000 x 500 x 2 = 2,000,000 faces (a concave ring, 90 mm across),
reads and simplifies it to the face budget (ObjectConfig.max_faces), decomposes it (CoACD on a
copy of at most ObjectConfig.decomposition_max_faces) and runs ``annotate --n 20`` on it in a fresh
process with that decomposition cached, printing each step's time and peak memory.

Each writes a record (bench/harness.py): ``scale_folder`` and ``scale_big_mesh``.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np
import trimesh

from bench.harness import Run

ROOT = Path(__file__).resolve().parents[1]


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _children_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0


def _run_measured(cmd: list[str], env: dict) -> tuple[int, float, str]:
    """Run ``cmd``; its exit code, the largest peak RSS (MB) of it and the children it waited for
    (os.wait4: that process tree only), and its output."""
    with tempfile.TemporaryFile("w+") as out:
        proc = subprocess.Popen(cmd, env=env, stdout=out, stderr=subprocess.STDOUT, text=True)
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        return proc.returncode, usage.ru_maxrss / 1024.0, out.read()


def _annotate_measured(cmd: list[str], tmp: Path, what: str, run: Run) -> tuple[int, str]:
    """Run an ``annotate`` command with its decomposition cache in ``tmp``; print ``what``, its exit
    code, wall time and peak RSS and record the last two; return the exit code and the output."""
    env = {**os.environ, "RG2_CACHE_DIR": str(tmp / "cache")}
    t0 = time.perf_counter()
    code, rss, text = _run_measured(cmd, env)
    seconds = time.perf_counter() - t0
    print(f"{what}: exit {code} in {seconds:.0f} s, peak RSS of its processes {rss:.0f} MB")
    run.figure("annotate_s", seconds, "s", note=f"{what}, wall, exit {code}")
    run.figure("annotate_peak_rss", rss, "MB", note="the largest of its processes")
    return code, text


def make_folder(dest: Path, count: int) -> int:
    """``count`` objects in ``dest``: random_urdfs first, then copies of the sample objects."""
    import pybullet_data

    random = Path(pybullet_data.getDataPath()) / "random_urdfs"
    made = 0
    for folder in sorted(random.iterdir()):
        if made >= count:
            return made
        if folder.is_dir() and (folder / f"{folder.name}.urdf").is_file():
            shutil.copytree(folder, dest / "random" / folder.name)
            made += 1
    samples = [p for p in (ROOT / "objects").iterdir() if p.suffix in (".obj", ".stl", ".ply", ".off")]
    copy = 0
    while made < count:
        target = dest / "samples" / f"{copy:04d}"
        target.mkdir(parents=True)
        for path in samples:
            if made >= count:
                break
            shutil.copy(path, target / path.name)
            made += 1
        if made < count:
            shutil.copytree(ROOT / "objects" / "urdf" / "shampoo", target / "shampoo")
            made += 1
        copy += 1
    return made


def folder(args) -> None:
    from annotator.objects import discover_objects, source_digest

    with (
        Run(
            "scale_folder",
            config=vars(args),
            about="A folder of thousands of objects: discovery, digests and peak memory of the main process "
            "before any work starts (and annotate --n 1 on some of them with --run).",
        ) as run,
        tempfile.TemporaryDirectory(prefix="rg2-scale-") as tmp,
    ):
        root = Path(tmp) / "objects"
        t0 = time.perf_counter()
        made = make_folder(root, args.objects)
        files = sum(1 for p in root.rglob("*") if p.is_file())
        print(f"wrote {made} objects ({files} files) in {time.perf_counter() - t0:.1f} s")
        tracemalloc.start()
        t0 = time.perf_counter()
        sources = discover_objects(root)
        t1 = time.perf_counter()
        digests = {s.object_id: source_digest(s) for s in sources}
        t2 = time.perf_counter()
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        print(
            f"discovery: {len(sources)} objects in {t1 - t0:.2f} s; digests: {len(digests)} in "
            f"{t2 - t1:.2f} s; Python peak {peak / 2**20:.1f} MB, process peak RSS {_rss_mb():.0f} MB"
        )
        run.figure("objects", len(sources), note=f"{files} files written")
        run.figure("discovery_ms_per_object", (t1 - t0) / len(sources) * 1e3, "ms")
        run.figure("digest_ms_per_object", (t2 - t1) / len(sources) * 1e3, "ms")
        run.figure("python_peak", peak / 2**20, "MB", note="tracemalloc, discovery and digests")
        run.figure("peak_rss", _rss_mb(), "MB", note="this process")
        if args.run:
            keep = {s.object_id for s in sources[: args.run]}
            for s in sources[args.run :]:  # the run's folder: the first --run objects only
                for f in [s.path, *((s.path.parent).glob("*") if s.is_urdf else [])]:
                    f.unlink(missing_ok=True)
            out = Path(tmp) / "labels"
            cmd = ["annotate", "--objects", str(root), "--n", "1", "--out", str(out), "--quiet"]
            code, text = _annotate_measured(cmd, Path(tmp), f"annotate --n 1 on {len(keep)} objects", run)
            if args.log:
                args.log.write_text(text)
            lines = [ln for ln in text.splitlines() if "failed" in ln or "labelled" in ln]
            print("\n".join(lines[-12:]))


def torus(major: float, minor: float, n_major: int, n_minor: int) -> trimesh.Trimesh:
    """A closed torus of n_major x n_minor x 2 faces, outward wound (trimesh.creation.torus drops
    every face of a 2000 x 500 one: their area is below its degeneracy tolerance)."""
    u = np.linspace(0, 2 * np.pi, n_major, endpoint=False)[:, None]
    v = np.linspace(0, 2 * np.pi, n_minor, endpoint=False)[None, :]
    r = major + minor * np.cos(v)
    vertices = np.stack([r * np.cos(u), r * np.sin(u), minor * np.sin(v) + 0 * u], axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n_major), np.arange(n_minor), indexing="ij")
    a, b = i * n_minor + j, ((i + 1) % n_major) * n_minor + j
    c, d = ((i + 1) % n_major) * n_minor + (j + 1) % n_minor, i * n_minor + (j + 1) % n_minor
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def write_torus(args) -> None:
    torus(0.036, 0.009, args.major, args.minor).export(args.path)


def big_mesh(args) -> None:
    from annotator.config import ObjectConfig
    from annotator.objects import load_object, read_object_mesh

    with (
        Run(
            "scale_big_mesh",
            config=vars(args),
            about="A 2,000,000-face ring end to end: read, clean and simplify, decompose, annotate --n 20, "
            "each step's time and peak memory.",
        ) as run,
        tempfile.TemporaryDirectory(prefix="rg2-big-") as tmp,
    ):
        objects = Path(tmp) / "objects"
        objects.mkdir()
        t0 = time.perf_counter()
        path = objects / "ring.ply"
        # written by a child process, so this process's peak memory is the reading's
        sizes = [f"--major={args.major}", f"--minor={args.minor}"]
        subprocess.run(
            [sys.executable, "-m", "bench.scale", "write-torus", str(path), *sizes], check=True, cwd=ROOT
        )
        seconds = time.perf_counter() - t0
        size = path.stat().st_size / 2**20
        print(
            f"wrote {2 * args.major * args.minor:,} faces ({size:.0f} MB .ply) in {seconds:.1f} s "
            f"(writer's peak RSS {_children_rss_mb():.0f} MB)"
        )
        config = ObjectConfig()
        before = _rss_mb()
        t0 = time.perf_counter()
        mesh = read_object_mesh(path, config)
        seconds = time.perf_counter() - t0
        print(
            f"read + clean + simplify to {len(mesh.faces):,} faces (budget {config.max_faces:,}): "
            f"{seconds:.1f} s, peak RSS {_rss_mb():.0f} MB (from {before:.0f})"
        )
        run.figure("faces", 2 * args.major * args.minor, note="written")
        run.figure("read_s", seconds, "s", note=f"read, clean, simplify to {len(mesh.faces)} faces")
        run.figure("read_peak_rss", _rss_mb(), "MB", note="this process")
        del mesh
        t0 = time.perf_counter()
        model = load_object(path, config, cache_dir=Path(tmp) / "cache")
        err = model.collision_error
        seconds = time.perf_counter() - t0
        run.figure("load_s", seconds, "s", note="load_object: read again, weigh, decompose")
        run.figure("decomposition_s", model.decomposition_seconds, "s", note=model.collision_method)
        run.figure("collision_error_max", err.max * 1e3, "mm")
        run.figure("load_peak_rss", _rss_mb(), "MB", note="this process")
        print(
            f"load_object (read again, weigh, decompose): {seconds:.1f} s, of which "
            f"decomposition {model.decomposition_seconds:.1f} s (CoACD on at most "
            f"{config.decomposition_max_faces:,} faces, in a child process): {model.collision_method} "
            f"{len(model.parts)} parts, threshold "
            f"{model.collision_threshold:g}, error {err.mean * 1e3:.2f} / {err.max * 1e3:.2f} mm "
            f"({'approximate' if model.approximate else 'within the limits'}); peak RSS {_rss_mb():.0f} MB"
        )
        out = Path(tmp) / "labels"
        cmd = [
            "annotate",
            "--objects",
            str(objects),
            "--n",
            "20",
            "--out",
            str(out),
            "--quiet",
            "--workers",
            "2",
        ]
        what = "annotate --n 20 --workers 2 (decomposition cached)"
        code, text = _annotate_measured(cmd, Path(tmp), what, run)
        print("\n".join(text.strip().splitlines()[-8:]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="what", required=True)
    f = sub.add_parser("folder")
    f.add_argument("--objects", type=int, default=2000)
    f.add_argument("--run", type=int, default=0, help="then annotate --n 1 on this many of them")
    f.add_argument("--log", type=Path, default=None, help="write annotate's whole output here")
    b = sub.add_parser("big-mesh")
    w = sub.add_parser("write-torus")
    w.add_argument("path")
    for p in (b, w):
        p.add_argument("--major", type=int, default=2000)
        p.add_argument("--minor", type=int, default=500)
    args = ap.parse_args()
    {"folder": folder, "big-mesh": big_mesh, "write-torus": write_torus}[args.what](args)


if __name__ == "__main__":
    sys.exit(main())
