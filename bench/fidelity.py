"""Label the same candidates with the default and the thorough protocol; print their agreement.

    python bench/fidelity.py                    # >= 1,000 candidates over the sample objects
    python bench/fidelity.py --per-object 20    # a quick look

The thorough protocol (AnnotatorConfig.thorough): time step 1/1000 s, twice the solver
iterations, a shake three times as long with 1.5x the amplitudes. Candidates rejected by the
kinematic collision check are identical under both protocols (no physics), so agreement is printed
over all candidates and over the physically simulated ones.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import joblib
import numpy as np
import pandas as pd

from annotator.config import AnnotatorConfig
from annotator.objects import ObjectError, discover_objects, load_object
from annotator.pipeline.plan import CHUNK_SIZE
from annotator.pipeline.worker import GivenGrasps, Span, SpanTask, label_span, max_width, object_candidates

ROOT = Path(__file__).resolve().parents[1]


def label(chunks: list[Span], config: AnnotatorConfig, seed: int, workers: int) -> pd.DataFrame:
    tasks = (SpanTask(c, config, seed, c.size) for c in chunks)
    out = joblib.Parallel(n_jobs=workers)(joblib.delayed(label_span)(t) for t in tasks)
    return pd.concat([r.rows for r in out], ignore_index=True).sort_values(["object_id", "grasp_id"])


def chunk(source, start: int, T_obj_tcp: np.ndarray, width: np.ndarray) -> Span:
    """Candidates ``start..`` of ``source`` given as poses (k, 4, 4) and chords (k,)."""
    return Span(source.object_id, source, None, start, start + len(width), GivenGrasps(T_obj_tcp, width))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--objects", type=Path, default=ROOT / "objects")
    ap.add_argument("--per-object", type=int, default=110, help="candidates per object (10 objects)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    args = ap.parse_args()

    default = AnnotatorConfig()
    thorough = AnnotatorConfig.thorough(default)
    stroke = max_width(default)
    chunks = []
    for source in discover_objects(args.objects):
        try:
            model = load_object(source, default.objects)
        except ObjectError as exc:
            print(f"skip {source.object_id}: {exc}")
            continue
        cands = object_candidates(model, args.per_object, args.seed, default, stroke)
        for s in range(0, args.per_object, CHUNK_SIZE):
            e = min(args.per_object, s + CHUNK_SIZE)
            chunks.append(chunk(source, s, cands.T_obj_tcp[s:e], cands.width_expected[s:e]))
    n = sum(c.size for c in chunks)
    print(f"{n} candidates on {len({c.object_id for c in chunks})} objects, seed {args.seed}")

    t0 = time.perf_counter()
    a = label(chunks, default, args.seed, args.workers)
    t1 = time.perf_counter()
    simulated = a["outcome"] != "collision"
    # collisions are decided kinematically, identically under both protocols: only simulate the rest
    sim_chunks = []
    for c in chunks:
        rows = a[(a.object_id == c.object_id) & a.grasp_id.between(c.start, c.stop - 1)]
        keep = (rows["outcome"] != "collision").to_numpy()
        g = c.given
        for k in np.flatnonzero(keep):
            sim_chunks.append(chunk(c.source, c.start + k, g.T_obj_tcp[k : k + 1], g.width[k : k + 1]))
    b_sim = label(sim_chunks, thorough, args.seed, args.workers)
    t2 = time.perf_counter()
    b = a.copy()
    b = b.set_index(["object_id", "grasp_id"])
    b.loc[b_sim.set_index(["object_id", "grasp_id"]).index, ["outcome", "success"]] = b_sim.set_index(
        ["object_id", "grasp_id"]
    )[["outcome", "success"]]
    b = b.reset_index()

    print(f"default protocol: {t1 - t0:.0f} s, mean {a.sim_steps.mean():.0f} steps/candidate")
    print(f"thorough protocol: {t2 - t1:.0f} s on the {int(simulated.sum())} simulated candidates")
    cm = pd.crosstab(a["success"].rename("default"), b["success"].rename("thorough"), margins=True)
    print("\nsuccess confusion matrix (rows: default, columns: thorough)\n" + cm.to_string())
    agree_all = float((a["success"].to_numpy() == b["success"].to_numpy()).mean())
    sim = simulated.to_numpy()
    agree_sim = float((a["success"].to_numpy()[sim] == b["success"].to_numpy()[sim]).mean())
    print(
        f"\nagreement on success: {agree_all:.1%} of all {n} candidates, "
        f"{agree_sim:.1%} of the {int(sim.sum())} simulated ones"
    )
    oc = pd.crosstab(a["outcome"].rename("default"), b["outcome"].rename("thorough"))
    print("\noutcome confusion (rows: default, columns: thorough)\n" + oc.to_string())
    per = pd.DataFrame(
        {
            "default": a.groupby("object_id")["success"].mean(),
            "thorough": b.groupby("object_id")["success"].mean(),
        }
    )
    print("\nsuccess rate per object\n" + per.to_string(float_format=lambda x: f"{x:.1%}"))


if __name__ == "__main__":
    main()
