"""Scale: a folder with thousands of objects, and a mesh with millions of faces.

    python -m bench.scale folder                  # 2,000 objects: discovery, digests, peak memory
    python -m bench.scale folder --run 200        # ... and `annotate --n 1` on the first 200 ids
    python -m bench.scale big-mesh                # a 2,000,000-face ring, end to end
    python -m bench.scale store --sizes 1000,10000,100000 --annotate 1000
                                                  # the store's bookkeeping at 1k..100k objects

``folder`` writes, in a temporary folder, pybullet_data's 1,000 random_urdfs (a URDF and its mesh
each) and copies of the sample objects (every format, the URDF with its two meshes) until there
are ``--objects`` objects, then times what the main process of a run does before any work starts:
discovering the objects and hashing every source (the manifest's digests), with its peak memory.

``big-mesh`` writes a torus of 2000 x 500 x 2 = 2,000,000 faces (a concave ring, 90 mm across),
reads and simplifies it to the face budget (ObjectConfig.max_faces), decomposes it (CoACD on a
copy of at most DecompositionConfig.max_faces) and runs ``annotate --n 20`` on it in a fresh
process with that decomposition cached, printing each step's time and peak memory.

``store`` measures the output folder's bookkeeping as the number of objects grows, at ``--n 1``
(one chunk and one merged file per object): for each of ``--sizes`` it writes a folder of that many
tiny convex objects (boxes of random extents, ``.obj``, in a temporary folder), and, in a fresh
process per size: discovers and digests them (what a run's main process does before any work);
drives the store as a run of that many objects does (one chunk, one geometry record and one merge
recorded per object, each followed by the save a merge forces) with the label files themselves
written as plain copies of one real label file (the bookkeeping is measured, not Parquet writing or
simulation); closes the run (the compaction); and reopens the folder as a resume does (open,
verify every file against its checksum, match the objects). It prints and records the time of one
save, of the resume, of the compaction, the CPU per object of the main process's bookkeeping, its
peak memory, and the time of writing the whole manifest at that size (what the store before the
journal did at every save), then extrapolates each to 1,000,000 objects (marked as such).
``--annotate K`` also runs ``annotate --n 1 --workers 2`` on K of the objects end to end (then
again, as a resume of a finished run) with the main process's own CPU time and peak memory.

Each writes a record (bench/harness.py): ``scale_folder``, ``scale_big_mesh`` and ``scale_store``.
"""

from __future__ import annotations

import argparse
import json
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

from bench.arguments import Parser, count, writable_file, writable_folder
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
            f"{config.decomposition.max_faces:,} faces, in a child process): {model.collision_method} "
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


# ------------------------------------------------------------------------------------------ store


def write_convex_objects(dest: Path, count: int, seed: int = 0) -> None:
    """``count`` boxes of 20-60 mm extents, one ``.obj`` each, 1,000 to a subfolder."""
    rng = np.random.default_rng(seed)
    template = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    for i in range(count):
        folder = dest / f"set{i // 1000:04d}"
        if i % 1000 == 0:
            folder.mkdir(parents=True, exist_ok=True)
        v = template.vertices * rng.uniform(0.02, 0.06, size=3)
        lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in v]
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in template.faces]
        (folder / f"box{i:07d}.obj").write_text("\n".join(lines) + "\n")


def _label_bytes(tmp: Path) -> tuple[bytes, str]:
    """A real one-row label file's bytes (marked as the tool marks them) and their SHA-256."""
    import hashlib

    import pandas as pd

    from annotator.dataset import pose_columns
    from annotator.store.files import write_labels

    df = pose_columns(np.eye(4)[None])
    df.insert(0, "object_id", "set0000/box0000000")
    df.insert(1, "grasp_id", np.array([0], dtype=np.int64))
    for name, value in (("width", 0.05), ("success", True), ("outcome", "success"), ("score", 1.0)):
        df[name] = value
    df["object_scale"], df["mesh_sha256"], df["seed"] = 1.0, "0" * 64, np.int64(0)
    write_labels(tmp, pd.DataFrame(df), 0, 1, "one.parquet", "key", "0" * 64)
    data = (tmp / "one.parquet").read_bytes()
    return data, hashlib.sha256(data).hexdigest()


