"""Write docs/performance.md from the newest record of each benchmark in bench/results/.

    python -m bench.docs              # (re)write docs/performance.md
    python -m bench.docs --check      # exit 1 if docs/performance.md is not what the records make

Nothing in the page is typed by hand: every number comes from a record (bench/harness.py), with
the command, commit, date, machine and load of the run that measured it; ratios come first.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from collections.abc import Iterable, Mapping
from typing import Any

from bench.arguments import Parser, existing_folder, writable_file
from bench.harness import RESULTS, ROOT, newest, read_records, record_key

OUT = ROOT / "docs" / "performance.md"
COMMAND = "python -m bench.docs"
# the page's order; benchmarks not named here follow in alphabetical order
ORDER = (
    "throughput",
    "peers",
    "fidelity",
    "profile_worker",
    "object_sets",
    "cold_start",
    "collision_error",
    "light_threshold",
    "light_objects",
    "widths",
    "rg2_coupling",
    "ur3_ik",
    "scale_folder",
    "scale_big_mesh",
    "evaluate_replay",
    "arm_agreement",
)
MAX_ROWS = 40  # rows of a table shown; the record keeps them all
EXPERIMENTS = ROOT / "bench" / "experiments"


def current_command(command: str) -> str:
    """The record's command as it runs today: ``python -m bench.NAME`` becomes
    ``python -m bench.experiments.NAME`` for a script that has since moved among the experiments."""

    def moved(match: re.Match[str]) -> str:
        name = match.group(1)
        if not (ROOT / "bench" / f"{name}.py").is_file() and (EXPERIMENTS / f"{name}.py").is_file():
            return f"bench.experiments.{name}"
        return match.group(0)

    return re.sub(r"\bbench\.(\w+)\b", moved, command, count=1)


def is_experiment(record: Mapping[str, Any]) -> bool:
    """Whether a record comes from a one-off experiment (``bench/experiments/``), not a standing benchmark."""
    return "bench.experiments." in current_command(record["command"])


def fmt(value: Any) -> str:
    """A recorded value as the page shows it: four significant digits, whole numbers from 1000."""
    if value is None:
        return "n/a"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            return "n/a"
        if abs(value) >= 1000:
            return f"{value:.0f}"
        return f"{value:.4g}"
    return str(value)


def cell(value: Any) -> str:
    """``fmt(value)`` made safe inside a Markdown table."""
    return fmt(value).replace("|", "\\|").replace("\n", " ")


def _spread(entry: Mapping[str, Any]) -> str:
    return f"{fmt(entry['min'])} – {fmt(entry['max'])}" if "min" in entry else ""


def _loads(values: Iterable[float]) -> str:
    return " / ".join(fmt(v) for v in values)


def _table(head: list[str], rows: list[list[Any]]) -> list[str]:
    return [
        "| " + " | ".join(head) + " |",
        "|" + "|".join("---" for _ in head) + "|",
        *("| " + " | ".join(cell(v) for v in row) + " |" for row in rows),
    ]


def provenance(record: Mapping[str, Any]) -> list[str]:
    """Where a benchmark's figures come from: command, commit, date, machine, load, configuration."""
    m, config = record["machine"], record["config"]
    state = "with changes to " + ", ".join(record["changed_files"]) if record["dirty"] else "clean"
    libs = ", ".join(f"{k} {v}" for k, v in record["libraries"].items() if v is not None)
    changed = config["annotator_changes"]
    settings = (
        "; ".join(f"{s}.{k} = {fmt(v)}" for s, fields in changed.items() for k, v in fields.items())
        if changed
        else "the default"
    )
    date = record["date"].replace("T", " ").replace("Z", " UTC")
    return [
        f"- Command: `{current_command(record['command'])}`",
        f"- Commit `{record['commit'][:7]}` (working tree {state}); started {date}, took "
        f"{fmt(record['seconds'])} s",
        f"- Machine: {m['cpu']}, {m['cores']} cores ({m['usable_cores']} usable), "
        f"{fmt(m['memory_gib'])} GiB, Python {m['python']}, {m['platform']}",
        f"- Load average (one, five and fifteen minutes): {_loads(record['load']['before'])} before, "
        f"{_loads(record['load']['after'])} after",
        f"- Libraries: {libs}",
        f"- Configuration: `{config['digest']}` (arguments and AnnotatorConfig); AnnotatorConfig "
        f"`{config['annotator_digest']}`: {settings}",
    ]


