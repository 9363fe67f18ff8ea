"""Fidelity: the default protocol's labels against a thorough reference's on the same candidates.

    python -m bench.fidelity                    # >= 1,000 candidates over the sample objects
    python -m bench.fidelity --per-object 20    # a quick look
    python -m bench.fidelity --variant "it100:physics.solver_iterations=100"   # a changed model

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

The agreements are ratios of labels, not of times: no machine moves them. A record
(bench/harness.py) keeps them with the widths, the tables and the times of what was not cached.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import time
from pathlib import Path

import numpy as np
import pandas as pd

from annotator.config import AnnotatorConfig
from annotator.objects import ObjectError, default_cache_dir, discover_objects, load_object
from annotator.pipeline.in_memory import ExecutionOptions, run_in_memory
from annotator.pipeline.plan import CHUNK_SIZE
from annotator.pipeline.simulate import object_candidates
from annotator.pipeline.tasks import GivenGrasps, Span, SpanTask
from annotator.sim.hand import max_width
from bench._variants import parse_variant
from bench.arguments import N_MAX, WORKERS_MAX, Parser, count, existing_folder, seed, writable_folder
from bench.harness import Run

ROOT = Path(__file__).resolve().parents[1]
KEY = ["object_id", "grasp_id"]
# Sections the floating labels of this script never read: a change to them keeps the cached labels.
CELL_ONLY = ("cell", "kinect")


def label(chunks: list[Span], config: AnnotatorConfig, seed: int, workers: int) -> pd.DataFrame:
    """The chunks' labels, through the runner's execution on ``workers`` processes."""
    tasks = [SpanTask(span=c, config=config, seed=seed, n=c.size) for c in chunks]
    out = run_in_memory(tasks, ExecutionOptions(workers))
    failed = [r.error for r in out if r.error is not None]
    if failed:
        raise RuntimeError(f"{len(failed)} chunks failed: {failed[0]}")
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
    """Digest of the simulation code and robot models: cached labels of other code are not reused."""
    h = hashlib.sha256()
    for path in sorted((ROOT / "annotator").rglob("*.py")) + sorted((ROOT / "assets").rglob("*.urdf")):
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


def parser() -> Parser:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--objects", type=existing_folder, default=ROOT / "objects")
    ap.add_argument(
        "--per-object", type=count(1, N_MAX), default=110, help="candidates per object (10 objects)"
    )
    ap.add_argument("--seed", type=seed, default=0)
    ap.add_argument("--workers", type=count(1, WORKERS_MAX), default=os.cpu_count() or 1)
    ap.add_argument("--variant", action="append", default=[], help="NAME:FIELD=VALUE[,FIELD=VALUE]")
    ap.add_argument(
        "--baseline",
        default="",
        help="FIELD=VALUE[,...]: the model the variants are compared with, and whose thorough protocol is "
        "the reference, when it is not the current default (e.g. the previous default after a change)",
    )
    ap.add_argument("--cache", type=writable_folder, default=default_cache_dir() / "fidelity")
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
    return ap


def main() -> None:
    args = parser().parse_args()
    print(f"load average {os.getloadavg()[0]:.2f} (1 min)")
    default = parse_variant(args.baseline)[1] if args.baseline else AnnotatorConfig()
    with Run("fidelity", config=vars(args), annotator=default) as run:
        measure(args, default, run)


def candidate_chunks(args: argparse.Namespace, default: AnnotatorConfig) -> tuple[list[Span], list]:
    """The sampled candidates of every object in spans of CHUNK_SIZE; [object id, mesh digest] pairs."""
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
    return chunks, files


def measure(args: argparse.Namespace, default: AnnotatorConfig, run: Run) -> None:
    thorough = AnnotatorConfig.thorough(default)
    variants = [parse_variant(spec) for spec in args.variant]
    chunks, files = candidate_chunks(args, default)
    n = sum(c.size for c in chunks)
    print(f"{n} candidates on {len({c.object_id for c in chunks})} objects, seed {args.seed}")
    run.figure("candidates", n, note=f"{len(files)} objects, seed {args.seed}")
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

    b = cache.get("thorough", thorough, ref_key)
    hit_b = b is not None
    if not hit_b and args.no_reference:
        b = None
    elif not hit_b:
        b = reference(chunks, a, thorough, args)
        cache.put("thorough", thorough, ref_key, b)
    t2 = time.perf_counter()
    run.figure("simulated", int(simulated.sum()), note="candidates the default did not reject kinematically")
    run.figure("default_steps_per_candidate", float(a.sim_steps.mean()))
    if not hit:
        run.figure("default_s", t1 - t0, "s", note="labelling with the default protocol, wall")
    if b is None:
        print(f"default protocol: {t1 - t0:.0f} s{' (cached)' if hit else ''}; no thorough reference")
        for name, config in variants:
            print(f"\n== variant {name} == (load average {os.getloadavg()[0]:.2f})")
            t3 = time.perf_counter()
            v = label(chunks, config, args.seed, args.workers)
            record_compare(run, name, compare(name, v, a, "variant", "default"))
            timing(run, name, time.perf_counter() - t3, None if hit else t1 - t0)
        return
    print(
        f"default protocol: {t1 - t0:.0f} s{' (cached)' if hit else ''}, "
        f"mean {a.sim_steps.mean():.0f} steps/candidate"
    )
    print(
        f"thorough protocol: {t2 - t1:.0f} s{' (cached)' if hit_b else ''} "
        f"on the {int(simulated.sum())} simulated candidates"
    )
    if not hit_b:
        run.figure(
            "thorough_s", t2 - t1, "s", note="the thorough reference on the simulated candidates, wall"
        )
        if not hit:
            run.ratio("thorough_vs_default_time", (t2 - t1) / (t1 - t0), note="wall, thorough / default")
    agree_sim = against_reference(run, a, b, n)
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
        timing(run, name, t4 - t3, None if hit else t1 - t0)
        record_compare(run, name, compare(name, v, a, "variant", "default"))
        variant_against_reference(run, name, v, a, b, agree_sim)


def reference(chunks: list[Span], a: pd.DataFrame, thorough: AnnotatorConfig, args) -> pd.DataFrame:
    """The thorough protocol's labels: collisions are decided kinematically, identically under both
    protocols, so only the rest of ``a``'s rows are simulated."""
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