# an object's geometry record as a run keeps it (the banana's, at --n 200 on the sample objects)
_INFO = {
    "collision_error_max": 0.0007203077931598537,
    "collision_error_mean": 5.526474048350792e-05,
    "convex": False,
    "lateral_friction": 1.0,
    "mass": 0.061164363663093003,
    "mesh_sha256": "a" * 64,
    "parts": 5,
    "scale": 1.0,
    "source": "objects/banana.obj",
    "volume": 0.000122328727326186,
    "warnings": [],
    "watertight": True,
    "geometry": {
        "cleaning": "clean",
        "collision_approximate": False,
        "collision_error_max": 0.0007203077931598537,
        "collision_error_mean": 5.526474048350792e-05,
        "collision_ladder": "coacd kept (threshold 0.02, error 0.06 / 0.72 mm)",
        "collision_method": "coacd",
        "collision_parts": 5,
        "collision_threshold": 0.02,
        "digest": "9" * 64,
        "faces": 1280,
        "friction": 1.0,
        "mass": 0.061164363663093003,
        "mass_model": "solid",
        "object_id": "banana",
        "objects_dir": "/tmp/objects",
        "pose_frame": "mesh file frame",
        "pose_units": "m",
        "properties": "{}",
        "scale": 1.0,
        "source_files": '["banana.obj"]',
        "source_node": -1,
        "volume": 0.000122328727326186,
        "watertight": True,
    },
}


def store_one(args) -> None:
    """One size, in this (fresh) process: prints one JSON line of figures."""
    from annotator.config import AnnotatorConfig
    from annotator.objects import discover_objects, source_digest
    from annotator.store import RunSpec, Store
    from annotator.store.manifest import Manifest
    from annotator.store.names import chunk_filename, object_filename

    count = args.objects
    fig: dict[str, float] = {"objects": count}
    with tempfile.TemporaryDirectory(prefix="rg2-store-", dir=args.tmp) as tmp_name:
        tmp = Path(tmp_name)
        t0 = time.perf_counter()
        write_convex_objects(tmp / "objects", count)
        fig["write_objects_s"] = time.perf_counter() - t0
        rss_start = _rss_mb()
        c0, t0 = time.process_time(), time.perf_counter()
        digests = {s.object_id: source_digest(s) for s in discover_objects(tmp / "objects")}
        fig["discover_digest_s"] = time.perf_counter() - t0
        fig["discover_digest_cpu_ms_per_object"] = (time.process_time() - c0) / count * 1e3
        data, sha = _label_bytes(tmp)
        out = tmp / "labels"
        spec = RunSpec(seed=0, n=1, trials=1, scale=None, chunk_size=10, config=AnnotatorConfig().to_dict())
        store = Store(out, spec)
        store.open()
        store.reconcile(digests)
        saves, saves_cpu = [], []
        c0, t0 = time.process_time(), time.perf_counter()
        for oid, digest in digests.items():
            (out / object_filename(oid)).write_bytes(data)  # the label file (not timed apart)
            record = {"file": chunk_filename(oid, 0, 1), "sha256": sha, "n": 1}
            store.record({"op": "chunk", "oid": oid, "key": "0-1", "source_sha256": digest, "record": record})
            store.record({"op": "info", "oid": oid, "info": {**_INFO, "source": oid}})
            done = {
                **record,
                "file": object_filename(oid),
                "source_sha256": digest,
                "time": "t",
                "stats": {"n": 1, "successes": 1, "mean_score": 1.0, "outcomes": {"success": 1}},
            }
            store.record({"op": "done", "oid": oid, "record": done})
            s0, sc0 = time.perf_counter(), time.process_time()
            store.save(force=True)  # as finish_object does
            saves.append(time.perf_counter() - s0)
            saves_cpu.append(time.process_time() - sc0)
        fig["fill_s"] = time.perf_counter() - t0
        fig["bookkeeping_cpu_ms_per_object"] = (time.process_time() - c0) / count * 1e3
        saves_ms = np.array(saves) * 1e3
        fig["save_ms_median"] = float(np.median(saves_ms))
        fig["save_ms_p99"] = float(np.percentile(saves_ms, 99))
        fig["save_ms_last_1000"] = float(np.median(saves_ms[-1000:]))
        fig["save_cpu_ms_mean"] = float(np.mean(saves_cpu) * 1e3)
        c0, t0 = time.process_time(), time.perf_counter()
        store.close()  # the compaction
        fig["close_s"] = time.perf_counter() - t0
        fig["close_cpu_s"] = time.process_time() - c0
        fig["manifest_mb"] = Manifest.path(out).stat().st_size / 2**20
        t0 = time.perf_counter()
        Manifest.load(out).save(tmp)  # what the store before the journal wrote at every save
        fig["full_manifest_write_s"] = time.perf_counter() - t0
        (tmp / "_manifest.json").unlink()
        c0, t0 = time.process_time(), time.perf_counter()
        store = Store(out, spec)
        store.open()
        resume = store.reconcile(digests)
        fig["resume_s"] = time.perf_counter() - t0
        fig["resume_cpu_s"] = time.process_time() - c0
        fig["resume_cpu_ms_per_object"] = fig["resume_cpu_s"] / count * 1e3
        assert len(resume.done) == count, f"{len(resume.done)} of {count} resumed as done"
        store.close()
        fig["peak_rss_mb"] = _rss_mb()
        fig["rss_start_mb"] = rss_start
    print(json.dumps(fig))


