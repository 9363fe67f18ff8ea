"""Label the same candidates with the default and the thorough protocol; print their agreement.

    python bench/fidelity.py                    # >= 1,000 candidates over the sample objects
    python bench/fidelity.py --per-object 20    # a quick look
    python bench/fidelity.py --variant "it100:physics.solver_iterations=100"   # a changed model

The thorough protocol (AnnotatorConfig.thorough): time step 1/1000 s, 300 solver iterations, the
whole RG2 linkage simulated, a shake three times as long with 1.5x the amplitudes. Candidates rejected by the
kinematic collision check are identical under both protocols (no physics), so agreement is printed
over all candidates and over the physically simulated ones.

``--variant`` (repeatable) labels the same candidates with a changed configuration (see
``bench/_variants.py``; changes are applied to the current default) and prints its agreement with
the default on ``success`` and ``outcome``, its widths against the default's where both succeed,
and its agreement with the thorough reference (always the default's thorough protocol, so a variant
cannot move it). ``--baseline`` replaces the default in these comparisons, e.g. by the previous
default after a change of the defaults.
The default's and the reference's labels are cached under ``--cache`` keyed by configuration, seed,
candidates per object and the objects' files (a cache made by other simulation code is reported);
``--fresh`` recomputes the default; the reference (outcomes, widths and closed poses) is keyed by
the rows it simulates, so a new default that rejects the same candidates reuses it.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import time
from pathlib import Path

import joblib
import numpy as np
import pandas as pd
from _variants import parse_variant

from annotator.config import AnnotatorConfig
from annotator.objects import ObjectError, default_cache_dir, discover_objects, load_object
from annotator.pipeline.plan import CHUNK_SIZE
from annotator.pipeline.worker import GivenGrasps, Span, SpanTask, label_span, max_width, object_candidates

ROOT = Path(__file__).resolve().parents[1]
KEY = ["object_id", "grasp_id"]
# Sections the floating labels of this script never read: a change to them keeps the cached labels.
CELL_ONLY = ("cell", "kinect")


def label(chunks: list[Span], config: AnnotatorConfig, seed: int, workers: int) -> pd.DataFrame:
    tasks = (SpanTask(c, config, seed, c.size) for c in chunks)
    out = joblib.Parallel(n_jobs=workers)(joblib.delayed(label_span)(t) for t in tasks)
    return pd.concat([r.rows for r in out], ignore_index=True).sort_values(KEY, ignore_index=True)


def chunk(source, start: int, T_obj_tcp: np.ndarray, width: np.ndarray) -> Span:
    """Candidates ``start..`` of ``source`` given as poses (k, 4, 4) and chords (k,)."""
    return Span(source.object_id, source, None, start, start + len(width), GivenGrasps(T_obj_tcp, width))


# Fields added after labels were cached, at the value every run had before they existed (PyBullet's
# own): at that value they are left out of the key, so those labels stay valid.
IMPLICIT_BEFORE = {("physics", "contact_breaking_threshold"): 0.02}


def settings(config: AnnotatorConfig) -> dict:
    """The configuration's sections that floating labels read (the cache's key)."""
    out = {k: v for k, v in config.to_dict().items() if k not in CELL_ONLY}
    for (section, name), value in IMPLICIT_BEFORE.items():
        if out[section][name] == value:
            del out[section][name]
    return out


def code_digest() -> str:
    """Digest of the simulation code and robot model: cached labels of other code are not reused."""
    h = hashlib.sha256()
    for path in sorted((ROOT / "annotator").rglob("*.py")) + [ROOT / "assets" / "rg2" / "rg2.urdf"]:
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


class LabelCache:
    """Labels on disk keyed by (name, configuration, key); the key leaves the code out (the
    reference takes half an hour), so each file records the simulation code it was made by."""

    def __init__(self, folder: Path | None) -> None:
        self.folder = folder

    def _path(self, name: str, config: AnnotatorConfig, key: dict) -> Path | None:
        if self.folder is None:
            return None
        digest = hashlib.sha256(json.dumps([settings(config), key], sort_keys=True).encode()).hexdigest()
        return self.folder / f"{name}-{digest[:20]}.parquet"

    def get(self, name: str, config: AnnotatorConfig, key: dict) -> pd.DataFrame | None:
        path = self._path(name, config, key)
        if path is None or not path.is_file():
            return None
        stamp = path.with_suffix(".code")
        if not stamp.is_file() or stamp.read_text() != code_digest():
            print(f"note: the cached {name} labels were made by other simulation code")
        return pd.read_parquet(path)

    def put(self, name: str, config: AnnotatorConfig, key: dict, df: pd.DataFrame) -> None:
        path = self._path(name, config, key)
        if path is None:
            return
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        df.to_parquet(tmp)
        os.replace(tmp, path)
        path.with_suffix(".code").write_text(code_digest())


def identical(a: pd.DataFrame, b: pd.DataFrame) -> bool:
    """The same rows with bit-identical outcomes, poses and widths."""
    cols = [*KEY, "outcome", "success", "width", "x", "y", "z", "qx", "qy", "qz", "qw", "sim_steps"]
    return len(a) == len(b) and a[cols].reset_index(drop=True).equals(b[cols].reset_index(drop=True))


def compare(name: str, a: pd.DataFrame, b: pd.DataFrame, a_name: str, b_name: str) -> dict[str, float]:
    """Agreement of ``a`` with ``b`` (same rows, same order): success, outcome, widths."""
    sim = ((a["outcome"] != "collision") | (b["outcome"] != "collision")).to_numpy()
    same = a["success"].to_numpy() == b["success"].to_numpy()
    dw = width_differences(a, b)  # mm
    figures = {
        "agree_all": float(same.mean()),
        "agree_sim": float(same[sim].mean()) if sim.any() else float("nan"),
        "n_sim": int(sim.sum()),
        "flips": int((~same).sum()),
        "outcome_agree": float((a["outcome"].to_numpy() == b["outcome"].to_numpy()).mean()),
        "width_max_mm": float(dw.max()) if dw.size else float("nan"),
        "width_p99_mm": float(np.percentile(dw, 99)) if dw.size else float("nan"),
        "width_over_0p2": int((dw > 0.2).sum()),
    }
    print(
        f"{name}: {a_name} vs {b_name}: success agrees on {figures['agree_all']:.1%} of {len(a)} "
        f"({figures['flips']} flips), {figures['agree_sim']:.1%} of the {figures['n_sim']} simulated; "
        f"outcome {figures['outcome_agree']:.1%}; widths where both succeed: max "
        f"{figures['width_max_mm']:.3f} mm, 99th pct {figures['width_p99_mm']:.3f} mm, "
        f"{figures['width_over_0p2']} over 0.2 mm"
    )
    if figures["width_over_0p2"]:
        print(f"{name}: rows both succeed whose widths differ by more than 0.2 mm")
        print(width_outliers(a, b, a_name, b_name).to_string(index=False, float_format=lambda x: f"{x:.2f}"))
    return figures


def width_differences(a: pd.DataFrame, b: pd.DataFrame) -> np.ndarray:
    """|width a - width b| (mm) over the rows both succeed, (k,)."""
    both = (a["success"] & b["success"]).to_numpy()
    return np.abs(a["width"].to_numpy() - b["width"].to_numpy())[both] * 1000


def width_spread(a: pd.DataFrame, b: pd.DataFrame) -> str:
    """Width differences over the rows both succeed: median, 99th percentile, max (mm), count over
    0.2 mm. Against the thorough reference it says how far a model's widths are from the
    reference's, so two models' width differences can be read against their own error."""
    dw = width_differences(a, b)
    if not dw.size:
        return "no row both succeed"
    return (
        f"median {np.median(dw):.3f} mm, 99th pct {np.percentile(dw, 99):.3f} mm, max {dw.max():.3f} mm, "
        f"{int((dw > 0.2).sum())} of {dw.size} over 0.2 mm"
    )


def width_outliers(a: pd.DataFrame, b: pd.DataFrame, a_name: str, b_name: str) -> pd.DataFrame:
    """Rows both succeed whose widths differ by more than 0.2 mm: the two widths and the chord the
    candidate expected (mm), and how far apart the two closed grasps are in the object's frame
    (TCP position, mm; orientation, deg): a different width with the same grasp is a different
    contact, with a moved grasp the object turned in the hand while closing."""
    both = (a["success"] & b["success"]).to_numpy()
    over = both & (np.abs(a["width"].to_numpy() - b["width"].to_numpy()) > 0.0002)
    ra, rb = a[over], b[over]
    xyz = ["x", "y", "z"]
    qa, qb = ra[["qx", "qy", "qz", "qw"]].to_numpy(), rb[["qx", "qy", "qz", "qw"]].to_numpy()
    dot = np.clip(np.abs((qa * qb).sum(axis=1)), 0.0, 1.0)
    return pd.DataFrame(
        {
            "object_id": ra["object_id"].to_numpy(),
            "grasp_id": ra["grasp_id"].to_numpy(),
            f"{a_name}_mm": ra["width"].to_numpy() * 1e3,
            f"{b_name}_mm": rb["width"].to_numpy() * 1e3,
            "expected_mm": ra["cmd_width"].to_numpy() * 1e3,
            "tcp_moved_mm": np.linalg.norm(ra[xyz].to_numpy() - rb[xyz].to_numpy(), axis=1) * 1e3,
            "turned_deg": np.degrees(2 * np.arccos(dot)),
        }
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--objects", type=Path, default=ROOT / "objects")
    ap.add_argument("--per-object", type=int, default=110, help="candidates per object (10 objects)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--variant", action="append", default=[], help="NAME:FIELD=VALUE[,FIELD=VALUE]")
    ap.add_argument(
        "--baseline",
        default="",
        help="FIELD=VALUE[,...]: the model the variants are compared with, and whose thorough protocol is "
        "the reference, when it is not the current default (e.g. the previous default after a change)",
    )
    ap.add_argument("--cache", type=Path, default=default_cache_dir() / "fidelity")
    ap.add_argument("--no-cache", action="store_true", help="neither read nor write cached labels")
    ap.add_argument(
        "--no-reference",
        action="store_true",
        help="skip the thorough reference (when not cached): variants against the default only",
    )
    ap.add_argument(
        "--fresh",
        action="store_true",
        help="recompute the default (and the reference if the default changed)",
    )
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f} (1 min)")

    default = parse_variant(args.baseline)[1] if args.baseline else AnnotatorConfig()
    thorough = AnnotatorConfig.thorough(default)
    variants = [parse_variant(spec) for spec in args.variant]
    stroke = max_width(default)
    chunks = []
    files = []
    for source in discover_objects(args.objects):
        try:
            model = load_object(source, default.objects)
        except ObjectError as exc:
            print(f"skip {source.object_id}: {exc}")
            continue
        files.append([source.object_id, model.mesh_sha256])
        cands = object_candidates(model, args.per_object, args.seed, default, stroke)
        for s in range(0, args.per_object, CHUNK_SIZE):
            e = min(args.per_object, s + CHUNK_SIZE)
            chunks.append(chunk(source, s, cands.T_obj_tcp[s:e], cands.width_expected[s:e]))
    n = sum(c.size for c in chunks)
    print(f"{n} candidates on {len({c.object_id for c in chunks})} objects, seed {args.seed}")
    cache = LabelCache(None if args.no_cache else args.cache)
    key = {"seed": args.seed, "per_object": args.per_object, "objects": files}

    t0 = time.perf_counter()
    cached_a = cache.get("default", default, key)
    hit = cached_a is not None and not args.fresh
    a = cached_a if hit else label(chunks, default, args.seed, args.workers)
    t1 = time.perf_counter()
    if not hit:
        if cached_a is not None:
            same = identical(a, cached_a)
            print(f"fresh default labels {'identical to' if same else 'DIFFER from'} the cached ones")
        cache.put("default", default, key, a)
    simulated = a["outcome"] != "collision"
    # the reference simulates the rows the default did not reject kinematically (the same rows for
    # every model of the gripper: the kinematic checks use the whole geometry), so it is keyed by
    # those rows, not by the default's settings; a new default with the same rows reuses it
    rows_digest = hashlib.sha256(np.packbits(simulated.to_numpy()).tobytes()).hexdigest()
    ref_key = {**key, "simulated_rows": rows_digest, "reference": "outcome, success, width, pose"}

    def reference() -> pd.DataFrame:
        # collisions are decided kinematically, identically under both protocols: only simulate the rest
        sim_chunks = []
        for c in chunks:
            rows = a[(a.object_id == c.object_id) & a.grasp_id.between(c.start, c.stop - 1)]
            keep = (rows["outcome"] != "collision").to_numpy()
            g = c.given
            for k in np.flatnonzero(keep):
                sim_chunks.append(chunk(c.source, c.start + k, g.T_obj_tcp[k : k + 1], g.width[k : k + 1]))
        b_sim = label(sim_chunks, thorough, args.seed, args.workers)
        b = a.copy().set_index(KEY)
        cols = ["outcome", "success", "width", "x", "y", "z", "qx", "qy", "qz", "qw"]
        b.loc[b_sim.set_index(KEY).index, cols] = b_sim.set_index(KEY)[cols]
        return b.reset_index()

    b = cache.get("thorough", thorough, ref_key)
    hit_b = b is not None
    if not hit_b and args.no_reference:
        b = None
    elif not hit_b:
        b = reference()
        cache.put("thorough", thorough, ref_key, b)
    t2 = time.perf_counter()
    sim = simulated.to_numpy()
    if b is None:
        print(f"default protocol: {t1 - t0:.0f} s{' (cached)' if hit else ''}; no thorough reference")
        for name, config in variants:
            print(f"\n== variant {name} == (load average {os.getloadavg()[0]:.2f})")
            compare(name, label(chunks, config, args.seed, args.workers), a, "variant", "default")
        return

    print(
        f"default protocol: {t1 - t0:.0f} s{' (cached)' if hit else ''}, "
        f"mean {a.sim_steps.mean():.0f} steps/candidate"
    )
    print(
        f"thorough protocol: {t2 - t1:.0f} s{' (cached)' if hit_b else ''} "
        f"on the {int(simulated.sum())} simulated candidates"
    )
    cm = pd.crosstab(a["success"].rename("default"), b["success"].rename("thorough"), margins=True)
    print("\nsuccess confusion matrix (rows: default, columns: thorough)\n" + cm.to_string())
    agree_all = float((a["success"].to_numpy() == b["success"].to_numpy()).mean())
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
    print(f"\nwidths, default vs thorough reference where both succeed: {width_spread(a, b)}")

    for name, config in variants:
        print(f"\n== variant {name} == (load average {os.getloadavg()[0]:.2f})")
        t3 = time.perf_counter()
        v = label(chunks, config, args.seed, args.workers)
        t4 = time.perf_counter()
        sim_v = v["sim_steps"][v["outcome"] != "collision"]
        print(
            f"{name}: {t4 - t3:.0f} s, mean {v.sim_steps.mean():.0f} steps/candidate, "
            f"{sim_v.mean():.0f} per simulated trial (default {a.sim_steps[simulated].mean():.0f})"
        )
        compare(name, v, a, "variant", "default")
        # the reference is the default's thorough protocol; its agreement over the default's simulated set
        same = v["success"].to_numpy() == b["success"].to_numpy()
        print(
            f"{name}: variant vs thorough reference: {same.mean():.1%} of all, "
            f"{same[sim].mean():.1%} of the {int(sim.sum())} simulated (default {agree_sim:.1%})"
        )
        print(f"{name}: widths vs thorough reference where both succeed: {width_spread(v, b)}")
        flips = v[v["success"].to_numpy() != a["success"].to_numpy()]
        if len(flips):
            moved = pd.DataFrame(
                {
                    "object_id": flips["object_id"],
                    "grasp_id": flips["grasp_id"],
                    "default": a.loc[flips.index, "outcome"],
                    "variant": flips["outcome"],
                    "thorough": b.loc[flips.index, "outcome"],
                }
            )
            print("flips (outcomes)\n" + moved.to_string(index=False))


if __name__ == "__main__":
    main()
