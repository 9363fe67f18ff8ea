"""Object sets as users bring them (YCB, pybullet_data, the sample objects): per object its
collision error, decomposition method and CPU seconds, cold and warm; a run's cold start in
parallel against serial; warm labelling throughput per object and on the whole mix, as ratios to
a free step and to the code before.

    python -m bench.object_sets --ycb DIR --pybullet-data --samples --baseline COMMIT
    python -m bench.object_sets --samples --cold-start samples --n 20      # quick
    python -m bench.object_sets --compare before.jsonl after.jsonl         # a markdown table
    python -m bench.object_sets --compare RECORD.json RECORD.json          # ... of two records

Sets (each optional; the data folders are arguments, nothing is copied into the project):

- ``--ycb DIR``: a folder of YCB meshes (the 16 ``nontextured.stl`` meshes of the GRASPA
  benchmark, hsp-iit/GRASPA-benchmark, gzipped or not); their masses (:data:`YCB_MASSES`) go into
  the staged folder's ``objects.toml``. The record names the folder by its files' digest, not its
  path.
- ``--pybullet-data``: object URDFs of the installed pybullet_data (:data:`PYBULLET_OBJECTS`).
- ``--samples``: the shipped sample objects (``objects/``).

Parts, each on copies of the sets in one scratch folder:

1. **Loads** (``--phases cold warm``): every object loaded by ``annotator.objects.load_object``
   in a child process of its own, first with an empty cache (cold; one cache for the whole
   bench), then with it filled (warm): collision method and parts, collision error (mean / max,
   mm, against the cleaned mesh), the CPU seconds of the load (the child's and its decomposition
   processes'), wall seconds, peak RSS, the ladder, the failure reason. ``--json FILE`` appends
   one line per load (what ``--compare`` reads).
2. **Cold start** (``--cold-start SET``, default the YCB set when given, else the first): the
   run itself, ``annotate --n COLD_N`` on SET with an empty cache, with 2 workers and with 1:
   the wall time until every object is simulable (its decomposition task done) and to the end;
   their ratio; each object's decomposition as the parallel run made it.
3. **Warm throughput** (``--n N``, 0 skips): ``annotate --n N`` on the mix of every set, warm,
   ``--repeat`` times; with ``--baseline COMMIT`` alternating with that commit's code (its
   ``annotator/`` extracted by ``git archive``, same libraries, same cache, each code's entries
   filled by a run of its own first, so no measured run decomposes): candidates per
   CPU-second of the command and its workers, per object candidates per second per core (worker
   seconds), and each as free steps (``bench/reference.py``, measured before each run) per
   candidate; the ratio of this code's throughput to the baseline's in the same bench.

Printed at the end, the targets: no object fails; every collision shape within 2 mm (max) of its
mesh, or the reason it is not; no object above 60 reference CPU-s to become simulable; the YCB
set cold in at most 16 reference CPU-minutes (CPU-s here over this machine's speed factor,
annotator.objects.machine_speed, measured once and given to every load); warm throughput on the mix
no lower than the baseline's. Other CPU seconds are this machine's; compare builds by the ratios
measured in one run. Writes a record
(bench/harness.py); asserts nothing.
"""

from __future__ import annotations

import argparse
import fnmatch
import gzip
import hashlib
import json
import os
import re
import resource
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

from annotator.config import AnnotatorConfig, ObjectConfig
from annotator.objects.collision_ladder import budget_factor
from annotator.objects.machine_speed import FACTOR_ENV
from bench.arguments import (
    N_MAX,
    REPEAT_MAX,
    WORKERS_MAX,
    Parser,
    count,
    existing_folder,
    number,
    writable_file,
    writable_folder,
)
from bench.harness import Run
from bench.reference import free_step

ROOT = Path(__file__).resolve().parents[1]

# Object URDFs of pybullet_data (bullet3's data folder, pip package pybullet 3.2.x) that are
# graspable household-sized objects; random_urdfs 037 and 121 are convex parts written as one file.
PYBULLET_OBJECTS = (
    "duck_vhacd.urdf",
    "teddy_vhacd.urdf",
    "cube_small.urdf",
    "sphere_small.urdf",
    "soccerball.urdf",
    "objects/mug.urdf",
    "lego/lego.urdf",
    "jenga/jenga.urdf",
    "domino/domino.urdf",
    *(f"random_urdfs/{i:03d}/{i:03d}.urdf" for i in range(20)),
    "random_urdfs/037/037.urdf",
    "random_urdfs/121/121.urdf",
)

