"""The light-object step in a scene: the target's substeps against the lightest object's, per trial.

    python -m bench.experiments.scene_substeps [--scenes 16] [--n 60] [--per-scene 5] [--objects objects/]

A scene's trials share one world, so one step serves every object in it. An object under
``[physics] light_object_mass`` needs a finer step when it is *squeezed*
(docs/decisions/0003-light-objects.md); in a scene it may also only rest beside the target. Pile
scenes of the sample objects (the 27 g ring and the 38 g plate are light) are labelled twice with
the same candidates: ``[scenes] substeps = "target"`` (the target's step) and ``"lightest"`` (the
lightest kept object's). On the rows whose target is heavy in scenes holding a light object, the
two differ only by the step; their agreement is compared with a control, heavy targets in scenes
without a light object labelled at 1/240 s and at 1/480 s, where the finer step changes nothing
but the step either. Reported: success agreement, widths beyond 0.2 mm, neighbours disturbed, and
simulated steps per row for each rule.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
import pandas as pd

from annotator.config import AnnotatorConfig
from annotator.objects import discover_objects, load_object
from annotator.scenes import SceneBuilder, SceneSpec
from annotator.scenes.labels import SceneTrials, label_scene
from bench.arguments import N_MAX, Parser, count, existing_folder
from bench.harness import Run

WIDTH_TOLERANCE = 0.0002  # m, as bench/experiments/light_threshold.py compares widths


def with_scenes(config: AnnotatorConfig, **changes) -> AnnotatorConfig:
    return dataclasses.replace(config, scenes=dataclasses.replace(config.scenes, **changes))


def with_step(config: AnnotatorConfig, divisor: int) -> AnnotatorConfig:
    physics = dataclasses.replace(config.physics, time_step=config.physics.time_step / divisor)
    return dataclasses.replace(config, physics=physics)


def label(record, models, config, n: int) -> pd.DataFrame:
    with SceneTrials(record, models, config) as trials:
        candidates = trials.candidates(n, seed=0)
        return label_scene(trials, candidates, 0, n, seed=0)


def agreement(a: pd.DataFrame, b: pd.DataFrame) -> dict[str, float]:
    """Rows compared grasp for grasp (the same candidates): success agreement, widths apart."""
    simulated = (a["outcome"] != "collision") | (b["outcome"] != "collision")
    both_held = a["success"] & b["success"]
    return {
        "rows": int(len(a)),
        "simulated": int(simulated.sum()),
        "success_agreement": float((a["success"] == b["success"]).mean()) if len(a) else float("nan"),
        "success_flips": int((a["success"] != b["success"]).sum()),
        "widths_beyond_0.2mm": int((np.abs(a["width"] - b["width"])[both_held] > WIDTH_TOLERANCE).sum()),
    }


def parser() -> Parser:
    ap = Parser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=count(1, 1_000_000), default=16)
    ap.add_argument("--n", type=count(1, N_MAX), default=60, help="grasps per scene")
    ap.add_argument("--per-scene", type=count(1, 253), default=5)
    ap.add_argument(
        "--objects", type=existing_folder, default=Path(__file__).resolve().parents[2] / "objects"
    )
    return ap


def main() -> None:
    args = parser().parse_args()
    config = AnnotatorConfig()
    light = config.physics.light_object_mass
    models = {s.object_id: load_object(s, config.objects) for s in discover_objects(args.objects)}
    builder = SceneBuilder(models, scenes=config.scenes, physics=config.physics, cell=config.cell)
    pairs = {"rule": ([], []), "control": ([], [])}
    steps = {"target": 0, "lightest": 0}
    rows = {"target": 0, "lightest": 0}
    per_scene = []
    with Run("scene_substeps", config=vars(args), annotator=config) as record:
        for scene_id in range(args.scenes):
            t0 = time.perf_counter()
            spec = SceneSpec(scene_id, 0, "pile", args.per_scene, args.per_scene)
            scene = builder.build(spec)
            kept = {i.instance_id: models[i.object_id].mass for i in scene.kept}
            if not kept:
                continue
            has_light = min(kept.values()) < light
            target = label(scene, models, with_scenes(config, substeps="target"), args.n)
            heavy = target["object_mass"] >= light
            if has_light:
                lightest = label(scene, models, with_scenes(config, substeps="lightest"), args.n)
                pairs["rule"][0].append(target[heavy])
                pairs["rule"][1].append(lightest[heavy])
                for name, df in (("target", target), ("lightest", lightest)):
                    steps[name] += int(df["sim_steps"].sum())
                    rows[name] += len(df)
            else:
                fine = label(scene, models, with_step(config, 2), args.n)
                pairs["control"][0].append(target[heavy])
                pairs["control"][1].append(fine[heavy])
            per_scene.append(
                {
                    "scene_id": scene_id,
                    "objects": " ".join(sorted(models_of(scene))),
                    "light_object": bool(has_light),
                    "successes": int(target["success"].sum()),
                    "seconds": round(time.perf_counter() - t0, 1),
                }
            )
            print(per_scene[-1], flush=True)
        results = {}
        for name, (a, b) in pairs.items():
            if a:
                results[name] = agreement(pd.concat(a, ignore_index=True), pd.concat(b, ignore_index=True))
                print(name, results[name])
        record.table("scenes", per_scene)
        if "rule" in results:
            r = results["rule"]
            record.figure(
                "rule_success_agreement",
                r["success_agreement"],
                note=f"heavy targets beside a light object: target's step vs lightest's ({r['rows']} rows)",
            )
            record.figure("rule_widths_beyond_0_2mm", r["widths_beyond_0.2mm"], note="rows held by both")
            ratio = (steps["lightest"] / rows["lightest"]) / (steps["target"] / rows["target"])
            record.ratio("lightest_vs_target_steps", ratio, note="simulated steps per row in those scenes")
        if "control" in results:
            c = results["control"]
            record.figure(
                "control_success_agreement",
                c["success_agreement"],
                note=f"heavy targets, scenes without a light object, 1/240 s vs 1/480 s ({c['rows']} rows)",
            )
            record.figure("control_widths_beyond_0_2mm", c["widths_beyond_0.2mm"], note="rows held by both")
        record.table("agreement", [{"pair": k, **v} for k, v in results.items()])


def models_of(scene) -> list[str]:
    return [i.object_id for i in scene.kept]


if __name__ == "__main__":
    main()
