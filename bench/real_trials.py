"""Simulated grasps against real ones: GRASPA's Franka Panda trials through evaluate and calibrate.

    python -m bench.real_trials [--data FOLDER] [--work FOLDER] [--workers 2]

The data folder holds GRASPA's real Franka Panda trials of two planners (dexnet, gpd): 200 grasps
on 14 YCB objects lying on a board, each with the gripper's pose relative to the object and the
real outcome (``grasped``: lifted, GRASPA's S4; ``stability``: the share of a shaking motion it
stayed in the hand, S5), the board layouts (each object's pose on the board, millimetres) and the
YCB meshes (gzipped STL, metres); its README gives the frames. Default: the folder
``graspa_panda_calibration`` under ``real`` of the folder ``shared`` beside the repository or
beside its parent. It is read, never copied into the project; nothing here is a test.

What is built in ``--work`` (a scratch folder, default under the system's temporary folder):

- ``objects/``: the meshes gunzipped, and ``objects.toml`` with the YCB masses the data's README
  gives (the YCB object set's table).
- ``grasps_base.csv``: each trial's grasp as the pose of the Panda hand's base frame in the
  object's mesh frame, ``T_obj_base = T_obj_graspa · Tz(-105 mm) · Rz(-90 deg)``: GRASPA's TCP is
  the Franka hand frame moved 105 mm along its z (the approach) and its fingers close along its y,
  our Panda base frame is Franka's hand frame with x = -y, y = x (ACRONYM's axes, the fingers
  along x). Each row also carries the object's orientation on the board (``rest_q*``: the
  layout's rotation, orthonormalised), so an object whose mesh z pointed down rests upside down.
- ``grasps_tcp.csv``: the same grasps as TCP poses of our Panda model (its pad-centre midpoint,
  103.65 mm along the base's z: ``T_obj_graspa · Rz(-90 deg) · Tz(-1.35 mm)``), for the RG2 at
  the same TCP poses.
- ``real.csv``: ``object_id, grasp_id, real_success`` (= ``grasped``).

Then ``annotator evaluate --gripper panda --frame base --resting`` (the default model),
``annotator evaluate --gripper rg2 --resting`` at the TCP poses, and ``annotator calibrate``
over a grid of pad friction, grip force and shake severity on the Panda's labels, cross-validated
by object, with every simulated outcome written for the figures. Printed and recorded, each with a
95 % percentile bootstrap interval over the trials: accuracy, balanced accuracy, precision,
recall and F1 of simulated ``success`` against real ``grasped``, for the default Panda, the
setting calibrated by object-wise cross-validation (the held-out predictions of every fold,
pooled), the setting fitted on all trials (optimistic: chosen and scored on the same trials), two
baselines (always "success"; an analytic check on the mesh: the contacts of the pads' centre
line both inside a friction cone) and the RG2; per object; the folds; and the rows where the
calibrated simulation and reality disagree.

``--cost`` also times the Panda's evaluate at ``--trials 1`` and (with lift-only perturbed trials)
at ``--trials K`` with the perturbed fingers closing from where the approach left them, with the
perturbed closes stalled by speed alone, and with the perturbed trials run as trial 0 up to the
lift (approaches in full, closes stalled by speed), one after another:
CPU seconds of the command and its workers, and their ratios to ``--trials 1`` (run it on a quiet
machine).
"""

from __future__ import annotations

import argparse
import gzip
import math
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from annotator.config import AnnotatorConfig
from annotator.geometry import matrix_to_quat
from bench.arguments import (
    WORKERS_MAX,
    Parser,
    count,
    existing_file,
    existing_folder,
    number,
    writable_folder,
)
from bench.harness import ROOT, Run
from bench.object_sets import YCB_MASSES  # kg, the YCB set's published masses

DATA_NAME = "graspa_panda_calibration"
# m: GRASPA's TCP on the Franka hand frame's z (the data's README; hsp-panda/panda_grasp_server
# moves the panda_tcp link there), and our Panda model's TCP, the pad-centre midpoint (its FK).
# The public sources disagree: GRASPA's Simox gripper model puts panda_tcp 90 mm from its root
# (hsp-iit/GRASPA-test experiment_data/panda/panda_gripper/panda_gripper.xml); --tcp-depth
# measures the figures at another depth.
GRASPA_TCP_DEPTH = 0.105
# The Franka hand frame's axes seen from our Panda base frame: x = -y, y = x (Rz(-90 deg)).
R_HAND_BASE = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
POSE = [f"T_obj_tcp_{i}{j}" for i in range(3) for j in range(4)]
# m: the Panda hand's stroke. GRASPA's grasp server opens the hand fully (0.079 m) before each
# approach (hsp-panda/panda_grasp_server@0b0d184, open_gripper), so the Panda's grasps are given
# this width: the gripper approaches fully open and closes from there, whatever the chord.
PANDA_STROKE = 0.080
STATISTICS = ("accuracy", "balanced", "precision", "recall", "f1")
# m: Bullet resists a contact's spin with (pad spinning x object lateral + object spinning x pad
# lateral) friction times the normal force (btManifoldResult::calculateCombinedSpinningFriction).
# A rubber pad of 17.5 x 18.5 mm (the Panda's, assets/grippers/panda/README.md) pressed flat with
# uniform pressure resists with mu N times the mean distance of its area from its centre, 6.90 mm;
# with mu 1 on both sides and the objects' 0.002 m, the pad's share is 6.90 - 2.0 = 4.9 mm. An
# upper bound: a curved object touches a smaller patch.
FLAT_PAD_SPINNING = 0.0049
# The analytic baseline's Coulomb coefficient: the project's antipodal test (SamplerConfig).
CONE_FRICTION = AnnotatorConfig().sampler.friction_coefficient


def default_data() -> Path | None:
    """The data folder beside the repository or beside its parent, if there is one."""
    for base in (ROOT.parent, ROOT.parent.parent):
        folder = base.joinpath("shared", "real", DATA_NAME)
        if (folder / "trials.csv").is_file():
            return folder
    return None


# --- the data ------------------------------------------------------------------------------------


def read_layout(path: Path) -> dict[str, np.ndarray]:
    """Object (YCB name) -> ``T_board_obj`` (4, 4), metres, rotation orthonormalised (the files
    give some rotations to four digits)."""
    out = {}
    for obj in ET.parse(path).getroot().iter("ManipulationObject"):
        name = obj.find("File").text.split("/")[-2]
        matrix = obj.find("GlobalPose/Transform/Matrix4x4")
        T = np.eye(4)
        for i in range(4):
            row = matrix.find(f"row{i + 1}")
            for j in range(4):
                T[i, j] = float(re.sub(r"[^0-9eE.+-]", "", row.get(f"c{j + 1}")))
        U, _, Vt = np.linalg.svd(T[:3, :3])
        T[:3, :3] = U @ Vt
        T[:3, 3] /= 1000.0
        out[name] = T
    return out


@dataclass(frozen=True)
class Prepared:
    """The trials (``trials``: one row per trial with its ``object_id`` and ``grasp_id`` in the
    tables below, ``T_obj_graspa`` (n, 4, 4)), and the files written for the commands."""

    trials: pd.DataFrame
    T_obj_graspa: np.ndarray
    objects: Path
    grasps_base: Path
    grasps_tcp: Path
    real: Path