# kg, the YCB object set's published masses (Calli et al., "The YCB object and model set", 2015;
# ycbbenchmarks.com), for the 16 objects of the GRASPA benchmark
YCB_MASSES = {
    "banana": 0.066,
    "cracker_box": 0.411,
    "foam_brick": 0.028,
    "gelatin_box": 0.097,
    "hammer": 0.665,
    "medium_clamp": 0.059,
    "mustard_bottle": 0.603,
    "pear": 0.049,
    "potted_meat_can": 0.370,
    "power_drill": 0.895,
    "scissors": 0.082,
    "strawberry": 0.018,
    "tennis_ball": 0.058,
    "tomato_soup_can": 0.349,
    "chips_can": 0.205,
    "master_chef_can": 0.414,
}

MAX_ERROR = 0.002  # m, the target: every collision shape within 2 mm (max) of its mesh
# s, the target: no object takes longer to become simulable, in reference CPU-seconds (the CPU-s
# of the machine the decomposition budget was set on: CPU-s here / speed_factor(), as the ladder counts)
MAX_CPU = 60.0
YCB_COLD_CPU = 16 * 60.0  # s, the target: the 16 YCB meshes cold in all

_FILENAME = re.compile(r'filename\s*=\s*"([^"]+)"')


@dataclass
class Load:
    """One object loaded once (in a child process)."""

    set: str
    object_id: str
    phase: str  # cold or warm
    ok: bool = False
    reason: str = ""
    method: str = ""
    parts: int = 0
    faces: int = 0
    watertight: bool = False
    convex: bool = False
    cleaning: str = ""
    error_mean_mm: float = float("nan")
    error_max_mm: float = float("nan")
    threshold: float = 0.0
    decomposition_seconds: float = 0.0
    cpu_s: float = 0.0
    wall_s: float = 0.0
    peak_rss_mb: float = 0.0
    warnings: list[str] = field(default_factory=list)
    ladder: str = ""  # the decomposition rungs tried (builds that have them)

    @classmethod
    def from_json(cls, data: dict) -> Load:
        """A record of any build's JSON line (unknown keys ignored, missing ones defaulted)."""
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in data.items() if k in known})

    @property
    def beyond(self) -> bool:
        """Loaded, with a collision shape more than MAX_ERROR from its mesh."""
        return self.ok and self.error_max_mm > MAX_ERROR * 1e3


# --------------------------------------------------------------------------------------------------
# the child: one load


def _cpu() -> float:
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def child(folder: Path, object_id: str, cache: Path, set_name: str, phase: str) -> None:
    """Load one object and print its :class:`Load` as JSON (the last line of stdout)."""
    import logging

    from annotator.objects import ObjectError, discover_objects, load_object

    logging.basicConfig(level=logging.ERROR)
    config = AnnotatorConfig()
    out = Load(set_name, object_id, phase)
    sources = {s.object_id: s for s in discover_objects(folder, config.objects)}
    t0, c0 = time.perf_counter(), _cpu()
    try:
        model = load_object(sources[object_id], config.objects, cache_dir=cache)
    except ObjectError as exc:
        out.reason = str(exc)
    else:
        err = model.collision_error
        out.ok = True
        out.method = model.collision_method
        out.parts = len(model.parts)
        out.faces = len(model.mesh.faces)
        out.watertight = bool(model.watertight)
        out.convex = bool(model.convex)
        out.cleaning = model.cleaning.summary()
        out.error_mean_mm = err.mean * 1e3
        out.error_max_mm = err.max * 1e3
        out.threshold = float(model.collision_threshold)
        out.decomposition_seconds = float(model.decomposition_seconds)
        out.warnings = list(model.warnings)
        out.ladder = model.collision_ladder
    out.cpu_s = _cpu() - c0
    out.wall_s = time.perf_counter() - t0
    kids = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    out.peak_rss_mb = max(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, kids) / 1024.0
    print(json.dumps(asdict(out)))


def run_child(folder: Path, object_id: str, cache: Path, set_name: str, phase: str, timeout: float) -> Load:
    cmd = [sys.executable, "-m", "bench.object_sets", "--child", str(folder), object_id, str(cache)]
    t0 = time.perf_counter()
    try:
        done = subprocess.run(
            [*cmd, set_name, phase], capture_output=True, text=True, timeout=timeout, check=False, cwd=ROOT
        )
    except subprocess.TimeoutExpired:
        return Load(set_name, object_id, phase, reason=f"bench: no result within {timeout:g} s")
    lines = done.stdout.strip().splitlines()
    if done.returncode != 0 or not lines:
        tail = (done.stderr.strip().splitlines() or ["?"])[-1][:200]
        out = Load(set_name, object_id, phase, reason=f"bench child exit {done.returncode}: {tail}")
        out.wall_s = time.perf_counter() - t0
        return out
    return Load.from_json(json.loads(lines[-1]))


