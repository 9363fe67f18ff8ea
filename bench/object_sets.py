"""Object sets as users bring them: how each object becomes simulable, cold (empty decomposition
cache) and warm (the same cache filled), per object and in total.

    python bench/object_sets.py --ycb DIR                       # YCB meshes (*.stl or *.stl.gz)
    python bench/object_sets.py --ycb DIR --pybullet-data --samples --json out.jsonl
    python bench/object_sets.py --samples --only 'samples/mug'
    python bench/object_sets.py --compare before.jsonl after.jsonl   # a markdown table of two runs

Sets (each optional; the data folders are arguments, nothing is copied into the project):

- ``--ycb DIR``: a folder of YCB meshes (e.g. the 16 ``nontextured.stl`` meshes of the GRASPA
  benchmark, hsp-iit/GRASPA-benchmark, gzipped or not); masses from ``--ycb-masses`` (name=kg, as
  in the YCB object set's published table) go into the folder's ``objects.toml``.
- ``--pybullet-data``: object URDFs of the installed pybullet_data (:data:`PYBULLET_OBJECTS`).
- ``--samples``: the shipped sample objects (``objects/``).

Each set is copied into one scratch folder (the gzipped meshes decompressed), and every object is
loaded by ``annotator.objects.load_object`` in a child process of its own, twice: with an empty
cache folder (cold; one folder for the whole run, so nothing is shared with other runs), then
with that folder filled (warm). Per object: the collision method and parts, the collision error
(mean / max, mm, against the cleaned mesh), the CPU seconds of the load (the child's own and its
children's, i.e. the isolated decomposition), wall seconds, the child's peak RSS, and the failure
reason of an object that fails. Totals per set: failures, objects beyond 2 mm max, the largest
and summed cold CPU seconds. CPU seconds are this machine's; its speed varies between days, so
compare two builds in the same run, or the ratio of their totals.
"""

from __future__ import annotations

import argparse
import fnmatch
import gzip
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

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
MAX_CPU = 60.0  # s, the target: no object takes longer to become simulable

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


# --------------------------------------------------------------------------------------------------
# the child: one load


def _cpu() -> float:
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def child(folder: Path, object_id: str, cache: Path, set_name: str, phase: str) -> None:
    """Load one object and print its :class:`Load` as JSON (the last line of stdout)."""
    import logging

    from annotator.config import AnnotatorConfig
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
        out.cleaning = model.cleaning.summary()
        out.error_mean_mm = err.mean * 1e3
        out.error_max_mm = err.max * 1e3
        out.threshold = float(model.collision_threshold)
        out.decomposition_seconds = float(model.decomposition_seconds)
        out.warnings = list(getattr(model, "warnings", []))
        out.ladder = str(getattr(model, "collision_ladder", ""))
    out.cpu_s = _cpu() - c0
    out.wall_s = time.perf_counter() - t0
    kids = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    out.peak_rss_mb = max(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, kids) / 1024.0
    print(json.dumps(asdict(out)))


def run_child(folder: Path, object_id: str, cache: Path, set_name: str, phase: str, timeout: float) -> Load:
    cmd = [sys.executable, __file__, "--child", str(folder), object_id, str(cache), set_name, phase]
    t0 = time.perf_counter()
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)
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


def object_ids(folder: Path) -> list[str]:
    from annotator.config import ObjectConfig
    from annotator.objects import discover_objects

    return [s.object_id for s in discover_objects(folder, ObjectConfig())]


# --------------------------------------------------------------------------------------------------
# report


def _row(r: Load) -> str:
    if not r.ok:
        return f"  {r.object_id:<26} {r.phase:<4} FAILED {r.reason[:90]}  ({r.cpu_s:.1f} CPU-s)"
    flag = "" if r.error_max_mm <= MAX_ERROR * 1e3 else " >2mm"
    flag += "" if r.phase == "warm" or r.cpu_s <= MAX_CPU else " >60s"
    return (
        f"  {r.object_id:<26} {r.phase:<4} {r.method:<8} {r.parts:3d} parts {r.faces:7d} faces "
        f"err {r.error_mean_mm:6.2f} / {r.error_max_mm:6.2f} mm  {r.cpu_s:7.1f} CPU-s {r.wall_s:7.1f} s "
        f"{r.peak_rss_mb:6.0f} MB{flag}" + (f"\n      {r.ladder}" if r.ladder and r.phase == "cold" else "")
    )


def _cell(r: Load | None) -> str:
    if r is None:
        return "–"
    if not r.ok:
        return f"failed: {r.reason[:60]}"
    return f"{r.method} {r.parts}, {r.error_mean_mm:.2f} / {r.error_max_mm:.2f} mm, {r.cpu_s:.1f} CPU-s"