def prepare(data: Path, work: Path, tcp_depth: float = GRASPA_TCP_DEPTH) -> Prepared:
    """Objects, grasp tables and real outcomes in ``work`` (see the module docstring); GRASPA's
    TCP ``tcp_depth`` (m) along the Franka hand frame's z."""
    trials = pd.read_csv(data / "trials.csv")
    layouts = {
        k: read_layout(data / "layouts" / f"layout_{k}.xml") for k in sorted(trials["layout"].unique())
    }
    objects = work / "objects"
    objects.mkdir(parents=True, exist_ok=True)
    for name in sorted(trials["object"].unique()):
        target = objects / f"{name}.stl"
        if not target.is_file():
            with gzip.open(data / "meshes" / f"{name}.stl.gz", "rb") as src, open(target, "wb") as dst:
                shutil.copyfileobj(src, dst)
    toml = "".join(f'["{n}"]\nmass = {YCB_MASSES[n]}\n' for n in sorted(trials["object"].unique()))
    (objects / "objects.toml").write_text(toml)

    trials = trials.assign(object_id=trials["object"])
    trials["grasp_id"] = trials.groupby("object_id").cumcount()
    T = np.tile(np.eye(4), (len(trials), 1, 1))
    T[:, :3, :] = trials[POSE].to_numpy(dtype=np.float64).reshape(-1, 3, 4)
    rest = np.array([matrix_to_quat(layouts[r.layout][r.object][:3, :3]) for r in trials.itertuples()])
    base = T @ _tz(-tcp_depth) @ _rot(R_HAND_BASE)
    tcp = base @ _tz(_panda_tcp_depth())
    paths = {}
    for name, poses in (("grasps_base", base), ("grasps_tcp", tcp)):
        table = _pose_table(trials, poses, rest)
        if name == "grasps_base":  # GRASPA's robot opened the hand fully before every approach
            table["width"] = PANDA_STROKE
        paths[name] = work / f"{name}.csv"
        table.to_csv(paths[name], index=False, float_format="%.17g")
    real = work / "real.csv"
    trials.assign(real_success=trials["grasped"])[["object_id", "grasp_id", "real_success"]].to_csv(
        real, index=False
    )
    return Prepared(trials, T, objects, paths["grasps_base"], paths["grasps_tcp"], real)


def _tz(z: float) -> np.ndarray:
    T = np.eye(4)
    T[2, 3] = z
    return T


def _rot(R: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    return T


def _panda_tcp_depth() -> float:
    from annotator.tools.export import TcpDepth

    return float(TcpDepth("panda").T_base_tcp(np.array([0.04]))[0][2, 3])


def _pose_table(trials: pd.DataFrame, T: np.ndarray, rest: np.ndarray) -> pd.DataFrame:
    from annotator.dataset import pose_columns

    table = pose_columns(T)
    table.insert(0, "object_id", trials["object_id"].to_numpy())
    table.insert(1, "grasp_id", trials["grasp_id"].to_numpy())
    table[["rest_qx", "rest_qy", "rest_qz", "rest_qw"]] = rest
    return table


# --- running the commands -------------------------------------------------------------------------


def children_cpu() -> float:
    """CPU seconds (user + system) of this process's finished children and what they waited for."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def annotator(*args: object) -> str:
    """Run ``annotator ARGS`` in a child process (this interpreter); its output, echoed."""
    cmd = [sys.executable, "-c", "from annotator.cli import main; main()", *map(str, args)]
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True)
    output = done.stdout + done.stderr
    print(output, end="", flush=True)
    if done.returncode != 0:
        raise RuntimeError(f"annotator {args[0]} exited {done.returncode}")
    print(f"[annotator {args[0]}: {time.perf_counter() - t0:.0f} s]", flush=True)
    return output


def evaluate(
    prepared: Prepared, out: Path, gripper: str, frame: str, workers: int, config=None, trials: int = 1
) -> pd.DataFrame:
    """``annotator evaluate --resting`` of one grasp table (``--trials trials``); the rows in the
    trials' order."""
    table = prepared.grasps_base if frame == "base" else prepared.grasps_tcp
    args = ["evaluate", table, "--objects", prepared.objects, "--out", out, "--gripper", gripper]
    args += ["--frame", frame, "--resting-grasps", "table", "--workers", workers, "--quiet", "--overwrite"]
    args += ["--trials", trials]
    if config is not None:
        args += ["--config", config]
    annotator(*args)
    rows = pd.read_parquet(out)
    return prepared.trials[["object_id", "grasp_id"]].merge(rows, on=["object_id", "grasp_id"], how="left")


# --- figures ---------------------------------------------------------------------------------------


def stats(real: np.ndarray, sim: np.ndarray, bootstrap: int, seed: int = 0):
    from annotator.tools.calibrate import agreement

    return agreement(np.asarray(real, bool), np.asarray(sim, bool), bootstrap, seed)


def stat_row(name: str, a, **extra) -> dict:
    row = {"predictor": name, **extra, "n": a.n}
    for s in STATISTICS:
        row[s] = a.value(s)
        row[f"{s}_lo"], row[f"{s}_hi"] = a.interval(s)
    return row


def show(row: dict) -> str:
    parts = []
    for s in STATISTICS:
        v = row[s]
        parts.append(
            f"{s} n/a"
            if not math.isfinite(v)
            else f"{s} {100 * v:.1f} [{100 * row[s + '_lo']:.0f}, {100 * row[s + '_hi']:.0f}]"
        )
    return f"{row['predictor']:>28}: " + ", ".join(parts)


def friction_cone_baseline(prepared: Prepared, tcp: np.ndarray, stroke: float, mu: float) -> np.ndarray:
    """An analytic check on the mesh: the pads' centre line (the TCP's x through the TCP) meets the
    mesh on both sides within the stroke, and the closing line lies inside the friction cone
    (half-angle atan ``mu``) of both contacts. Scanned meshes' faces may be wound either way: the
    cone test takes the normal's line, not its side."""
    import trimesh

    from annotator.sampler import _first_hits

    out = np.zeros(len(tcp), dtype=bool)
    cos_cone = 1.0 / math.sqrt(1.0 + mu**2)
    for oid, idx in prepared.trials.groupby("object_id").indices.items():
        mesh = trimesh.load(prepared.objects / f"{oid}.stl", force="mesh")
        tri = np.asarray(mesh.triangles)
        normals = np.asarray(mesh.face_normals)
        T = tcp[idx]
        x, p = T[:, :3, 0], T[:, :3, 3]
        half = stroke / 2
        t1, f1 = _first_hits(tri, p - half * x, x)
        t2, f2 = _first_hits(tri, p + half * x, -x)
        reach = (t1 <= half) & (t2 <= half)
        n1 = np.abs(np.sum(normals[np.maximum(f1, 0)] * x, axis=1))
        n2 = np.abs(np.sum(normals[np.maximum(f2, 0)] * x, axis=1))
        out[idx] = reach & (f1 >= 0) & (f2 >= 0) & (n1 >= cos_cone) & (n2 >= cos_cone)
    return out


def data_digest(data: Path) -> str:
    """SHA-256 of what the data folder says about the trials (``trials.csv`` and the layouts), the
    first 8 hex digits: the tag of its records, so two data sets never share a record."""
    import hashlib

    h = hashlib.sha256()
    for path in [data / "trials.csv", *sorted((data / "layouts").glob("*.xml"))]:
        h.update(path.name.encode() + b"\0" + path.read_bytes())
    return h.hexdigest()[:8]


def trials_folder(text: str) -> Path:
    """An argparse type: a folder holding the trials (its ``trials.csv``)."""
    folder = existing_folder(text)
    if not (folder / "trials.csv").is_file():
        raise argparse.ArgumentTypeError(f"{text}: no trials.csv in it")
    return folder


def parser() -> Parser:
    ap = Parser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--data", type=trials_folder, default=None, help="the trials' folder [default: see above]"
    )
    ap.add_argument("--work", type=writable_folder, default=Path(tempfile.gettempdir()) / "rg2-real-trials")
    ap.add_argument(
        "--cache",
        type=writable_folder,
        default=None,
        help="the decomposition cache of the bench's runs [default: WORK/cache, never the user's]",
    )
    ap.add_argument("--workers", type=count(1, WORKERS_MAX), default=2)
    ap.add_argument("--bootstrap", type=count(1, 1_000_000), default=2000)
    ap.add_argument("--folds", type=count(0, 1000), default=5)
    ap.add_argument(
        "--profile",
        type=existing_file,
        default=None,
        help="apply this frozen profile (a calibrate --fit-ranges file) to the trials, without fitting "
        "anything: its ranges, gate, --trials and p_success mapping and threshold, as a user applies it",
    )
    ap.add_argument(
        "--explore-trials",
        type=count(1, 100_000),
        default=64,
        help="perturbed trials per grasp in the fit's exploration",
    )
    ap.add_argument("--no-fit", action="store_true", help="skip the fit of the execution (the longest part)")
    ap.add_argument(
        "--no-baseline",
        action="store_true",
        help="skip the default ranges' confidence and the agreement table (compare fits of variants)",
    )
    ap.add_argument(
        "--stages-only",
        action="store_true",
        help="only trial 0's stages against the real outcomes (one evaluate at --trials 1): to compare "
        "protocols (--set) quickly",
    )
    ap.add_argument(
        "--trials",
        type=count(1, 100),
        default=5,
        help="--trials of the default ranges' baseline (score, p_success)",
    )
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SECTION.FIELD=VALUE",
        help="a configuration change for every simulation (repeatable), "
        "e.g. gripper.pad_spinning_friction=0.0049",
    )
    ap.add_argument(
        "--grid", action="store_true", help="also run calibrate's grid of friction, force, severity"
    )
    ap.add_argument("--friction", default="0.5,1.0,2.0", help="pad friction coefficients of the grid")
    ap.add_argument("--force", default="25,70,140", help="grip forces of the grid, N")
    ap.add_argument("--severity", default="0,0.5,1", help="shake severities of the grid (0: lift only)")
    ap.add_argument("--rg2", action="store_true", help="also simulate the RG2 at the same TCP poses")
    ap.add_argument(
        "--perturbed-shake",
        action="store_true",
        help="shake the default ranges' perturbed trials as trial 0 ([robust] shake = true)",
    )
    ap.add_argument(
        "--cost",
        action="store_true",
        help="also time the Panda's evaluate at --trials 1 and (lift-only perturbed trials) at --trials K "
        "with each shortcut of the perturbed trials off, and with the perturbed trials as trial 0 up to the "
        "lift: CPU seconds and ratios, one after another",
    )
    ap.add_argument(
        "--pad-spinning-friction",
        type=number(0.0, 1.0),
        default=None,
        help="[gripper] pad_spinning_friction for every simulation, m [default: the description's]; "
        f"{FLAT_PAD_SPINNING:.4f}: the Panda's rubber pad pressed flat (FLAT_PAD_SPINNING)",
    )
    ap.add_argument(
        "--tcp-depth",
        type=number(0.0, 1.0),
        default=GRASPA_TCP_DEPTH,
        help="GRASPA's TCP along the Franka hand frame's z, m [default: the data's 0.105]",
    )
    return ap