# --------------------------------------------------------------------------------------------------
# the sets, copied into a scratch folder


def stage_ycb(src: Path, dst: Path, masses: dict[str, float]) -> None:
    dst.mkdir(parents=True)
    names = []
    for path in sorted(src.iterdir()):
        if path.name.endswith(".stl.gz"):
            name = path.name[: -len(".stl.gz")]
            with gzip.open(path, "rb") as fh, open(dst / f"{name}.stl", "wb") as out:
                shutil.copyfileobj(fh, out)
        elif path.suffix.lower() in (".stl", ".obj", ".ply", ".off", ".glb"):
            name = path.stem
            shutil.copyfile(path, dst / path.name)
        else:
            continue
        names.append(name)
    lines = [f'["{n}"]\nmass = {masses[n]!r}\n' for n in names if n in masses]
    if lines:
        (dst / "objects.toml").write_text("\n".join(lines))


def stage_pybullet_data(dst: Path, names: tuple[str, ...]) -> None:
    import pybullet_data

    data = Path(pybullet_data.getDataPath())
    for rel in names:
        urdf = data / rel
        if not urdf.is_file():
            print(f"pybullet_data: {rel} not installed; skipped")
            continue
        (dst / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(urdf, dst / rel)
        for ref in sorted(set(_FILENAME.findall(urdf.read_text(errors="replace")))):
            mesh = (urdf.parent / ref).resolve()
            target = dst / Path(rel).parent / ref
            if mesh.is_file() and not target.exists():
                target.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(mesh, target)


def stage_samples(dst: Path) -> None:
    shutil.copytree(ROOT / "objects", dst, ignore=shutil.ignore_patterns("*.py", "__pycache__"))


def stage_mix(sets: dict[str, Path], dst: Path) -> None:
    """Every set as a subfolder of ``dst``, their sidecars merged into one (ids prefixed)."""
    dst.mkdir(parents=True)
    sidecar = []
    for name, folder in sets.items():
        shutil.copytree(folder, dst / name, ignore=shutil.ignore_patterns("objects.toml"))
        toml = folder / "objects.toml"
        if toml.is_file():
            sidecar.append(re.sub(r'^\["', f'["{name}/', toml.read_text(), flags=re.M))
    if sidecar:
        (dst / "objects.toml").write_text("\n".join(sidecar))


def object_ids(folder: Path) -> list[str]:
    from annotator.objects import discover_objects

    return [s.object_id for s in discover_objects(folder, ObjectConfig())]


def folder_digest(folder: Path) -> dict:
    """What the record says of a data folder instead of its path: its files and their digest."""
    h, files = hashlib.sha256(), sorted(p for p in folder.iterdir() if p.is_file())
    for path in files:
        h.update(path.name.encode() + b"\0" + path.read_bytes())
    return {"files": len(files), "sha256": h.hexdigest()[:16]}


# --------------------------------------------------------------------------------------------------
# 1. loads


def _row(r: Load, factor: float) -> str:
    if not r.ok:
        return f"  {r.object_id:<26} {r.phase:<4} FAILED {r.reason[:90]}  ({r.cpu_s:.1f} CPU-s)"
    flag = " >2mm" if r.beyond else ""
    flag += "" if r.phase == "warm" or r.cpu_s / factor <= MAX_CPU else " >60 reference s"
    return (
        f"  {r.object_id:<26} {r.phase:<4} {r.method:<8} {r.parts:3d} parts {r.faces:7d} faces "
        f"err {r.error_mean_mm:6.2f} / {r.error_max_mm:6.2f} mm  {r.cpu_s:7.1f} CPU-s {r.wall_s:7.1f} s "
        f"{r.peak_rss_mb:6.0f} MB{flag}" + (f"\n      {r.ladder}" if r.ladder and r.phase == "cold" else "")
    )


def loads(args, sets: dict[str, Path], cache: Path, factor: float) -> list[Load]:
    rows: list[Load] = []
    for phase in args.phases:
        for name, folder in sets.items():
            print(f"\n== loads: {name} ({phase}), one process per object", flush=True)
            for oid in object_ids(folder):
                if args.only and not any(fnmatch.fnmatch(f"{name}/{oid}", g) for g in args.only):
                    continue
                r = run_child(folder, oid, cache, name, phase, args.timeout)
                rows.append(r)
                print(_row(r, factor), flush=True)
                if args.json:
                    with args.json.open("a") as fh:
                        fh.write(json.dumps(asdict(r)) + "\n")
    return rows


def why_beyond(r: Load, config: ObjectConfig) -> str:
    """Why a collision shape is more than 2 mm from its mesh, from what its load reported."""
    if not r.watertight:
        return "open surface that could not be closed: collided as its hull"
    if r.method == "hull" and r.convex:
        return "convex within convex_volume_tolerance: its hull bridges the mesh's grooves and recesses"
    if "over budget" in r.ladder and r.method == "coacd":
        return "the CPU budget stopped CoACD's refinement: its best finished threshold"
    if r.method == "coacd" and r.threshold <= config.decomposition.min_threshold:
        return "CoACD at its finest threshold: the decomposition, not the mesh, is the limit"
    if r.method == "coacd":
        return "CoACD kept a coarser threshold: the finer ones did not measure better"
    if r.method == "coacd-remeshed":
        return "CoACD cut only the remeshed mesh within the budget: its surface moved by the remeshing"
    if r.method == "vhacd":
        return "CoACD finished no threshold within the budget: V-HACD's parts"
    return f"{r.method}: the ladder gave no better parts ({r.ladder})"


def record_loads(rows: list[Load], run: Run) -> None:
    config = ObjectConfig()
    run.table(
        "loads",
        [
            {
                "set": r.set,
                "object": r.object_id,
                "phase": r.phase,
                "ok": r.ok,
                "method": r.method,
                "parts": r.parts,
                "error_mean_mm": r.error_mean_mm,
                "error_max_mm": r.error_max_mm,
                "cpu_s": r.cpu_s,
                "wall_s": r.wall_s,
                "peak_rss_mb": r.peak_rss_mb,
                "beyond_2mm_because": why_beyond(r, config) if r.beyond else "",
                "ladder": r.ladder,
                "reason": r.reason,
            }
            for r in rows
        ],
        note="each object loaded in a process of its own: cold (empty cache), then warm; CPU-s of the "
        "whole load (reading, cleaning, weighing, the decomposition)",
    )
    for name in dict.fromkeys(r.set for r in rows):
        for phase in ("cold", "warm"):
            sel = [r for r in rows if r.set == name and r.phase == phase]
            if not sel:
                continue
            cpu = [r.cpu_s for r in sel]
            run.figure(f"{name}_{phase}_objects", len(sel))
            run.figure(f"{name}_{phase}_failed", sum(not r.ok for r in sel))
            run.figure(f"{name}_{phase}_cpu_s", sum(cpu), "s", note="CPU seconds to load every object")
            run.figure(f"{name}_{phase}_slowest_cpu_s", max(cpu), "s")
            if phase == "cold":
                beyond = sum(r.beyond for r in sel)
                run.figure(f"{name}_beyond_2mm", beyond, note="collision error max > 2 mm")


# --------------------------------------------------------------------------------------------------
# 2., 3. runs of the job, in a child process (this code's or the baseline's)

RUNNER = r"""
import json, sys
from pathlib import Path
from annotator.config import AnnotatorConfig
from annotator.pipeline.run import RunOptions, run
objects, out, n, workers = sys.argv[1:5]
options = RunOptions(objects_dir=Path(objects), n=int(n), out_dir=Path(out), workers=int(workers), quiet=True)
s = run(options, AnnotatorConfig())
prepared = {
    oid: {"method": p.method, "parts": p.parts, "made": p.made, "decomposed": p.decomposed,
          "decomposition_cpu_s": p.decomposition_cpu_s, "cpu_s": p.cpu_s, "error_max_mm": p.error_max * 1e3}
    for oid, p in getattr(s, "prepared", {}).items()
}
print(json.dumps({
    "candidates": s.candidates, "seconds": s.seconds, "worker_seconds": s.worker_seconds,
    "failed": s.failed, "object_seconds": {oid: st.seconds for oid, st in s.done.items()},
    "ready_seconds": getattr(s, "ready_seconds", None), "prepared": prepared,
}))
"""


@dataclass
class JobRun:
    """One run of the job in a child process: its summary's figures, its wall and CPU seconds (the
    process and the workers it waited for, os.wait4)."""

    wall_s: float
    cpu_s: float
    candidates: int
    seconds: float
    ready_seconds: float | None
    object_seconds: dict[str, float]
    prepared: dict[str, dict]
    failed: dict[str, str]


def run_job(
    objects: Path, n: int, workers: int, cache: Path, scratch: Path, tree: Path | None = None
) -> JobRun:
    """``run()`` of this checkout's code (or of the ``annotator/`` in ``tree``) on ``objects`` with
    ``cache``, from a scratch folder, the code's folder first on the path of it and its workers (so
    that neither imports another copy of the package, such as an editable install elsewhere)."""
    env = {**os.environ, "RG2_CACHE_DIR": str(cache), "PYTHONPATH": str(tree or ROOT)}
    with tempfile.TemporaryDirectory(dir=scratch) as tmp, tempfile.TemporaryFile("w+") as log:
        cmd = [sys.executable, "-c", RUNNER, str(objects), str(Path(tmp) / "out"), str(n), str(workers)]
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, cwd=tmp, env=env, stdout=log, stderr=subprocess.STDOUT, text=True)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        log.seek(0)
        text = log.read()
    if os.waitstatus_to_exitcode(status) not in (0,):
        raise SystemExit(f"the job exited {os.waitstatus_to_exitcode(status)}:\n{text[-3000:]}")
    data = json.loads(text.strip().splitlines()[-1])
    return JobRun(
        wall,
        usage.ru_utime + usage.ru_stime,
        data["candidates"],
        data["seconds"],
        data["ready_seconds"],
        data["object_seconds"],
        data["prepared"],
        data["failed"],
    )