def section(record: Mapping[str, Any], level: int = 2) -> list[str]:
    """One benchmark's part of the page: provenance, ratios, figures, tables."""
    lines = [f"{'#' * level} {record_key(record)}", ""]
    if record["about"]:
        lines += [record["about"], ""]
    lines += [*provenance(record), ""]
    if record["ratios"]:
        rows = [[r["name"], r["value"], _spread(r), r["note"]] for r in record["ratios"]]
        lines += [
            "Ratios (both sides measured in this run):",
            "",
            *_table(["ratio", "value", "range", "what"], rows),
        ]
        lines.append("")
    if record["figures"]:
        rows = [[f["name"], f["value"], f["unit"], _spread(f), f["note"]] for f in record["figures"]]
        lines += ["Figures:", "", *_table(["figure", "value", "unit", "range", "what"], rows), ""]
    for table in record["tables"]:
        shown = table["rows"][:MAX_ROWS]
        more = len(table["rows"]) - len(shown)
        title = f"Table `{table['name']}`" + (f": {table['note']}" if table["note"] else "")
        if more:
            title += f" (the first {len(shown)} of {len(table['rows'])} rows; the record has all)"
        lines += [title, "", *_table(table["columns"], shown), ""]
    return lines


def ordered(records: Mapping[str, Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    """Records in the page's order: :data:`ORDER`'s benchmarks first, then the others by name; a
    benchmark's tagged records after its own, by tag."""
    rank = {name: i for i, name in enumerate(ORDER)}
    return sorted(
        records.values(),
        key=lambda r: (rank.get(r["benchmark"], len(ORDER)), r["benchmark"], r.get("tag") or ""),
    )


def _overview(records: list[Mapping[str, Any]]) -> list[list[Any]]:
    return [
        [
            f"[{record_key(r)}](#{record_key(r)})",
            r["about"],
            r["date"][:10],
            f"`{r['commit'][:7]}`" + (" (changed)" if r["dirty"] else ""),
            f"{fmt(r['load']['before'][0])} / {fmt(r['load']['after'][0])}",
        ]
        for r in records
    ]


def render(records: Mapping[str, Mapping[str, Any]]) -> str:
    """The page for ``{benchmark: newest record}``."""
    lines = [
        f"<!-- Generated by `{COMMAND}` from bench/results/; do not edit: re-run the benchmark, then "
        "the command. -->",
        "",
        "# Performance",
        "",
        f"Generated by `{COMMAND}` from the newest record of each benchmark in `bench/results/`, which "
        "the benchmark wrote itself (`bench/harness.py`); no figure here is typed by hand. How to run "
        "the benchmarks: `bench/README.md`.",
        "",
        "Ratios come first: each compares two things measured in the same run (ours against a peer, a "
        "candidate against a free step of the gripper, the model against the model before), so a slower "
        "or busier machine moves them little. Absolute times depend on the machine and on its load, "
        "given with every run.",
        "",
    ]
    records_in_order = ordered(records)
    standing = [r for r in records_in_order if not is_experiment(r)]
    experiments = [r for r in records_in_order if is_experiment(r)]
    head = ["benchmark", "measures", "date", "commit", "load before / after"]
    lines += ["Standing benchmarks, re-run to track the product:", "", *_table(head, _overview(standing)), ""]
    if experiments:
        lines += [
            "[One-off experiments](#one-off-experiments), each run to decide a constant or a design "
            "(the decision record that cites it keeps its reasoning):",
            "",
            *_table(head, _overview(experiments)),
            "",
        ]
    for record in standing:
        lines += section(record)
    if experiments:
        lines += [
            "## One-off experiments",
            "",
            "Scripts in `bench/experiments/`: nothing re-runs them to track the product; each record is "
            "the measurement a decision was made on.",
            "",
        ]
        for record in experiments:
            lines += section(record, level=3)
    return "\n".join(lines).rstrip("\n") + "\n"


def parser() -> Parser:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--results", type=existing_folder, default=RESULTS, help="the records' folder")
    ap.add_argument("--out", type=writable_file, default=OUT)
    ap.add_argument("--check", action="store_true", help="compare with --out instead of writing it")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        text = render(newest(read_records(args.results)))
    except ValueError as exc:
        print(f"bench.docs: {exc}", file=sys.stderr)
        return 2
    if args.check:
        current = args.out.read_text() if args.out.is_file() else ""
        if current != text:
            print(f"{args.out} is not what the records make: run {COMMAND}", file=sys.stderr)
            return 1
        return 0
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