def main() -> None:  # noqa: C901 - a script: one pass from the data to the record
    ap = parser()
    args = ap.parse_args()
    data = args.data or default_data()
    if data is None:
        ap.error("no trials.csv in the default places; pass --data FOLDER")
    args.work.mkdir(parents=True, exist_ok=True)
    args.cache = (args.cache or args.work / "cache").resolve()
    os.environ["RG2_CACHE_DIR"] = str(args.cache)  # this process's workers and every command it runs
    digest = data_digest(data)
    prepared = prepare(data, args.work, args.tcp_depth)
    real = prepared.trials["grasped"].to_numpy(dtype=bool)
    print(
        f"{len(real)} real trials on {prepared.trials.object_id.nunique()} objects, "
        f"{real.mean():.1%} grasped "
        f"(data {data.name}, digest {digest})"
    )
    arguments = {
        k: (v if k not in ("data", "work", "cache", "profile") else None) for k, v in vars(args).items()
    }
    arguments["data"] = data.name
    arguments["data_digest"] = digest
    arguments["profile"] = None if args.profile is None else args.profile.name
    config = execution_config(args.work, args.pad_spinning_friction, args.perturbed_shake, args.set)
    annotator_config = AnnotatorConfig.from_toml(config)
    tag = f"data-{digest}"
    if args.set or args.pad_spinning_friction is not None or args.tcp_depth != GRASPA_TCP_DEPTH:
        import hashlib

        changes = repr((sorted(args.set), args.pad_spinning_friction, args.tcp_depth)).encode()
        tag += "-set-" + hashlib.sha256(changes).hexdigest()[:6]  # a variant's record beside the default's
    if args.stages_only:
        tag += "-stages"
    if args.profile is not None:
        tag += f"-profile-{args.profile.stem}"  # a frozen profile's record beside the fitted run's
    with Run(
        "real_trials",
        config=arguments,
        annotator=annotator_config,
        command="python -m bench.real_trials",
        tag=tag,
    ) as run:
        label = f"{data.name} ({digest})"
        if args.profile is not None:
            profile_report(run, prepared, real, args, label)
            return
        stage_report(run, prepared, real, args, config)
        if args.stages_only:
            return
        if not args.no_baseline:
            report(run, prepared, real, args, config, label)
        if not args.no_fit:
            fit_report(run, prepared, real, args, config, label)


def chord_check(prepared: Prepared) -> dict[str, float]:
    """Which of GRASPA's TCP axes the fingers close along: the share of grasps whose pads, closing
    along the axis through the TCP, meet the mesh on both sides within the Panda's 80 mm."""
    import trimesh

    from annotator.tools.evaluate import expected_width

    out = {}
    for axis, R in (("y", _rot(R_HAND_BASE)), ("x", np.eye(4))):
        found = 0
        for oid, idx in prepared.trials.groupby("object_id").indices.items():
            mesh = trimesh.load(prepared.objects / f"{oid}.stl", force="mesh")
            found += int((expected_width(mesh, prepared.T_obj_graspa[idx] @ R, 0.080) > 0).sum())
        out[axis] = found / len(prepared.trials)
    return out