def cold_start(args, folder: Path, name: str, work: Path, run: Run) -> None:
    """The job with an empty cache on 2 workers and on 1: until every object is simulable."""
    print(f"\n== cold start: annotate --n {args.cold_n} on {name}, empty cache, 2 workers then 1", flush=True)
    runs = {}
    for workers in (2, 1):
        copy = work / f"cold-{workers}" / name  # a path of its own: nothing kept from another run
        shutil.copytree(folder, copy)
        job = run_job(copy, args.cold_n, workers, work / f"cold-{workers}-cache", work)
        runs[workers] = job
        print(
            f"{workers} worker(s): every object ready after {job.ready_seconds:.1f} s, done after "
            f"{job.wall_s:.1f} s (launch to exit), {job.cpu_s:.1f} CPU-s; failed {len(job.failed)}",
            flush=True,
        )
    parallel, serial = runs[2], runs[1]
    run.ratio(
        "cold_start_serial_vs_parallel",
        serial.ready_seconds / parallel.ready_seconds,
        note=f"{name}, empty cache: wall seconds until every object is simulable, 1 worker / 2 workers",
    )
    run.ratio(
        "cold_run_serial_vs_parallel",
        serial.wall_s / parallel.wall_s,
        note=f"{name}, empty cache, annotate --n {args.cold_n}: launch to exit, 1 worker / 2 workers",
    )
    for workers, job in runs.items():
        run.figure(f"cold_start_ready_s_{workers}_workers", job.ready_seconds, "s", note=f"{name}")
        run.figure(f"cold_start_exit_s_{workers}_workers", job.wall_s, "s", note=f"{name}")
        run.figure(f"cold_start_cpu_s_{workers}_workers", job.cpu_s, "s", note=f"{name}, command and workers")
    run.table(
        "cold_start_decompositions",
        [{"object": oid, **p} for oid, p in sorted(parallel.prepared.items())],
        note=f"{name}: each object's decomposition task in the 2-worker run (CPU-s: the worker's and its "
        "decomposition processes')",
    )