def compare(before: Path, after: Path) -> list[str]:
    """A markdown table, cold loads, per object of both runs: method and parts, collision error mean /
    max (mm), CPU-s of the load; then the totals of each set."""
    runs = []
    for path in (before, after):
        rows = [Load.from_json(json.loads(line)) for line in path.read_text().splitlines() if line.strip()]
        runs.append({(r.set, r.object_id): r for r in rows if r.phase == "cold"})
    keys = sorted(set(runs[0]) | set(runs[1]))
    out = ["| set | object | before | after |", "|---|---|---|---|"]
    out += [f"| {s} | {o} | {_cell(runs[0].get((s, o)))} | {_cell(runs[1].get((s, o)))} |" for s, o in keys]
    out.append("")
    for name in dict.fromkeys(s for s, _ in keys):
        for label, run in zip(("before", "after"), runs, strict=True):
            sel = [r for (s, _), r in run.items() if s == name]
            if sel:
                far = sum(1 for r in sel if r.ok and r.error_max_mm > MAX_ERROR * 1e3)
                failed, cpu = sum(not r.ok for r in sel), [r.cpu_s for r in sel]
                out.append(
                    f"{name} {label}: {len(sel)} objects, {failed} failed, {far} beyond 2 mm, "
                    f"{sum(cpu):.0f} CPU-s in all, the slowest {max(cpu):.1f}"
                )
    return out


def totals(rows: list[Load]) -> list[str]:
    out = []
    for name in dict.fromkeys(r.set for r in rows):
        for phase in ("cold", "warm"):
            sel = [r for r in rows if r.set == name and r.phase == phase]
            if not sel:
                continue
            ok = [r for r in sel if r.ok]
            far = [r.object_id for r in ok if r.error_max_mm > MAX_ERROR * 1e3]
            cpu = [r.cpu_s for r in sel]
            slowest = max(sel, key=lambda r: r.cpu_s)
            methods: dict[str, int] = {}
            for r in ok:
                methods[r.method] = methods.get(r.method, 0) + 1
            out.append(
                f"{name:<13} {phase}: {len(sel)} objects, {len(sel) - len(ok)} failed, "
                f"{len(far)} beyond 2 mm max {far if far else ''}; CPU-s total {sum(cpu):.1f} "
                f"(max {slowest.cpu_s:.1f} {slowest.object_id}); methods {methods}; "
                f"peak RSS max {max(r.peak_rss_mb for r in sel):.0f} MB"
            )
    return out


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        folder, object_id, cache, set_name, phase = sys.argv[2:7]
        child(Path(folder), object_id, Path(cache), set_name, phase)
        return
    if len(sys.argv) == 4 and sys.argv[1] == "--compare":
        print("\n".join(compare(Path(sys.argv[2]), Path(sys.argv[3]))))
        return
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ycb", type=Path, help="folder of YCB meshes (*.stl, *.stl.gz)")
    ap.add_argument("--pybullet-data", action="store_true", help="pybullet_data's object URDFs")
    ap.add_argument("--samples", action="store_true", help="the shipped sample objects")
    ap.add_argument("--only", nargs="*", default=[], help="globs of set/object_id to run")
    ap.add_argument("--phases", nargs="+", default=["cold", "warm"], choices=["cold", "warm"])
    ap.add_argument("--timeout", type=float, default=3600.0, help="wall seconds per load (the bench's own)")
    ap.add_argument("--json", type=Path, help="append one JSON line per load here")
    ap.add_argument("--keep", type=Path, help="stage the sets and the cache here instead of a temp folder")
    args = ap.parse_args()
    if not (args.ycb or args.pybullet_data or args.samples):
        ap.error("give at least one set: --ycb DIR, --pybullet-data, --samples")
    with tempfile.TemporaryDirectory(prefix="rg2-object-sets-") as tmp:
        work = args.keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        cache = work / "cache"
        if cache.exists():
            shutil.rmtree(cache)
        sets: dict[str, Path] = {}
        if args.ycb:
            sets["ycb"] = work / "ycb"
            shutil.rmtree(sets["ycb"], ignore_errors=True)
            stage_ycb(args.ycb, sets["ycb"], YCB_MASSES)
        if args.pybullet_data:
            sets["pybullet_data"] = work / "pybullet_data"
            shutil.rmtree(sets["pybullet_data"], ignore_errors=True)
            stage_pybullet_data(sets["pybullet_data"], PYBULLET_OBJECTS)
        if args.samples:
            sets["samples"] = work / "samples"
            shutil.rmtree(sets["samples"], ignore_errors=True)
            stage_samples(sets["samples"])
        rows: list[Load] = []
        print(f"load average {os.getloadavg()[0]:.2f}; {os.cpu_count()} cores")
        for phase in args.phases:
            for name, folder in sets.items():
                print(f"== {name} ({phase})", flush=True)
                for oid in object_ids(folder):
                    if args.only and not any(fnmatch.fnmatch(f"{name}/{oid}", g) for g in args.only):
                        continue
                    r = run_child(folder, oid, cache, name, phase, args.timeout)
                    rows.append(r)
                    print(_row(r), flush=True)
                    if args.json:
                        with args.json.open("a") as fh:
                            fh.write(json.dumps(asdict(r)) + "\n")
        print(f"\nload average {os.getloadavg()[0]:.2f}")
        print("\n".join(totals(rows)))


if __name__ == "__main__":
    main()