def execution_config(
    work: Path,
    pad_spinning_friction: float | None = None,
    perturbed_shake: bool = False,
    changes: Sequence[str] = (),
) -> Path:
    """The trial as GRASPA's robot executed it, written for ``--config`` (docs/real_trials.md);
    ``pad_spinning_friction`` (m) overrides the gripper description's when given;
    ``perturbed_shake``: the perturbed trials shake too ([robust] shake); ``changes``:
    ``section.field=value`` for every simulation (``--set``)."""
    from annotator.tools.calibrate import config_toml
    from bench._variants import parse_variant

    path = work / "execution.toml"
    spec = ",".join(
        [
            f"protocol.{k}={v!r}" if isinstance(v, float) else f'protocol.{k}="{v}"'
            for k, v in EXECUTION.items()
        ]
        + (
            [f"gripper.pad_spinning_friction={pad_spinning_friction!r}"]
            if pad_spinning_friction is not None
            else []
        )
        + (["robust.shake=true"] if perturbed_shake else [])
        + list(changes)
    )
    _, config = parse_variant(spec)
    header = (
        "GRASPA's execution (hsp-panda/panda_grasp_server@0b0d184): the arm moves to the grasp in a\n"
        "straight line whatever it meets (the object is not in its planning scene), then lifts slowly"
    )
    path.write_text(config_toml(config, header))
    return path


# The execution settings of docs/real_trials.md: a simulated approach at 0.1 m/s, a 10 cm lift in 0.5 s.
EXECUTION = {"approach": "simulated", "approach_speed": 0.1, "lift_duration": 0.5}


# --cost's runs at --trials K with the perturbed trials' shortcuts off: (name, [robust] lines, note)
COST_VARIANTS = (
    (
        "fingers_from_where",
        "fingers_from_contact = false",
        "the perturbed fingers closing from where the approach left them",
    ),
    ("by_speed", "stall_by_travel = false", "the perturbed closes stalled by the drive's speed alone"),
    (
        "in_full",
        "approach_from_contact = false\nstall_by_travel = false\nfingers_from_contact = false",
        "the perturbed approaches in full and their closes stalled by speed alone (trial 0's protocol)",
    ),
)


def evaluate_cost(
    run: Run, prepared: Prepared, args, config: Path, cpu_k: float, rows_k: pd.DataFrame
) -> None:
    """The Panda's evaluate at ``--trials 1`` and, with lift-only perturbed trials, at ``--trials
    K`` with their shortcuts off (:data:`COST_VARIANTS`), after the run at K that took ``cpu_k``
    CPU-s and gave ``rows_k``: each one's CPU seconds (the command and its workers) and their
    ratios to ``--trials 1``, and how many scores each variant changes, recorded."""
    k, work = args.trials, args.work
    cpu = {f"k{k}": cpu_k}
    before = children_cpu()
    evaluate(prepared, work / "ev_cost_k1", "panda", "base", args.workers, config, 1)
    cpu["k1"] = children_cpu() - before
    for variant, lines, what in COST_VARIANTS if not args.perturbed_shake else ():
        toml = work / f"execution_{variant}.toml"
        toml.write_text(config.read_text() + f"[robust]\n{lines}\n")
        before = children_cpu()
        rows = evaluate(prepared, work / f"ev_cost_{variant}", "panda", "base", args.workers, toml, k)
        cpu[f"k{k}_{variant}"] = children_cpu() - before
        diff = rows_k["score"].to_numpy() - rows["score"].to_numpy()
        changed = int(np.sum(diff != 0))
        run.figure(f"scores_changed_vs_{variant}", changed, note=f"grasps whose score differs with {what}")
        run.figure(f"score_minus_{variant}_mean", float(np.mean(diff)), note="over all grasps")
        print(f"{what}: {changed} of {len(diff)} scores change, mean {np.mean(diff):+.3f}")
    for name, seconds in cpu.items():
        note = "the Panda's evaluate, the command and its workers"
        run.figure(f"evaluate_cpu_s_{name}", seconds, "CPU-s", note=note)
        if name != "k1":
            run.ratio(f"evaluate_{name}_over_k1", seconds / cpu["k1"], note=f"CPU seconds of {note}")
        print(f"evaluate, {name}: {seconds:.1f} CPU-s ({seconds / cpu['k1']:.2f} x --trials 1)", flush=True)