def _free_step_cpu() -> float:
    return free_step(AnnotatorConfig()).cpu


def warm_throughput(args, mix: Path, cache: Path, work: Path, baseline: Path | None, run: Run) -> None:
    """``annotate --n N`` on the mix, warm, alternating this code and the baseline's."""
    versions = [("this", None)] + ([("baseline", baseline)] if baseline is not None else [])
    count = len(object_ids(mix))
    print(f"\n== warm throughput: annotate --n {args.n} on the mix ({count} objects)", flush=True)
    for _, tree in versions:  # fills each code's cache where the loads did not (keys differ by version)
        run_job(mix, 1, args.workers, cache, work, tree)
    per_cpu: dict[str, list[float]] = {v: [] for v, _ in versions}
    steps: dict[str, list[float]] = {v: [] for v, _ in versions}
    seconds: dict[str, list[float]] = {}
    rows = []
    for r in range(args.repeat):
        for version, tree in versions:
            step = _free_step_cpu()
            load = os.getloadavg()[0]
            job = run_job(mix, args.n, args.workers, cache, work, tree)
            per_cpu[version].append(job.candidates / job.cpu_s)
            steps[version].append(job.cpu_s / job.candidates / step)
            if version == "this":
                for oid, s in job.object_seconds.items():
                    seconds.setdefault(oid, []).append(s)
            print(
                f"run {r + 1} {version:<8}: {job.candidates} candidates, {job.wall_s:6.1f} s, "
                f"{job.cpu_s:6.1f} CPU-s: {per_cpu[version][-1]:5.1f} per CPU-second, "
                f"{steps[version][-1]:6.1f} free steps per candidate (load {load:.1f})",
                flush=True,
            )
            rows.append(
                {
                    "run": r + 1,
                    "code": version,
                    "candidates": job.candidates,
                    "wall_s": job.wall_s,
                    "cpu_s": job.cpu_s,
                    "candidates_per_cpu_s": per_cpu[version][-1],
                    "free_steps_per_candidate": steps[version][-1],
                    "free_step_cpu_ms": step * 1e3,
                    "load_before": load,
                }
            )
    record_warm(args, per_cpu, steps, seconds, rows, run)


