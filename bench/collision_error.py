"""Collision error of each object before and after refinement: the distance between the simulated
collision shape and the mesh surface (annotator/objects/fidelity.py), mean and max in mm.

    python bench/collision_error.py                 # the sample objects
    python bench/collision_error.py --objects DIR

"before": what the annotator simulated until issue 9, CoACD once at threshold 0.05 with its
default preprocessing ("auto"), or the hull of a convex object; "after": what load_object gives
now (cleaned mesh, thresholds refined until within the limits). Decompositions are cached in
$RG2_CACHE_DIR (the "after" ones) or recomputed (the "before" ones, a few seconds to a minute each).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import trimesh

from annotator.config import ObjectConfig
from annotator.objects import ObjectError, discover_objects, load_object
from annotator.objects.fidelity import collision_error

ROOT = Path(__file__).resolve().parents[1]


def before(model, config: ObjectConfig):
    """The old collision geometry: hull, or CoACD at 0.05 with preprocess "auto", seed 0."""
    if len(model.parts) == 1:
        return model.parts, 0.0
    import coacd

    coacd.set_log_level("error")
    t0 = time.perf_counter()
    result = coacd.run_coacd(
        coacd.Mesh(np.asarray(model.mesh.vertices), np.asarray(model.mesh.faces)), threshold=0.05, seed=0
    )
    parts = [trimesh.Trimesh(v, f).convex_hull for v, f in result]
    return [p for p in parts if p.volume > 0], time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--objects", type=Path, default=ROOT / "objects")
    args = ap.parse_args()
    config = ObjectConfig()
    print(
        f"limits: mean <= {config.collision_mean_limit * 1e3:g} mm, "
        f"max <= {config.collision_max_limit * 1e3:g} mm"
    )
    head = f"{'object':<24} {'before: parts mean max':>24} {'after: parts thr mean max':>30}  within"
    print(head + "\n" + "-" * len(head))
    for source in discover_objects(args.objects, config):
        try:
            model = load_object(source, config)
        except ObjectError as exc:
            print(f"{source.object_id:<24} failed: {exc}")
            continue
        old_parts, _ = before(model, config)
        old = collision_error(model.mesh, old_parts, config.collision_error_samples)
        new = model.collision_error
        threshold = "hull" if model.collision_method == "hull" else f"{model.collision_threshold:g}"
        print(
            f"{source.object_id:<24} {len(old_parts):>9} {old.mean * 1e3:6.2f} {old.max * 1e3:6.2f}"
            f" {len(model.parts):>11} {threshold:>5} {new.mean * 1e3:6.2f} {new.max * 1e3:6.2f}"
            f"  {'yes' if not model.approximate else 'APPROXIMATE'}"
        )


if __name__ == "__main__":
    main()