def report(run: Run, prepared: Prepared, real: np.ndarray, args, config: Path, label: str) -> None:  # noqa: C901
    from annotator.tools import calibrate as cal

    work, boot = args.work, args.bootstrap
    trials = prepared.trials
    chords = chord_check(prepared)
    print(
        f"closing along GRASPA's y: a chord within 80 mm for {chords['y']:.0%} of grasps; "
        f"along x: {chords['x']:.0%}"
    )
    run.figure(
        "chord_share_closing_y",
        chords["y"],
        note="grasps whose pads, closing along GRASPA's TCP y, meet the mesh within 80 mm",
    )
    run.figure("chord_share_closing_x", chords["x"], note="the same along GRASPA's TCP x")

    rows: list[dict] = []
    cpu0 = children_cpu()
    panda = evaluate(prepared, work / "ev_panda", "panda", "base", args.workers, config, args.trials)
    if args.cost:
        evaluate_cost(run, prepared, args, config, children_cpu() - cpu0, panda)
    sim_panda = panda["success"].to_numpy(dtype=bool)
    rows.append(stat_row("panda (as shipped)", stats(real, sim_panda, boot)))
    always = np.ones(len(real), dtype=bool)
    T_tcp = prepared.T_obj_graspa @ _rot(R_HAND_BASE) @ _tz(_panda_tcp_depth() - args.tcp_depth)
    cone = friction_cone_baseline(prepared, T_tcp, 0.080, CONE_FRICTION)
    confidence_report(run, trials, real, panda, cone, args, label)

    # the RG2 at the same TCP poses, closing on the chord the Panda's pads found there
    sim_rg2 = rg2 = None
    if args.rg2:
        tcp = pd.read_csv(prepared.grasps_tcp)
        closed = panda["outcome"].ne("collision") & panda["width"].gt(0.001)
        tcp["width"] = np.where(closed, panda["width"], np.nan)
        tcp.to_csv(prepared.grasps_tcp, index=False, float_format="%.17g")
        rg2 = evaluate(prepared, work / "ev_rg2", "rg2", "tcp", args.workers, config)
        sim_rg2 = rg2["success"].to_numpy(dtype=bool)
    if not args.grid:
        rows.append(stat_row("always success", stats(real, always, boot)))
        rows.append(stat_row(f"friction cone (mu {CONE_FRICTION:g})", stats(real, cone, boot)))
        if sim_rg2 is not None:
            rows.append(stat_row("rg2 at the same TCP poses", stats(real, sim_rg2, boot)))
        print("\nagreement with the real grasped, % [95 % bootstrap interval]:")
        for row in rows:
            print(show(row))
        run.table("agreement", rows, note="simulated or predicted success against real grasped")
        return

    # the grid, through the command (every simulated outcome written for the figures)
    outcomes_path, toml = work / "grid.parquet", work / "calibrated.toml"
    annotator(
        "calibrate",
        work / "ev_panda",
        prepared.real,
        "--objects",
        prepared.objects,
        "--friction",
        args.friction,
        "--force",
        args.force,
        "--severity",
        args.severity,
        "--folds",
        args.folds,
        "--workers",
        args.workers,
        "--write-config",
        toml,
        "--outcomes",
        outcomes_path,
    )
    grid = pd.read_parquet(outcomes_path)
    order = trials[["object_id", "grasp_id"]]
    simulated = {}
    for (mu, force, sev), part in grid.groupby(["friction", "force", "severity"], sort=True):
        part = order.merge(part, on=["object_id", "grasp_id"], how="left")
        simulated[cal.Setting(float(mu), float(force), float(sev))] = part["sim_success"].to_numpy(dtype=bool)
    settings = sorted(simulated, key=lambda s: (s.friction, s.force, s.severity))
    labelled = cal._gripper_settings(AnnotatorConfig(), "panda")
    table = trials[["object_id", "grasp_id"]].assign(real_success=real)
    cv = cal.cross_validate(table, simulated, settings, labelled, args.folds, 0, "balanced", boot)
    fitted = cal.rank(cal.score_settings(real, simulated, settings, labelled, boot), "balanced").iloc[0]
    best = fitted["_setting"]
    rows.append(stat_row("panda, calibrated (CV by object)", cv.pooled))
    rows.append(
        stat_row("panda, fitted on all (optimistic)", fitted["_agreement"], setting=cal.setting_text(best))
    )
    before = cal.Setting(1.0, 70.0, 1.0)
    if before in simulated:
        rows.append(stat_row("panda, before (mu 1, 70 N, x1)", stats(real, simulated[before], boot)))
    rows.append(stat_row("always success", stats(real, always, boot)))
    rows.append(stat_row(f"friction cone (mu {CONE_FRICTION:g})", stats(real, cone, boot)))
    if sim_rg2 is not None:
        rows.append(stat_row("rg2 at the same TCP poses", stats(real, sim_rg2, boot)))
    print("\nagreement with the real grasped, % [95 % bootstrap interval]:")
    for row in rows:
        print(show(row))
    run.table(
        "agreement",
        rows,
        note="simulated or predicted success against real grasped; *_lo/*_hi: 95 % bootstrap",
    )
    for row in rows:
        key = re.sub(r"[^a-z0-9]+", "_", row["predictor"].lower()).strip("_")
        for s_name in ("balanced", "precision"):
            run.figure(
                f"{key}_{s_name}"[:60],
                row[s_name],
                note=f"{row['predictor']}: {s_name}, 95 % CI "
                f"{row[s_name + '_lo']:.3f}..{row[s_name + '_hi']:.3f}",
            )
    print("\n" + cal.format_folds(cv))
    run.table(
        "folds",
        [
            {
                "fold": f.index + 1,
                "held_out": " ".join(f.held_out),
                "n_fit": f.fit.n,
                "setting": cal.setting_text(f.best),
                "fit_balanced": f.fit.balanced,
                "held_n": f.held.n,
                "held_accuracy": f.held.accuracy,
                "held_balanced": f.held.balanced,
                "held_precision": f.held.precision,
            }
            for f in cv.folds
        ],
        note="object-wise cross-validation: the setting chosen on the other objects, scored on the held-out "
        "ones",
    )
    if rg2 is None:
        return
    run.table(
        "outcomes", _outcome_counts(panda, rg2), note="simulated outcomes of the shipped Panda and the RG2"
    )
    run.table("per_object", _per_object(trials, real, sim_panda, cv.predicted, always, cone, sim_rg2, boot))
    run.table(
        "disagreements",
        _disagreements(trials, panda, real),
        note="rows where the shipped Panda's success and real grasped differ",
    )
    run.ratio(
        "rg2_collision_share_vs_panda",
        (rg2["outcome"].eq("collision").mean() + 1e-9) / (panda["outcome"].eq("collision").mean() + 1e-9),
        note="share of collision outcomes, RG2 over the Panda, the same grasps",
    )


def confidence_report(
    run: Run, trials: pd.DataFrame, real: np.ndarray, panda: pd.DataFrame, cone: np.ndarray, args, label: str
) -> None:
    """The label's confidence against the real outcomes: AUC of ``score`` and of ``p_success``
    (isotonic, cross-validated by object), balanced accuracy and precision at the threshold chosen
    on the other objects, precision of the top-scored fifth and Brier score, each with a 95 %
    bootstrap interval; beside trial 0's ``success``, always-success and the friction cone. The
    reliability diagram is written to the work folder."""
    from annotator import confidence as conf
    from annotator.tools.calibrate import agreement, agreement_text

    boot = args.bootstrap
    score = panda["score"].to_numpy(dtype=np.float64)
    objects = trials["object_id"].astype(str).to_numpy()
    p_cv = conf.cross_validated(score, real, objects, args.trials, args.folds)
    calls, thresholds = conf.cross_validated_decisions(score, real, objects, args.folds)
    base_rate = np.full(len(real), real.mean())
    predictors = [
        (f"score (--trials {args.trials})", score, calls, score),
        ("p_success (isotonic, CV by object)", p_cv, calls, p_cv),
        ("success (trial 0)", panda["success"].to_numpy(dtype=float), panda["success"].to_numpy(bool), None),
        ("always success", np.ones(len(real)), np.ones(len(real), dtype=bool), base_rate),
        (f"friction cone (mu {CONE_FRICTION:g})", cone.astype(float), cone, None),
    ]
    table = []
    print(
        f"\nconfidence against the real grasped ({len(real)} trials, {real.mean():.1%} grasped); "
        f"thresholds on score chosen on the other objects: {', '.join(f'{t:g}' for t in thresholds)}"
    )
    for name, ranking, decided, prob in predictors:
        a = conf.bootstrap(conf.auc, real, ranking, boot)
        top = conf.bootstrap(conf.top_fraction_precision, real, ranking, boot)
        b = conf.bootstrap(conf.brier, real, prob if prob is not None else ranking, boot)
        ag = agreement(real, decided, boot)
        row = {"predictor": name, "n": len(real)}
        for key, m in (("auc", a), ("top_fifth_precision", top), ("brier", b)):
            row[key], row[f"{key}_lo"], row[f"{key}_hi"] = m.value, m.low, m.high
        for key in ("balanced", "precision", "recall"):
            row[key] = ag.value(key)
            row[f"{key}_lo"], row[f"{key}_hi"] = ag.interval(key)
        table.append(row)
        calls_text = agreement_text(ag, ("balanced", "precision"))
        print(
            f"{name:>36}: AUC {a.text()}, {calls_text}, top fifth {top.text(percent=True)}, Brier {b.text()}",
            flush=True,
        )
    run.table(
        "confidence",
        table,
        note=f"--trials {args.trials}: ranking (AUC, top fifth), calls at the CV threshold (balanced, "
        "precision), probabilities (Brier; score as a probability, the base rate for always-success)",
    )
    for row, key in zip(table[:2], ("score", "p_success"), strict=True):
        run.figure(f"{key}_auc", row["auc"], note=f"95 % CI {row['auc_lo']:.3f}..{row['auc_hi']:.3f}")
        run.figure(f"{key}_brier", row["brier"], note=f"95 % CI {row['brier_lo']:.3f}..{row['brier_hi']:.3f}")
    run.figure("cv_threshold_balanced", table[1]["balanced"], note="p_success at the CV threshold")
    run.figure("cv_threshold_precision", table[1]["precision"], note="p_success at the CV threshold")
    run.figure("score_top_fifth_precision", table[0]["top_fifth_precision"])
    png = conf.reliability_png(
        [
            ("score as a probability", conf.reliability(real, score)),
            ("p_success (CV by object)", conf.reliability(real, p_cv)),
        ],
        title=f"{label}: the default ranges, --trials {args.trials}",
    )
    (args.work / "reliability_default.png").write_bytes(png)
    print(f"reliability diagram: {args.work / 'reliability_default.png'}", flush=True)