def against_reference(run: Run, a: pd.DataFrame, b: pd.DataFrame, n: int) -> float:
    """Print and record the default against the thorough reference; the agreement over the simulated."""
    sim = (a["outcome"] != "collision").to_numpy()
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
    run.ratio("success_agrees_with_reference", agree_all, note=f"share of all {n} candidates")
    run.ratio(
        "success_agrees_with_reference_simulated", agree_sim, note=f"share of the {int(sim.sum())} simulated"
    )
    record_widths(run, "widths_vs_reference", width_differences(a, b))
    run.table(
        "outcomes",
        [{"default": str(i), **{str(c): int(oc.loc[i, c]) for c in oc.columns}} for i in oc.index],
        note="rows: the default's outcome; columns: the thorough reference's",
    )
    run.table(
        "success_per_object",
        [{"object": o, "default": r.default, "thorough": r.thorough} for o, r in per.iterrows()],
        note="success rates",
    )
    return agree_sim


def record_widths(run: Run, name: str, dw: np.ndarray) -> None:
    """Width differences (mm) over the rows both succeed: median, 99th percentile, max, over 0.2 mm."""
    if not dw.size:
        return
    run.figure(f"{name}_median", float(np.median(dw)), "mm", note="|width difference| where both succeed")
    run.figure(f"{name}_p99", float(np.percentile(dw, 99)), "mm")
    run.figure(f"{name}_max", float(dw.max()), "mm")
    run.figure(f"{name}_over_0p2mm", int((dw > 0.2).sum()), note=f"of {dw.size} successes both")


def record_compare(run: Run, name: str, figures: dict[str, float]) -> None:
    """A variant's agreement with the default (``compare``'s figures)."""
    key = f"variant_{slug(name)}"
    run.ratio(
        f"{key}_success_agrees", figures["agree_all"], note=f"variant {name} vs the default, all candidates"
    )
    run.ratio(
        f"{key}_success_agrees_simulated", figures["agree_sim"], note=f"of the {figures['n_sim']} simulated"
    )
    run.ratio(f"{key}_outcome_agrees", figures["outcome_agree"], note="outcome, all candidates")
    run.figure(f"{key}_flips", figures["flips"], note="success differs from the default")
    run.figure(f"{key}_width_max", figures["width_max_mm"], "mm", note="vs the default, where both succeed")
    run.figure(
        f"{key}_width_over_0p2mm", figures["width_over_0p2"], note="vs the default, where both succeed"
    )


def timing(run: Run, name: str, seconds: float, default_seconds: float | None) -> None:
    key = f"variant_{slug(name)}"
    if default_seconds is not None:
        run.ratio(
            f"{key}_time_vs_default", seconds / default_seconds, note="wall, variant / default, this run"
        )
    run.figure(f"{key}_s", seconds, "s", note=f"labelling with variant {name}, wall")


def variant_against_reference(
    run: Run, name: str, v: pd.DataFrame, a: pd.DataFrame, b: pd.DataFrame, agree_sim: float
) -> None:
    """A variant against the thorough reference (always the default's), and its flips."""
    sim = (a["outcome"] != "collision").to_numpy()
    same = v["success"].to_numpy() == b["success"].to_numpy()
    print(
        f"{name}: variant vs thorough reference: {same.mean():.1%} of all, "
        f"{same[sim].mean():.1%} of the {int(sim.sum())} simulated (default {agree_sim:.1%})"
    )
    print(f"{name}: widths vs thorough reference where both succeed: {width_spread(v, b)}")
    key = f"variant_{slug(name)}"
    run.ratio(f"{key}_agrees_with_reference", float(same.mean()), note="success, all candidates")
    run.ratio(f"{key}_agrees_with_reference_simulated", float(same[sim].mean()), note="success, simulated")
    record_widths(run, f"{key}_widths_vs_reference", width_differences(v, b))
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


def slug(name: str) -> str:
    """A variant's name as part of a figure's name."""
    return re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_") or "unnamed"


if __name__ == "__main__":
    main()
