"""Labels of this code against another version's, bit for bit: the same commands run by both, the
tables compared with ``pandas.testing.assert_frame_equal(check_exact=True)``.

    python -m bench.label_equality --versus-install ../old --cache ./cache --versus-cache ../old-cache
    python -m bench.label_equality --versus-install ../old --keep out/ --versus-keep old_out/ \\
        --runs cell scenes          # only these; kept folders are resumed, not run again

``--versus-install DIR`` is a checkout of the other version with its own ``DIR/.venv`` (as
``bench.throughput --versus-install``). Each run is the same command for both versions, on the
sample objects (``--objects``), two workers:

- ``objects``: ``annotate --n 200``
- ``cell``: ``annotate --n 30 --cell``
- ``panda``: ``annotate --n 60 --gripper panda``
- ``scenes``: ``annotate --scenes 3 --per-scene 3 --n 40``
- ``evaluate``: ``annotator evaluate`` of the first ``--evaluate-n`` grasps per object of the other
  version's ``objects`` labels (their TCP poses and widths), both versions reading the same file
- ``evaluate_resting``: the same with ``--resting``

Rows are matched on their keys (scene, object, placement, grasp ids); columns only one version
writes are listed, not compared. A kept output folder (``--keep``, ``--versus-keep``) is resumed
by the next bench run (a finished one costs nothing), so a reference made once serves many
comparisons. Give each version its own decomposition cache when their cache keys differ: a
collision shape made under CPU contention may differ from one made on an idle machine, and the
labels follow the shape. Prints one line per run and writes a record (bench/harness.py) whose
figures are 1 (equal) or 0 per run; asserts nothing.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from bench.arguments import N_MAX, WORKERS_MAX, Parser, count, existing_folder, writable_folder
from bench.harness import Run

ROOT = Path(__file__).resolve().parents[1]
KEYS = ("scene_id", "object_id", "placement_id", "grasp_id")
POSE = ("x", "y", "z", "qx", "qy", "qz", "qw", "width")


@dataclass(frozen=True)
class Command:
    """One run both versions make: the console script and its arguments after ``--objects``."""

    script: str
    args: tuple[str, ...]


RUNS: dict[str, Command] = {
    "objects": Command("annotate", ("--n", "200")),
    "cell": Command("annotate", ("--n", "30", "--cell")),
    "panda": Command("annotate", ("--n", "60", "--gripper", "panda")),
    "scenes": Command("annotate", ("--scenes", "3", "--per-scene", "3", "--n", "40")),
    "evaluate": Command("annotator", ("evaluate",)),
    "evaluate_resting": Command("annotator", ("evaluate", "--resting")),
}


@dataclass(frozen=True)
class Version:
    """One side: where its console scripts are, its decomposition cache, where its outputs go."""

    label: str
    bin_dir: Path
    cache: Path | None
    out: Path

    def run(self, name: str, command: Command, objects: Path, workers: int, grasps: Path | None) -> Path:
        """Run ``command`` (resuming a kept folder) and return its output folder."""
        out = self.out / name
        argv = [str(self.bin_dir / command.script), *command.args]
        if command.script == "annotator":  # evaluate GRASPS --objects ... --out ...
            assert grasps is not None
            argv += [str(grasps)]
        argv += ["--objects", str(objects), "--out", str(out), "--workers", str(workers), "--quiet"]
        env = dict(os.environ)
        if self.cache is not None:
            env["RG2_CACHE_DIR"] = str(self.cache)
        proc = subprocess.run(argv, env=env, capture_output=True, text=True)
        if proc.returncode != 0:
            tail = (proc.stdout + proc.stderr).strip().splitlines()[-5:]
            raise SystemExit(f"{self.label}: {' '.join(argv)} exited {proc.returncode}:\n" + "\n".join(tail))
        return out


@dataclass(frozen=True)
class Comparison:
    """How two label tables compare: rows, columns compared, columns one side lacks, equality."""

    rows: int
    versus_rows: int
    compared: tuple[str, ...]
    only_this: tuple[str, ...]
    only_versus: tuple[str, ...]
    equal: bool
    differing: tuple[str, ...]
    message: str


def compare(this: pd.DataFrame, versus: pd.DataFrame) -> Comparison:
    """Compare two label tables bit for bit on the columns both have, rows matched on their keys."""
    keys = [k for k in KEYS if k in this.columns and k in versus.columns]
    a = versus.sort_values(keys).reset_index(drop=True)
    b = this.sort_values(keys).reset_index(drop=True)
    common = tuple(c for c in a.columns if c in b.columns)
    only_this = tuple(c for c in b.columns if c not in a.columns)
    only_versus = tuple(c for c in a.columns if c not in b.columns)
    if len(a) != len(b):
        return Comparison(len(b), len(a), common, only_this, only_versus, False, (), "row counts differ")
    try:
        pd.testing.assert_frame_equal(a[list(common)], b[list(common)], check_exact=True)
    except AssertionError as exc:
        differing = tuple(c for c in common if not a[c].equals(b[c]))
        message = str(exc).splitlines()[0] if str(exc) else "differ"
        return Comparison(len(b), len(a), common, only_this, only_versus, False, differing, message)
    return Comparison(len(b), len(a), common, only_this, only_versus, True, (), "equal")


def evaluate_grasps(labels: Path, per_object: int, dest: Path) -> Path:
    """The first ``per_object`` grasps of each object of ``labels`` (TCP pose and width) as the
    GRASPS file both versions evaluate."""
    table = pd.read_parquet(labels)
    table = table.sort_values(["object_id", "grasp_id"]).groupby("object_id").head(per_object)
    grasps = table[["object_id", "grasp_id", *POSE]].reset_index(drop=True)
    grasps.to_parquet(dest, index=False)
    return dest


def _installed_bin(install: Path | None) -> Path:
    if install is None:
        return Path(sys.executable).parent
    bin_dir = install / ".venv" / "bin"
    if not (bin_dir / "annotate").is_file():
        raise SystemExit(
            f"--versus-install {install}: no {bin_dir / 'annotate'} (install it in DIR/.venv first)"
        )
    return bin_dir


def _install_commit(install: Path) -> str:
    head = subprocess.run(
        ["git", "-C", str(install), "rev-parse", "--short", "HEAD"], capture_output=True, text=True
    )
    return head.stdout.strip() or "unknown commit"


def parser() -> Parser:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--versus-install", type=existing_folder, required=True, help="DIR: the other version, with DIR/.venv"
    )
    ap.add_argument("--objects", type=existing_folder, default=ROOT / "objects")
    ap.add_argument(
        "--runs", nargs="+", choices=sorted(RUNS), default=list(RUNS), help="which runs [default: all]"
    )
    ap.add_argument("--workers", type=count(1, WORKERS_MAX), default=2)
    ap.add_argument("--evaluate-n", type=count(1, N_MAX), default=8, help="grasps per object evaluated")
    ap.add_argument("--cache", type=writable_folder, help="RG2_CACHE_DIR of this version's runs")
    ap.add_argument("--versus-cache", type=writable_folder, help="RG2_CACHE_DIR of the other version's runs")
    ap.add_argument("--keep", type=writable_folder, help="keep (and resume) this version's outputs here")
    ap.add_argument(
        "--versus-keep", type=writable_folder, help="keep (and resume) the other version's outputs here"
    )
    return ap


def main() -> None:
    args = parser().parse_args()
    versus_bin = _installed_bin(args.versus_install)
    commit = _install_commit(args.versus_install)
    tmp = Path(tempfile.mkdtemp(prefix="label_equality-"))
    try:
        this = Version("this", _installed_bin(None), args.cache, args.keep or tmp / "this")
        versus = Version(commit, versus_bin, args.versus_cache, args.versus_keep or tmp / "versus")
        rows = []
        with Run("label_equality", config=vars(args)) as record:
            grasps = None
            for name in args.runs:
                command = RUNS[name]
                if command.script == "annotator" and grasps is None:
                    source = versus.run("objects", RUNS["objects"], args.objects, args.workers, None)
                    grasps = evaluate_grasps(source, args.evaluate_n, tmp / "grasps.parquet")
                a = versus.run(name, command, args.objects, args.workers, grasps)
                b = this.run(name, command, args.objects, args.workers, grasps)
                result = compare(pd.read_parquet(b), pd.read_parquet(a))
                shown = " ".join((command.script, *command.args))
                differing = ", ".join(result.differing)
                verdict = "EQUAL" if result.equal else f"DIFFER ({result.message}; {differing})"
                extra = (
                    f"; only this version writes {', '.join(result.only_this)}" if result.only_this else ""
                )
                size = f"{result.rows} rows, {len(result.compared)} columns"
                print(f"{name:17s} {shown}: {size}: {verdict}{extra}")
                record.figure(
                    f"{name}_equal",
                    int(result.equal),
                    "",
                    note=f"{shown} on {args.objects.name}/: {size} compared exactly against the code at "
                    f"{commit}{extra}",
                )
                rows.append(
                    {
                        "run": name,
                        "command": shown,
                        "rows": result.rows,
                        "versus_rows": result.versus_rows,
                        "columns_compared": len(result.compared),
                        "equal": result.equal,
                        "differing": ", ".join(result.differing),
                        "only_this": ", ".join(result.only_this),
                        "only_versus": ", ".join(result.only_versus),
                    }
                )
            record.table("runs", rows, note=f"this code against the code at {commit}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