# --- the stages, the fitted execution, a frozen profile ------------------------------------------


def stage_report(run: Run, prepared: Prepared, real: np.ndarray, args, config: Path) -> None:
    """Trial 0 of the Panda's grasps (``--trials 1``) held through each stage against real
    ``grasped``, through ``annotator evaluate --real`` (as a user compares their own trials)."""
    from annotator.agreement import agreement
    from annotator.dataset import held_through
    from annotator.outcome import GATES

    table = pd.read_csv(prepared.grasps_base).merge(pd.read_csv(prepared.real), on=["object_id", "grasp_id"])
    path = args.work / "grasps_real.csv"
    table.to_csv(path, index=False, float_format="%.17g")
    out = args.work / "ev_stages"
    args_ = ["evaluate", path, "--objects", prepared.objects, "--out", out, "--gripper", "panda"]
    args_ += ["--frame", "base", "--resting-grasps", "table", "--workers", args.workers, "--quiet"]
    annotator(*args_, "--overwrite", "--real", "real_success", "--config", config)
    rows = prepared.trials[["object_id", "grasp_id"]].merge(
        pd.read_parquet(out), on=["object_id", "grasp_id"]
    )
    stages = []
    for gate in GATES:
        held = held_through(rows, gate).to_numpy(dtype=bool)
        a = agreement(real, held, args.bootstrap)
        stages.append(stat_row(f"held through the {gate}", a, held=int(held.sum())))
        for name in ("balanced", "precision"):
            run.figure(
                f"stage_{gate}_{name}",
                a.value(name),
                note=f"trial 0 held through the {gate} against real grasped: {name}, 95 % CI "
                f"{a.interval(name)[0]:.3f}..{a.interval(name)[1]:.3f}",
            )
    run.table("stages", stages, note="trial 0 (--trials 1) held through each stage against real grasped")
    counts = rows["outcome"].value_counts()
    run.table(
        "stage_outcomes",
        [{"outcome": o, "n": int(counts.get(o, 0))} for o in OUTCOME_ORDER],
        note="trial 0's outcomes",
    )


# The outcomes in the protocol's order, for tables.
OUTCOME_ORDER = (
    "collision",
    "no_contact",
    "slipped_lift",
    "slipped_motion",
    "slipped_shake",
    "success",
    "error",
)


def probability_figures(
    run: Run,
    prefix: str,
    real: np.ndarray,
    p: np.ndarray,
    called: np.ndarray,
    args,
    base_rate: float,
    what: str,
) -> dict:
    """The figures of a probability of real success and its calls against real outcomes: AUC,
    Brier score (and always answering ``base_rate``, and the difference, paired), each fifth's mean
    p against its real rate (ties share their places), balanced accuracy, precision and recall of
    the calls, with 95 % bootstrap intervals; recorded under ``prefix`` and returned."""
    from annotator import confidence as conf
    from annotator.agreement import agreement, agreement_text

    boot = args.bootstrap
    auc = conf.bootstrap(conf.auc, real, p, boot)
    brier = conf.bootstrap(conf.brier, real, p, boot)
    base = np.full(len(real), base_rate)
    both = np.column_stack([p, base])
    diff = conf.bootstrap(lambda r, q: conf.brier(r, q[:, 0]) - conf.brier(r, q[:, 1]), real, both, boot)
    calls = agreement(real, called, boot)
    bins = conf.fifths(real, p)
    gaps = [b.mean_p - b.real_rate for b in bins]
    print(
        f"{what}: AUC {auc.text()}, Brier {brier.text()} "
        f"(always {base_rate:.3f}: {conf.brier(real, base):.3f}; "
        f"difference {diff.text()}), mean p {np.mean(p):.3f} against {np.mean(real):.3f} real; "
        f"{agreement_text(calls, ('balanced', 'precision', 'recall'))}",
        flush=True,
    )
    for k, b in enumerate(bins):
        print(f"  fifth {k + 1} (p {b.low:.2f}..{b.high:.2f}): mean p {b.mean_p:.3f}, real {b.real_rate:.3f}")
    out = {
        "auc": auc,
        "brier": brier,
        "brier_minus_base": diff,
        "base_brier": conf.brier(real, base),
        "mean_p": float(np.mean(p)),
        "real_rate": float(np.mean(real)),
        "worst_fifth_gap": float(max(abs(g) for g in gaps)),
        "calls": calls,
    }
    for key in ("auc", "brier", "brier_minus_base"):
        m = out[key]
        run.figure(f"{prefix}_{key}", m.value, note=f"{what}; 95 % CI {m.low:.3f}..{m.high:.3f}")
    run.figure(f"{prefix}_base_brier", out["base_brier"], note=f"{what}: always answering {base_rate:.3f}")
    run.figure(
        f"{prefix}_mean_p", out["mean_p"], note=f"{what}: mean p_success (real rate {out['real_rate']:.3f})"
    )
    run.figure(
        f"{prefix}_worst_fifth_gap",
        out["worst_fifth_gap"],
        note=f"{what}: largest |mean p - real rate| of a fifth",
    )
    for name in ("balanced", "precision", "recall"):
        lo, hi = calls.interval(name)
        run.figure(
            f"{prefix}_{name}",
            calls.value(name),
            note=f"{what}: calls at the threshold; 95 % CI {lo:.3f}..{hi:.3f}",
        )
    run.table(
        f"{prefix}_fifths",
        [
            {
                "fifth": k + 1,
                "p_low": b.low,
                "p_high": b.high,
                "n": b.n,
                "mean_p": b.mean_p,
                "real_rate": b.real_rate,
            }
            for k, b in enumerate(bins)
        ],
        note=f"{what}: the trials in five equal shares by p (ties share their places)",
    )
    return out