def _annotate_main_process(objects: Path, out: Path, env: dict) -> dict[str, float]:
    """``annotate --n 1 --workers 2`` on ``objects``: wall time, the main process's own CPU time
    and peak RSS (its workers excluded), exit code."""
    usage = out.parent / f"{out.name}.usage.json"
    code = (
        "import atexit, json, resource, sys\n"
        "from annotator.cli import annotate_main\n"
        "def _usage():\n"
        "    r = resource.getrusage(resource.RUSAGE_SELF)\n"
        "    got = {'cpu': r.ru_utime + r.ru_stime, 'rss': r.ru_maxrss}\n"
        f"    open({str(usage)!r}, 'w').write(json.dumps(got))\n"
        "atexit.register(_usage)\n"
        f"sys.argv = ['annotate', '--objects', {str(objects)!r}, '--n', '1', '--out', {str(out)!r}, "
        "'--workers', '2', '--quiet']\n"
        "annotate_main()\n"
    )
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    got = json.loads(usage.read_text()) if usage.is_file() else {"cpu": float("nan"), "rss": float("nan")}
    return {"s": seconds, "cpu_s": got["cpu"], "rss_mb": got["rss"] / 1024.0, "exit": proc.returncode}


def store_bench(args) -> None:
    sizes = [int(v) for v in args.sizes.split(",")]
    with Run(
        "scale_store",
        config=vars(args),
        about="The output folder's bookkeeping from 1,000 to 100,000 objects at --n 1: the time of one "
        "save and of a resume, the main process's CPU per object and peak memory, extrapolated to "
        "1,000,000 objects.",
    ) as run:
        rows = []
        for count in sizes:
            cmd = [sys.executable, "-m", "bench.scale", "store-one", "--objects", str(count)]
            if args.tmp:
                cmd += ["--tmp", str(args.tmp)]
            proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
            if proc.returncode:
                raise RuntimeError(f"store-one {count} failed:\n{proc.stderr[-3000:]}")
            fig = json.loads(proc.stdout.strip().splitlines()[-1])
            rows.append(fig)
            print(
                f"{count:>9,} objects: save {fig['save_ms_median']:.2f} ms (p99 {fig['save_ms_p99']:.2f}, "
                f"CPU {fig['save_cpu_ms_mean']:.3f} ms), resume {fig['resume_s']:.2f} s (CPU "
                f"{fig['resume_cpu_s']:.2f} s, {fig['resume_cpu_ms_per_object']:.3f} ms/object), close "
                f"{fig['close_s']:.2f} s (CPU {fig['close_cpu_s']:.2f} s), bookkeeping "
                f"{fig['bookkeeping_cpu_ms_per_object']:.3f} CPU-ms/object, "
                f"peak RSS {fig['peak_rss_mb']:.0f} MB, manifest {fig['manifest_mb']:.1f} MB "
                f"(written whole: {fig['full_manifest_write_s']:.2f} s), discovery+digests "
                f"{fig['discover_digest_s']:.1f} s"
            )
            tag = f"{count}"
            run.figure(
                f"save_ms_{tag}",
                fig["save_ms_median"],
                "ms",
                note="median of one save per merged object (journal append + fsync), store driven directly",
            )
            run.figure(
                f"resume_s_{tag}",
                fig["resume_s"],
                "s",
                note="open + verify every file + match the "
                "objects, after a closed run; store driven directly",
            )
            run.figure(
                f"bookkeeping_cpu_ms_per_object_{tag}",
                fig["bookkeeping_cpu_ms_per_object"],
                "ms",
                note="main process, recording and saving one object (no Parquet writing)",
            )
            run.figure(
                f"peak_rss_mb_{tag}", fig["peak_rss_mb"], "MB", note="the measuring process, all phases"
            )
            run.figure(f"close_s_{tag}", fig["close_s"], "s", note="the compaction at the end of the run")
            run.figure(f"save_cpu_ms_{tag}", fig["save_cpu_ms_mean"], "ms", note="mean CPU of one save")
            run.figure(f"resume_cpu_s_{tag}", fig["resume_cpu_s"], "s", note="CPU of the resume")
            run.figure(f"close_cpu_s_{tag}", fig["close_cpu_s"], "s", note="CPU of the compaction")
            run.figure(
                f"full_manifest_write_s_{tag}",
                fig["full_manifest_write_s"],
                "s",
                note="the whole manifest written once: what the store before the journal did at every save",
            )
        run.table("sizes", rows)
        small, big = rows[0], rows[-1]
        if len(rows) > 1:
            slope_rss = (big["peak_rss_mb"] - small["peak_rss_mb"]) / (big["objects"] - small["objects"])
            run.ratio(
                "save_ms_largest_vs_smallest",
                big["save_ms_median"] / small["save_ms_median"],
                note=f"{big['objects']:,} against {small['objects']:,} objects: flat is 1",
            )
            run.ratio(
                "resume_ms_per_object_largest_vs_smallest",
                (big["resume_s"] / big["objects"]) / (small["resume_s"] / small["objects"]),
                note="resume time per object: O(objects) is 1",
            )
            run.ratio(
                "save_cpu_largest_vs_smallest",
                big["save_cpu_ms_mean"] / small["save_cpu_ms_mean"],
                note="CPU of one save (what a busy machine does not inflate): flat is 1",
            )
            run.ratio(
                "resume_cpu_per_object_largest_vs_smallest",
                big["resume_cpu_ms_per_object"] / small["resume_cpu_ms_per_object"],
                note="CPU of the resume per object: O(objects) is 1",
            )
            run.ratio(
                "full_rewrite_vs_journal_save_largest",
                big["full_manifest_write_s"] * 1e3 / big["save_ms_median"],
                note="one save before the journal / one save now, at the largest size",
            )
            million = 1_000_000
            per = million / big["objects"]
            extrapolated = {
                "save_ms": big["save_ms_median"],
                "resume_s": big["resume_s"] * per,
                "resume_cpu_s": big["resume_cpu_s"] * per,
                "close_s": big["close_s"] * per,
                "close_cpu_s": big["close_cpu_s"] * per,
                "peak_rss_mb": big["peak_rss_mb"] + slope_rss * (million - big["objects"]),
                "bookkeeping_cpu_s": big["bookkeeping_cpu_ms_per_object"] * million / 1e3,
                "discover_digest_s": big["discover_digest_s"] * per,
                "manifest_mb": big["manifest_mb"] * per,
                "full_manifest_write_s": big["full_manifest_write_s"] * per,
            }
            for key, value in extrapolated.items():
                run.figure(
                    f"extrapolated_1m_{key}",
                    value,
                    note="EXTRAPOLATED to 1,000,000 objects, linearly "
                    f"from {big['objects']:,} (memory from the slope between the smallest and largest)",
                )
            print(
                "1,000,000 objects (EXTRAPOLATED, linear from the largest size): "
                + ", ".join(f"{k} {v:,.1f}" for k, v in extrapolated.items())
            )
        if args.annotate:
            with tempfile.TemporaryDirectory(prefix="rg2-store-run-", dir=args.tmp) as tmp_name:
                tmp = Path(tmp_name)
                write_convex_objects(tmp / "objects", args.annotate)
                env = {**os.environ, "RG2_CACHE_DIR": str(tmp / "cache")}
                first = _annotate_main_process(tmp / "objects", tmp / "labels", env)
                again = _annotate_main_process(tmp / "objects", tmp / "labels", env)
                k = args.annotate
                print(
                    f"annotate --n 1 --workers 2 on {k:,} boxes (cold cache): exit {first['exit']}, "
                    f"{first['s']:.0f} s wall; main process {first['cpu_s'] / k * 1e3:.1f} CPU-ms/object, "
                    f"peak RSS {first['rss_mb']:.0f} MB; again (a finished run resumed): {again['s']:.1f} s, "
                    f"main process {again['cpu_s']:.1f} CPU-s, exit {again['exit']}"
                )
                run.figure(
                    "annotate_s", first["s"], "s", note=f"annotate --n 1 --workers 2, {k} boxes, full run"
                )
                run.figure(
                    "annotate_main_cpu_ms_per_object",
                    first["cpu_s"] / k * 1e3,
                    "ms",
                    note="the main process's own CPU (workers excluded), full run",
                )
                run.figure(
                    "annotate_main_peak_rss_mb", first["rss_mb"], "MB", note="the main process, full run"
                )
                run.figure(
                    "annotate_resume_s",
                    again["s"],
                    "s",
                    note="the same command again on the finished folder: start-up to exit, full run",
                )
                run.figure("annotate_resume_main_cpu_s", again["cpu_s"], "s", note="main process, full run")