def record_warm(args, per_cpu, steps, seconds: dict[str, list[float]], rows, run: Run) -> None:
    what = f"annotate --n {args.n} on the mix, warm, {args.workers} workers"
    a = steps["this"]
    run.ratio(
        "mix_free_steps_per_candidate",
        statistics.median(a),
        spread=(min(a), max(a)),
        note=f"{what}: CPU-s per candidate (command and workers) / CPU-s of a free step measured before",
    )
    b = per_cpu["this"]
    run.figure("mix_candidates_per_cpu_s", statistics.median(b), "1/s", spread=(min(b), max(b)), note=what)
    if "baseline" in per_cpu:
        ratio = statistics.median(per_cpu["this"]) / statistics.median(per_cpu["baseline"])
        print(f"this / baseline, median candidates per CPU-second: {ratio:.3f}")
        run.ratio(
            "mix_this_vs_baseline",
            ratio,
            note=f"{what}: candidates per CPU-second, this code / --baseline {args.baseline} (medians, "
            "runs alternating)",
        )
        c = steps["baseline"]
        run.ratio("mix_baseline_free_steps_per_candidate", statistics.median(c), spread=(min(c), max(c)))
    step_ms = statistics.median(r["free_step_cpu_ms"] for r in rows)
    per_object = []
    for oid, s in sorted(seconds.items()):
        mid = statistics.median(s)
        per_object.append(
            {
                "object": oid,
                "candidates_per_s_per_core": args.n / mid,
                "free_steps_per_candidate": mid / args.n / (step_ms / 1e3),
            }
        )
    run.table(
        "warm_per_object",
        per_object,
        note=f"{what}: per object, its candidates over the worker seconds spent on it (median of runs), "
        "and as free steps per candidate (the median free step of the runs)",
    )
    for name in dict.fromkeys(row["object"].split("/")[0] for row in per_object):
        total = sum(statistics.median(s) for oid, s in seconds.items() if oid.split("/")[0] == name)
        count = sum(1 for oid in seconds if oid.split("/")[0] == name)
        run.figure(f"{name}_warm_candidates_per_s_per_core", count * args.n / total, "1/s", note=what)
        run.ratio(f"{name}_warm_free_steps_per_candidate", total / (count * args.n) / (step_ms / 1e3))
    run.table("warm_runs", rows, note=what)


def extract_baseline(commit: str, dst: Path) -> Path:
    """The ``annotator`` package of ``commit`` (git archive: nothing in the repository changes),
    its robot models where the package finds them."""
    dst.mkdir(parents=True)
    archive = subprocess.run(
        ["git", "-C", str(ROOT), "archive", commit, "annotator", "assets"], capture_output=True, check=True
    ).stdout
    subprocess.run(["tar", "-x", "-C", str(dst)], input=archive, check=True)
    shutil.move(str(dst / "assets"), str(dst / "annotator" / "assets"))
    return dst


# --------------------------------------------------------------------------------------------------
# the targets, and a table of two runs


