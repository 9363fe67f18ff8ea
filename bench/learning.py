"""A learner of the labels in the clutter-removal loop, on objects it never saw: the labels oracle,
the learned policy and vision-random on the same rounds, piles and packed, grasp success and
percent cleared with 95 % intervals.

    python -m bench.learning --train-objects DIR --test-objects DIR [--scenes 100 --packed-scenes 40]
    python -m bench.learning --train-objects DIR --train-labels L1 L2 --test-objects DIR --rounds 5

1. Labels: ``annotate --objects TRAIN --scenes S --per-scene 5 --n 120 --views K`` (piles) and the
   same with ``--arrangement packed`` (``--packed-scenes``), as subprocesses; their CPU time (the
   command and its workers) is recorded. Or ``--train-labels`` folders made before (of the same
   ``--train-objects``).
2. Training: ``annotator.learn`` on every labelled grasp of those runs and on the learned policy's
   own candidates in their scenes tried in simulation (``annotator.learn.candidates``; features of
   the observed cloud, a logistic regression), its CPU time, and the held-out AUC on the last fifth
   of the scenes (a model trained on the other four fifths), on their labels and on their vision
   candidates apart.
3. Clutter removal on ``--test-objects`` (other objects): rounds 0..R-1 of piles of 5 and of packed
   scenes of 5, each policy on the same rounds (round r is scene r of ``annotate --scenes`` with the
   seed), the vision policies seeing ``--views`` depth views; the labels oracle (the slowest: it
   labels the pile anew at every attempt) on its first ``--oracle-rounds`` only, if given.

``--rounds 0`` trains only (``--keep`` keeps the model); ``--model`` clears piles with a model
trained so (the training is then neither repeated nor recorded), e.g. the policies in two runs
side by side on a busy machine.

Printed against the targets: the learned policy's success at least vision-random's + 10 points and
its percent cleared above vision-random's, the 95 % intervals apart, over at least 100 attempts
each; the labels oracle an upper bound, the learned policy within 20 points of it.
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

from annotator.config import AnnotatorConfig
from bench.arguments import Parser, count, existing_file, existing_folder, seed, writable_folder
from bench.harness import Run

ROOT = Path(__file__).resolve().parents[1]
POLICIES = ("labels", "learned", "vision-random")
VIEWS_CONFIG = "[kinect]\nviews_color_scale = 0.1\n"  # colour is not used: render it small


def _children_cpu() -> float:
    import resource

    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def make_labels(args, out: Path, arrangement: str, scenes: int) -> tuple[Path, float]:
    """``annotate --scenes`` on the training objects as a subprocess: (labels folder, CPU s)."""
    exe = shutil.which("annotate", path=str(Path(sys.executable).parent)) or shutil.which("annotate")
    if exe is None:
        raise SystemExit("the annotate command is not installed (pip install -e .)")
    config = out.parent / "views.toml"
    config.write_text(VIEWS_CONFIG)
    cmd = [
        exe, "--objects", str(args.train_objects), "--scenes", str(scenes), "--per-scene", "5",
        "--arrangement", arrangement, "--n", str(args.n), "--views", str(args.views), "--seed",
        str(args.train_seed), "--config", str(config), "--out", str(out), "--quiet",
    ]  # fmt: skip
    if args.workers:
        cmd += ["--workers", str(args.workers)]
    before = _children_cpu()
    subprocess.run(cmd, check=True)
    return out, _children_cpu() - before


def train_model(labels: list[Path], objects: Path, out: Path, record: Run) -> Path:
    from annotator.learn.data import load_training_set
    from annotator.learn.model import auc, train

    c0, t0 = time.process_time(), time.perf_counter()
    data = load_training_set(labels, objects)
    read_cpu = time.process_time() - c0
    scenes = np.unique(data.scene_id)
    held = np.isin(data.scene_id, scenes[len(scenes) - len(scenes) // 5 :])
    c1 = time.process_time()
    model = train(data.X, data.y)
    fit_cpu = time.process_time() - c1
    model.save(out)
    held_auc = vision_auc = float("nan")
    if held.any() and (~held).any():
        p = train(data.X[~held], data.y[~held]).probability(data.X)
        held_auc = auc(p[held & ~data.vision], data.y[held & ~data.vision])
        vision_auc = auc(p[held & data.vision], data.y[held & data.vision])
    vision = int(data.vision.sum())
    print(
        f"training: {len(data.y)} grasps of {len(scenes)} scenes ({vision} vision candidates, "
        f"{int(data.y[data.vision].sum())} held; {len(data.y) - vision} labels, "
        f"{int(data.y[~data.vision].sum())} held); features and simulation {read_cpu:.0f} CPU-s, fit "
        f"{fit_cpu:.0f} CPU-s ({time.perf_counter() - t0:.0f} s); held-out AUC {held_auc:.3f} on labels, "
        f"{vision_auc:.3f} on vision candidates"
    )
    record.figure("training_grasps", len(data.y), note=f"{len(scenes)} scenes, {int(data.y.sum())} held")
    record.figure(
        "training_vision_candidates", vision, note=f"{int(data.y[data.vision].sum())} held in simulation"
    )
    record.figure(
        "training_cpu_s", read_cpu + fit_cpu, "CPU-s", note="features, candidates tried in simulation, fit"
    )
    record.figure(
        "held_out_auc", held_auc, note="a model of four fifths of the scenes on the last fifth's labels"
    )
    record.figure(
        "held_out_vision_auc", vision_auc, note="the same model on the last fifth's vision candidates"
    )
    return out


def clutter(args, model: Path, record: Run) -> list[dict]:
    from annotator.objects import default_cache_dir, discover_objects
    from annotator.pipeline.in_memory import ExecutionOptions
    from annotator.policies.clutter import ClutterSetup, wilson
    from annotator.tools.clutter_runs import run_clutter_removal

    config = AnnotatorConfig()
    sources = tuple(discover_objects(args.test_objects, config.objects))
    rows = []
    for arrangement in args.arrangements:
        for policy in args.policies:
            t0 = time.perf_counter()
            job = ClutterSetup(
                sources,
                5,
                args.seed,
                policy,
                config,
                cache_dir=str(default_cache_dir()),
                policy_args=(("model", str(model)),) if policy == "learned" else (),
                views=args.views,
                arrangement=arrangement,
            )
            rounds = args.oracle_rounds if policy == "labels" and args.oracle_rounds else args.rounds
            summary = run_clutter_removal(job, rounds, ExecutionOptions(args.workers or os.cpu_count() or 1))
            lo, hi = wilson(summary.successes, summary.attempts)
            clo, chi = wilson(summary.successes, summary.objects)
            for line in summary.lines(f"{policy} ({arrangement})"):
                print(line)
            seconds = time.perf_counter() - t0
            print(f"  {seconds:.0f} s")
            if args.keep is not None:  # rounds.csv and grasps.csv, as clutter-removal --out writes them
                cell = args.keep / f"clutter_{arrangement}_{policy.replace('-', '_')}"
                cell.mkdir(parents=True, exist_ok=True)
                rounds_table, grasps = summary.tables()
                rounds_table.to_csv(cell / "rounds.csv", index=False)
                grasps.to_csv(cell / "grasps.csv", index=False)
            rows.append(
                {
                    "arrangement": arrangement,
                    "policy": policy,
                    "rounds": len(summary.rounds),
                    "objects": summary.objects,
                    "attempts": summary.attempts,
                    "successes": summary.successes,
                    "success_rate": summary.success_rate,
                    "success_lo": lo,
                    "success_hi": hi,
                    "cleared": summary.percent_cleared,
                    "cleared_lo": clo,
                    "cleared_hi": chi,
                    "rounds_cleared": sum(r.ended == "cleared" for r in summary.rounds),
                    "ended_no_grasp": sum(r.ended == "no grasp proposed" for r in summary.rounds),
                    "seconds": round(seconds, 1),
                }
            )
            key = f"{arrangement}_{policy.replace('-', '_')}"
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
        "clutter_removal",
        rows,
        note=f"{args.rounds} rounds of 5 objects per row (the labels oracle's: "
        f"{args.oracle_rounds or args.rounds}), seed {args.seed}, {args.views} view(s)",
    )
    return rows


def targets(rows: list[dict]) -> list[str]:
    """The targets (module docstring), one line each per arrangement."""
    out = []
    for arrangement in sorted({r["arrangement"] for r in rows}):
        by = {r["policy"]: r for r in rows if r["arrangement"] == arrangement}
        learned, rand, oracle = by.get("learned"), by.get("vision-random"), by.get("labels")
        if learned and rand:
            gain = 100 * (learned["success_rate"] - rand["success_rate"])
            apart = learned["success_lo"] > rand["success_hi"]
            enough = min(learned["attempts"], rand["attempts"]) >= 100
            met = gain >= 10 and learned["cleared"] > rand["cleared"] and apart and enough
            out.append(
                f"{arrangement}: learned vs vision-random: {gain:+.1f} points of success, cleared "
                f"{100 * learned['cleared']:.1f} vs {100 * rand['cleared']:.1f} %, intervals "
                f"{'apart' if apart else 'overlap'}, {min(learned['attempts'], rand['attempts'])} attempts "
                f"(>= 100 needed): target {'met' if met else 'NOT met'}"
            )
        if learned and oracle:
            gap = 100 * (oracle["success_rate"] - learned["success_rate"])
            out.append(
                f"{arrangement}: labels oracle {100 * oracle['success_rate']:.1f} %, learned "
                f"{gap:.1f} points below it: within 20 {'met' if gap <= 20 else 'NOT met'}"
            )
    return out


def parser() -> Parser:
    parser = Parser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--train-objects",
        type=existing_folder,
        required=True,
        help="objects whose scenes are labelled to train on",
    )
    parser.add_argument(
        "--train-labels",
        type=existing_folder,
        nargs="+",
        help="annotate --scenes --views runs of them made already",
    )
    parser.add_argument(
        "--test-objects", type=existing_folder, required=True, help="other objects: the piles to clear"
    )
    parser.add_argument(
        "--scenes", type=count(1, 1_000_000), default=100, help="training pile scenes (with --train-objects)"
    )
    parser.add_argument(
        "--packed-scenes", type=count(0, 1_000_000), default=40, help="training packed scenes (0: none)"
    )
    parser.add_argument("--n", type=count(1, 1_000_000), default=120, help="grasps per training scene")
    parser.add_argument("--train-seed", type=seed, default=1000, help="the training scenes' seed")
    parser.add_argument(
        "--views", type=count(1, 100), default=3, help="depth views of training scenes and policies"
    )
    parser.add_argument(
        "--rounds",
        type=count(0, 100_000),
        default=40,
        help="clutter rounds per policy and arrangement (0: train only)",
    )
    parser.add_argument(
        "--oracle-rounds",
        type=count(0, 100_000),
        default=None,
        help="the labels oracle's rounds (its first ones; default --rounds)",
    )
    parser.add_argument("--arrangements", nargs="+", default=["pile", "packed"], choices=["pile", "packed"])
    parser.add_argument("--policies", nargs="+", default=list(POLICIES), choices=list(POLICIES))
    parser.add_argument("--seed", type=seed, default=0, help="the clutter rounds' seed")
    parser.add_argument("--workers", type=count(1, 1024), default=None)
    parser.add_argument(
        "--keep",
        type=writable_folder,
        default=None,
        help="keep the labels, the model and each policy's rounds.csv and grasps.csv here",
    )
    parser.add_argument(
        "--model",
        type=existing_file,
        default=None,
        help="a model trained already (--keep of a --rounds 0 run): no training",
    )
    return parser


def main() -> None:
    ap = parser()
    args = ap.parse_args()
    if args.model is not None:
        from annotator.learn.model import load_model

        try:
            load_model(str(args.model))
        except ValueError as exc:
            ap.error(f"--model: {exc}")
    recorded = {k: str(v) for k, v in vars(args).items()}
    with Run("learning", config=recorded) as record, tempfile.TemporaryDirectory() as tmp:
        work = args.keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        trained = args.model is not None or "learned" not in args.policies  # nothing to train
        if trained:
            labels = []
        elif args.train_labels:
            labels = list(args.train_labels)
        else:
            labels, cpu = [], 0.0
            for arrangement, scenes in (("pile", args.scenes), ("packed", args.packed_scenes)):
                if scenes > 0:
                    folder, seconds = make_labels(args, work / f"labels_{arrangement}", arrangement, scenes)
                    labels.append(folder)
                    cpu += seconds
            record.figure("labels_cpu_s", cpu, "CPU-s", note="annotate --scenes and its workers, every run")
        if trained:
            model = args.model
        else:
            model = train_model(labels, args.train_objects, work / "model.npz", record)
        if args.rounds <= 0:
            return
        rows = clutter(args, model, record)
        for line in targets(rows):
            print(line)


if __name__ == "__main__":
    main()