def sizes(text: str) -> str:
    """An argparse type: object counts, comma-separated, each 1 .. 10,000,000 (kept as the text)."""
    for part in text.split(","):
        count(1, 10_000_000)(part.strip())
    return text


def parser() -> Parser:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="what", required=True, parser_class=Parser)
    f = sub.add_parser("folder")
    f.add_argument("--objects", type=count(1, 10_000_000), default=2000)
    f.add_argument(
        "--run", type=count(0, 10_000_000), default=0, help="then annotate --n 1 on this many of them"
    )
    f.add_argument("--log", type=writable_file, default=None, help="write annotate's whole output here")
    b = sub.add_parser("big-mesh")
    w = sub.add_parser("write-torus")
    w.add_argument("path", type=writable_file)
    for p in (b, w):
        p.add_argument("--major", type=count(3, 100_000), default=2000)
        p.add_argument("--minor", type=count(3, 100_000), default=500)
    st = sub.add_parser("store")
    st.add_argument(
        "--sizes",
        type=sizes,
        default="1000,10000",
        help="object counts, comma-separated (e.g. 1000,10000,100000)",
    )
    st.add_argument(
        "--annotate",
        type=count(0, 10_000_000),
        default=0,
        help="also run annotate --n 1 on this many objects",
    )
    st.add_argument(
        "--tmp",
        type=writable_folder,
        default=None,
        help="where the temporary folders go (default: the system's)",
    )
    one = sub.add_parser("store-one")
    one.add_argument("--objects", type=count(1, 10_000_000), required=True)
    one.add_argument("--tmp", type=writable_folder, default=None)
    return ap


def main() -> None:
    args = parser().parse_args()
    modes = {"folder": folder, "big-mesh": big_mesh, "write-torus": write_torus, "store": store_bench}
    {**modes, "store-one": store_one}[args.what](args)


if __name__ == "__main__":
    sys.exit(main())