def targets(rows: list[Load], factor: float) -> list[str]:
    """The targets as lines: met or not, and for each collision shape beyond 2 mm, why. ``factor``:
    this machine's CPU-s per reference CPU-second (the times are compared in reference CPU-s)."""
    config = ObjectConfig()
    cold = [r for r in rows if r.phase == "cold"]
    out = ["", "targets:"]
    failed = [f"{r.set}/{r.object_id}" for r in cold if not r.ok]
    out.append(f"  no object fails: {'met' if not failed else 'NOT met: ' + ', '.join(failed)}")
    slow = [f"{r.set}/{r.object_id} ({r.cpu_s / factor:.0f})" for r in cold if r.cpu_s / factor > MAX_CPU]
    slow_text = "met" if not slow else "NOT met: " + ", ".join(slow)
    out.append(f"  no object above {MAX_CPU:.0f} reference CPU-s cold (factor {factor:.2f}): {slow_text}")
    ycb = [r.cpu_s / factor for r in cold if r.set == "ycb"]
    if ycb:
        met = "met" if sum(ycb) <= YCB_COLD_CPU else "NOT met"
        minutes = sum(ycb) / 60
        out.append(f"  YCB cold in <= 16 reference CPU-minutes: {met} ({minutes:.1f}, {len(ycb)} meshes)")
    beyond = [r for r in cold if r.beyond]
    out.append(f"  every collision shape within 2 mm, or why not: {len(beyond)} beyond")
    for r in beyond:
        why = why_beyond(r, config)
        out.append(f"    {r.set}/{r.object_id} ({r.error_max_mm:.2f} mm, {r.method}): {why}")
    return out


def _cell(r: Load | None) -> str:
    if r is None:
        return "–"
    if not r.ok:
        return f"failed: {r.reason[:60]}"
    return f"{r.method} {r.parts}, {r.error_mean_mm:.2f} / {r.error_max_mm:.2f} mm, {r.cpu_s:.1f} CPU-s"


def read_loads(path: Path) -> list[Load]:
    """The loads of a ``--json`` file (one JSON line per load) or of a bench record (its ``loads``
    table, as written under bench/results/object_sets/)."""
    text = path.read_text()
    try:
        record = json.loads(text)
    except json.JSONDecodeError:
        record = None
    if isinstance(record, dict) and "tables" in record:
        table = next(t for t in record["tables"] if t["name"] == "loads")
        rows = [dict(zip(table["columns"], row, strict=True)) for row in table["rows"]]
        return [Load.from_json({**row, "object_id": row["object"]}) for row in rows]
    return [Load.from_json(json.loads(line)) for line in text.splitlines() if line.strip()]


def compare(before: Path, after: Path) -> list[str]:
    """A markdown table, cold loads, per object of both runs: method and parts, collision error mean /
    max (mm), CPU-s of the load; then the totals of each set."""
    runs = []
    for path in (before, after):
        rows = read_loads(path)
        runs.append({(r.set, r.object_id): r for r in rows if r.phase == "cold"})
    keys = sorted(set(runs[0]) | set(runs[1]))
    out = ["| set | object | before | after |", "|---|---|---|---|"]
    out += [f"| {s} | {o} | {_cell(runs[0].get((s, o)))} | {_cell(runs[1].get((s, o)))} |" for s, o in keys]
    out.append("")
    for name in dict.fromkeys(s for s, _ in keys):
        for label, run in zip(("before", "after"), runs, strict=True):
            sel = [r for (s, _), r in run.items() if s == name]
            if sel:
                far = sum(1 for r in sel if r.beyond)
                failed, cpu = sum(not r.ok for r in sel), [r.cpu_s for r in sel]
                out.append(
                    f"{name} {label}: {len(sel)} objects, {failed} failed, {far} beyond 2 mm, "
                    f"{sum(cpu):.0f} CPU-s in all, the slowest {max(cpu):.1f}"
                )
    return out


# --------------------------------------------------------------------------------------------------


def _arguments(args: argparse.Namespace) -> tuple[dict, str]:
    """The arguments and the command as the record keeps them: a data folder by its digest."""
    recorded = {k: v for k, v in vars(args).items() if k not in ("ycb", "keep", "json")}
    argv = list(sys.argv[1:])
    if args.ycb is not None:
        recorded["ycb"] = {"graspa_meshes": folder_digest(args.ycb)}
        argv = [("DIR" if a == str(args.ycb) else a) for a in argv]
    return recorded, shlex.join(["python", "-m", "bench.object_sets", *argv])