def _evaluate_rows(
    prepared: Prepared,
    work: Path,
    name: str,
    objects: Sequence[str] | None,
    config: Path,
    k: int,
    workers: int,
) -> pd.DataFrame:
    """``annotator evaluate`` of the Panda's grasps (of ``objects`` only, when given) with
    ``config`` at ``--trials k``; the rows in the trials' order (those evaluated)."""
    table = pd.read_csv(prepared.grasps_base)
    if objects is not None:
        table = table[table["object_id"].isin(list(objects))]
    path = work / f"grasps_{name}.csv"
    table.to_csv(path, index=False, float_format="%.17g")
    out = work / f"ev_{name}"
    args_ = [
        "evaluate",
        path,
        "--objects",
        prepared.objects,
        "--out",
        out,
        "--gripper",
        "panda",
        "--frame",
        "base",
    ]
    annotator(
        *args_,
        "--resting-grasps",
        "table",
        "--workers",
        workers,
        "--quiet",
        "--overwrite",
        "--trials",
        k,
        "--config",
        config,
    )
    return prepared.trials[["object_id", "grasp_id"]].merge(
        pd.read_parquet(out), on=["object_id", "grasp_id"], how="inner"
    )


def fit_report(run: Run, prepared: Prepared, real: np.ndarray, args, config: Path, label: str) -> None:
    """``calibrate --fit-ranges`` on the trials, then its cross-validation simulated for real: each
    fold's profile (fitted on the other objects) written and applied to its own objects' grasps by
    ``annotator evaluate``, their p_success and calls pooled; the profile fitted on every trial is
    written to ``WORK/profile.toml`` for ``--profile``."""
    from annotator import confidence as conf
    from annotator.tools import calibrate as cal
    from annotator.tools import ranges

    source = cal.calibration_grasps(
        prepared.grasps_base, prepared.objects, "panda", "base", "table", None, config
    )
    trials = cal.read_real_trials(prepared.real, source.grasps)
    order = (
        trials[["object_id", "grasp_id"]]
        .merge(prepared.trials[["object_id", "grasp_id"]].reset_index(), on=["object_id", "grasp_id"])[
            "index"
        ]
        .to_numpy()
    )
    t0 = time.perf_counter()
    # the exploration is most of the time: kept in the work folder, keyed by everything it depends on
    key = exploration_key(trials, source.config, args.explore_trials)
    saved = args.work / "exploration.npz"
    exploration = ranges.Exploration.load(saved, key)
    if exploration is None:
        exploration = cal.explore(
            trials,
            source.config,
            prepared.objects,
            args.workers,
            0,
            source.gripper,
            "table",
            args.explore_trials,
        )
        exploration.save(saved, key)
    else:
        print(f"the exploration of an earlier run: {saved}", flush=True)
    result = cal.fit_ranges(
        trials,
        source.config,
        prepared.objects,
        args.workers,
        0,
        gripper=source.gripper,
        resting="table",
        m=args.explore_trials,
        folds=args.folds,
        exploration=exploration,
    )
    print(cal.ranges_text(result, args.bootstrap), flush=True)
    run.figure("fit_seconds", time.perf_counter() - t0, "s", note="exploration and fit, wall time")
    f = result.fit
    e = f.execution.execution
    for i, g in enumerate(ranges.GROUPS):
        own = e.theta[i] == f.exploration.own_index
        run.figure(
            f"fit_{g.name}_level",
            0.0 if own else f.exploration.levels[e.theta[i]],
            note=f"the {g.name} group's scale level (x its units; 0: the run's own ranges kept)",
        )
        run.figure(
            f"fit_{g.name}_identified", int(f.execution.identified[g.name]), note="1: the data identify it"
        )
    run.figure("fit_trials", f.k, note="the profile's --trials")
    run.figure("fit_threshold", f.threshold, note="the profile's p_success threshold")
    run.figure("fit_lapse_fail", e.fail, note="real fails whatever the simulation says")
    run.figure("fit_lapse_hold", e.hold, note="real holds whatever the simulation says")
    run.table(
        "fit_choices",
        [{"gate": f.gate, "perturbed_stage": e.stage, "k": f.k, **f.ranges()}],
        note="the profile fitted on every trial",
    )
    held = result.held_out
    profile = cal.profile_config(source.config, f, result.real, None if held is None else held.p)
    header = (
        f"the execution fitted to {label}: {len(trials)} real trials, "
        f"{args.explore_trials} perturbed trials each\n"
        f"use: annotate --objects DIR --n N --gripper panda --trials {f.k} --config THIS_FILE"
    )
    (args.work / "profile.toml").write_text(cal.config_toml(profile, header, cal.PROFILE_KEEP))
    print(f"the profile fitted on every trial: {args.work / 'profile.toml'}", flush=True)
    if held is None:
        return
    expected = np.full(len(real), np.nan)
    expected[order] = held.p
    probability_figures(
        run,
        "cv_expected",
        real,
        expected,
        np.isin(np.arange(len(real)), order[held.called >= 0.5]),
        args,
        float(real.mean()),
        "p_success cross-validated by object, expected over the scores (the fit's own estimate)",
    )
    # the same cross-validation, simulated: each fold's frozen profile applied to its objects
    p_sim = np.full(len(real), np.nan)
    called = np.zeros(len(real), dtype=bool)
    folds = []
    for i, (objects, fold) in enumerate(held.folds):
        path = args.work / f"profile_fold{i + 1}.toml"
        path.write_text(cal.config_toml(cal.profile_config(source.config, fold), "", cal.PROFILE_KEEP))
        rows = _evaluate_rows(prepared, args.work, f"fold{i + 1}", objects, path, fold.k, args.workers)
        idx = prepared.trials.reset_index().merge(
            rows[["object_id", "grasp_id"]], on=["object_id", "grasp_id"]
        )["index"]
        p_sim[idx.to_numpy()] = rows["p_success"].to_numpy()
        called[idx.to_numpy()] = rows["p_success"].to_numpy() >= fold.threshold - 1e-12
        fe = fold.execution.execution
        folds.append(
            {
                "fold": i + 1,
                "held_out": " ".join(objects),
                "pose": fold.exploration.label(fe.theta[0]),
                "friction": fold.exploration.label(fe.theta[1]),
                "perturbed_stage": fe.stage,
                "gate": fold.gate,
                "k": fold.k,
                "threshold": fold.threshold,
            }
        )
    run.table("cv_folds", folds, note="each fold's profile, fitted on the other objects' trials")
    figures = probability_figures(
        run,
        "cv",
        real,
        p_sim,
        called,
        args,
        float(real.mean()),
        "p_success cross-validated by object, each fold's profile simulated on its own objects",
    )
    png = conf.reliability_png(
        [("p_success, CV by object (simulated)", conf.reliability(real, p_sim))],
        title=f"{label}: the fitted execution, CV by object",
    )
    (args.work / "reliability.png").write_bytes(png)
    print(f"reliability diagram: {args.work / 'reliability.png'}", flush=True)
    del figures
    causes = disagreement_causes(prepared, real, called, result, order)
    run.table("disagreements_by_cause", causes["by_cause"], note=DISAGREEMENT_NOTE)
    run.table("disagreements_by_object", causes["by_object"], note="the same rows, per object")
    for row in causes["by_cause"]:
        print(f"  {row['real']:>8} called {row['called']:>7}: {row['n']:>3} {row['cause']}")