def stage(args, work: Path) -> dict[str, Path]:
    sets: dict[str, Path] = {}
    if args.ycb:
        stage_ycb(args.ycb, work / "ycb", YCB_MASSES)
        sets["ycb"] = work / "ycb"
    if args.pybullet_data:
        stage_pybullet_data(work / "pybullet_data", PYBULLET_OBJECTS)
        sets["pybullet_data"] = work / "pybullet_data"
    if args.samples:
        stage_samples(work / "samples")
        sets["samples"] = work / "samples"
    return sets


def parser() -> Parser:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ycb", type=existing_folder, help="folder of YCB meshes (*.stl, *.stl.gz)")
    ap.add_argument("--pybullet-data", action="store_true", help="pybullet_data's object URDFs")
    ap.add_argument("--samples", action="store_true", help="the shipped sample objects")
    ap.add_argument("--only", nargs="*", default=[], help="globs of set/object_id to load (part 1)")
    ap.add_argument("--phases", nargs="*", default=["cold", "warm"], choices=["cold", "warm"])
    ap.add_argument(
        "--timeout",
        type=number(0.0, 86_400.0, low_open=True),
        default=3600.0,
        help="wall seconds per load (the bench's own)",
    )
    ap.add_argument("--json", type=writable_file, help="append one JSON line per load here (for --compare)")
    ap.add_argument("--cold-start", default=None, help="set of part 2 [default: ycb, else the first]; none")
    ap.add_argument(
        "--cold-n", type=count(1, N_MAX), default=10, help="candidates per object in the cold-start runs"
    )
    ap.add_argument(
        "--n", type=count(0, N_MAX), default=50, help="candidates per object of the warm runs (0: skip)"
    )
    ap.add_argument("--workers", type=count(1, WORKERS_MAX), default=2, help="workers of the warm runs")
    ap.add_argument("--repeat", type=count(1, REPEAT_MAX), default=2, help="warm runs of each code")
    ap.add_argument("--baseline", help="a commit whose code the warm runs alternate with (e.g. main)")
    ap.add_argument(
        "--keep", type=writable_folder, help="stage the sets and caches here instead of a temp folder"
    )
    return ap


def parse(argv: list[str] | None = None) -> argparse.Namespace:
    ap = parser()
    args = ap.parse_args(argv)
    if not (args.ycb or args.pybullet_data or args.samples):
        ap.error("give at least one set: --ycb DIR, --pybullet-data, --samples")
    return args


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        folder, object_id, cache, set_name, phase = sys.argv[2:7]
        child(Path(folder), object_id, Path(cache), set_name, phase)
        return
    if len(sys.argv) == 4 and sys.argv[1] == "--compare":
        print("\n".join(compare(Path(sys.argv[2]), Path(sys.argv[3]))))
        return
    args = parse()
    recorded, command = _arguments(args)
    with (
        tempfile.TemporaryDirectory(prefix="rg2-object-sets-") as tmp,
        Run("object_sets", config=recorded, command=command) as run,
    ):
        work = args.keep or Path(tmp)
        if args.keep is not None:
            shutil.rmtree(work, ignore_errors=True)
        work.mkdir(parents=True, exist_ok=True)
        measure(args, stage(args, work), work, run)


def measure(args, sets: dict[str, Path], work: Path, run: Run) -> None:
    cache = work / "cache"
    print(f"load average {os.getloadavg()[0]:.2f}; {os.cpu_count()} cores")
    factor = budget_factor(ObjectConfig())  # the ladder's own factor for the loads' configuration
    os.environ[FACTOR_ENV] = repr(factor)  # each load's process uses it instead of measuring again
    print(f"this machine: {factor:.2f} CPU-s per reference CPU-second (annotator.objects.machine_speed)")
    run.figure("budget_factor", factor, note="CPU-s per reference CPU-second: the ladder's budget_factor()")
    rows = loads(args, sets, cache, factor)
    if rows:
        record_loads(rows, run)
    chosen = args.cold_start or ("ycb" if "ycb" in sets else next(iter(sets)))
    if chosen != "none":
        cold_start(args, sets[chosen], chosen, work, run)
    if args.n:
        stage_mix(sets, work / "mix")
        baseline = extract_baseline(args.baseline, work / "baseline") if args.baseline else None
        warm_throughput(args, work / "mix", cache, work, baseline, run)
    print(f"\nload average {os.getloadavg()[0]:.2f}")
    print("\n".join(targets(rows, factor)))


if __name__ == "__main__":
    main()