DISAGREEMENT_NOTE = (
    "the trials whose cross-validated call (simulated) disagrees with the real outcome, by what the "
    "exploration says of them at the fitted ranges: trial 0's stage and the share of perturbed "
    "executions that held"
)


def disagreement_causes(prepared: Prepared, real: np.ndarray, called: np.ndarray, result, order: np.ndarray):
    """The rows where the calls and reality disagree, sorted by cause from the exploration at the
    ranges fitted on all trials: what trial 0 reached (a collision at the nominal pose, no contact,
    a slip in the lift, the motion or the shake) and whether some perturbed executions held (the
    execution decides), none did (nothing the ranges cover holds it: the physics) or all did."""
    from annotator.outcome import Stage
    from annotator.tools import ranges

    exp, e = result.exploration, result.fit.execution.execution
    share = np.full(len(real), np.nan)
    stage0 = np.zeros(len(real), dtype=np.int64)
    p = ranges.held_share(exp.ratios(), e.theta, exp.stages >= int(Stage.from_label(e.stage)))
    share[order], stage0[order] = p, exp.stage0
    trial0 = {0: "trial 0 never held (collision or no contact)", 1: "trial 0 slipped in the lift"}
    trial0.update({2: "trial 0 slipped in the motion", 3: "trial 0 slipped in the shake", 4: "trial 0 held"})
    by_cause: dict[tuple, int] = {}
    by_object: dict[tuple, int] = {}
    for i in np.flatnonzero(called != real):
        if share[i] == 0:
            executions = "no perturbed execution held"
        elif share[i] >= 0.95:
            executions = "every perturbed execution held"
        else:
            executions = f"{'most' if share[i] >= 0.5 else 'some'} perturbed executions held"
        key = ("success" if real[i] else "failure", "success" if called[i] else "failure")
        cause = f"{trial0[int(stage0[i])]}; {executions}"
        by_cause[(*key, cause)] = by_cause.get((*key, cause), 0) + 1
        obj = prepared.trials["object_id"].iloc[i]
        by_object[(*key, obj)] = by_object.get((*key, obj), 0) + 1
    return {
        "by_cause": [
            {"real": r, "called": c, "cause": cause, "n": n}
            for (r, c, cause), n in sorted(by_cause.items(), key=lambda kv: (kv[0][0], -kv[1]))
        ],
        "by_object": [
            {"real": r, "called": c, "object": o, "n": n} for (r, c, o), n in sorted(by_object.items())
        ],
    }


def exploration_key(trials: pd.DataFrame, config: AnnotatorConfig, m: int) -> str:
    """What an exploration depends on, as a digest: the trials' grasps (poses, rest orientations),
    the configuration, the perturbed trials per grasp, the code's commit and the label libraries."""
    import hashlib
    import json

    from annotator.versions import library_versions
    from bench.harness import git_state

    grasps = trials.drop(columns=["real_success"], errors="ignore").to_csv(index=False, float_format="%.17g")
    text = json.dumps(
        [grasps, config.to_dict(trials=m + 1), m, git_state().commit, library_versions()], sort_keys=True
    )
    return hashlib.sha256(text.encode()).hexdigest()


def profile_report(run: Run, prepared: Prepared, real: np.ndarray, args, label: str) -> None:
    """A frozen profile applied to the trials, as a user applies a calibration to new grasps: its
    configuration and ``--trials``, its p_success mapping and its threshold; nothing fitted."""
    from annotator import confidence as conf

    profile = AnnotatorConfig.from_toml(args.profile)
    if profile.confidence.method == "none":
        sys.exit(f"bench.real_trials: {args.profile} has no [confidence] mapping")
    k = profile.confidence.trials
    rows = _evaluate_rows(prepared, args.work, "profile", None, args.profile, k, args.workers)
    if len(rows) != len(real):
        sys.exit(f"bench.real_trials: evaluate gave {len(rows)} rows for {len(real)} trials")
    p = rows["p_success"].to_numpy(dtype=np.float64)
    called = p >= profile.confidence.threshold - 1e-12
    base_rate = profile.confidence.base_rate or float(real.mean())
    run.figure("profile_trials", k, note=f"--trials of the profile {args.profile.name}")
    run.figure("profile_threshold", profile.confidence.threshold, note="its p_success threshold")
    probability_figures(
        run,
        "profile",
        real,
        p,
        called,
        args,
        base_rate,
        f"the frozen profile {args.profile.name} applied (nothing refitted)",
    )
    png = conf.reliability_png(
        [("p_success, frozen profile", conf.reliability(real, p))],
        title=f"{label}: profile {args.profile.name}, frozen",
    )
    (args.work / "reliability_profile.png").write_bytes(png)
    print(f"reliability diagram: {args.work / 'reliability_profile.png'}", flush=True)


def _outcome_counts(panda: pd.DataFrame, rg2: pd.DataFrame) -> list[dict]:
    out = []
    for outcome in ("success", "collision", "no_contact", "slipped_lift", "slipped_shake", "error"):
        out.append(
            {
                "outcome": outcome,
                "panda": int(panda["outcome"].eq(outcome).sum()),
                "rg2": int(rg2["outcome"].eq(outcome).sum()),
            }
        )
    return out


def _per_object(trials, real, sim, cv, always, cone, rg2, boot) -> list[dict]:
    out = []
    for oid, idx in trials.groupby("object_id").indices.items():
        a = stats(real[idx], sim[idx], boot)
        out.append(
            {
                "object": oid,
                "n": len(idx),
                "real_grasped": float(real[idx].mean()),
                "panda_success": float(sim[idx].mean()),
                "panda_accuracy": a.accuracy,
                "panda_accuracy_lo": a.accuracy_ci[0],
                "panda_accuracy_hi": a.accuracy_ci[1],
                "cv_accuracy": float((cv[idx] == real[idx]).mean()),
                "always_accuracy": float((always[idx] == real[idx]).mean()),
                "cone_accuracy": float((cone[idx] == real[idx]).mean()),
                "rg2_accuracy": float((rg2[idx] == real[idx]).mean()),
            }
        )
    return out


def _disagreements(trials: pd.DataFrame, panda: pd.DataFrame, real: np.ndarray) -> list[dict]:
    sim = panda["success"].to_numpy(dtype=bool)
    out = []
    for k in np.flatnonzero(sim != real):
        t, p = trials.iloc[k], panda.iloc[k]
        out.append(
            {
                "object": t["object_id"],
                "grasp_id": int(t["grasp_id"]),
                "planner": t["planner"],
                "layout": int(t["layout"]),
                "grasp": t["grasp_name"],
                "real_grasped": int(t["grasped"]),
                "real_stability": float(t["stability"]),
                "sim_outcome": p["outcome"],
                "sim_width_mm": 1000 * float(p["width"]),
                "settle_drift_mm": 1000 * float(p["settle_drift"]),
            }
        )
    return out


if __name__ == "__main__":
    main()
