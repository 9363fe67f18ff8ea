"""The bench's records and the page made from them: what is written, and that no figure is typed."""

from __future__ import annotations

import dataclasses
import json
import math
import re
import subprocess
from pathlib import Path

import pytest

from annotator.config import AnnotatorConfig
from bench import docs, harness
from bench.harness import Run

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "bench"
NUMBER = re.compile(r"\d+(?:\.\d+)?")
# bench modules that are not benchmarks
HELPERS = {"__init__", "__main__", "_variants", "arguments", "harness", "docs", "reference", "vgn_policy"}


def run_demo(results: Path, **kwargs) -> dict:
    """A run of a made-up benchmark into ``results``; its record as read back."""
    with Run(
        "demo",
        config={"n": 3, "objects": ROOT / "objects", "out": Path("/elsewhere/x")},
        results=results,
        command="demo --n 3",
        **kwargs,
    ) as run:
        run.figure("candidates_per_s", 12.5, "1/s", note="wall")
        run.ratio("ours_over_peer", 0.93, note="ms per candidate", spread=(0.9, 0.95))
        run.figure("failed_share", float("nan"), "%")
        run.table("per_object", [{"object": "mug", "ms": 3.25}, {"object": "bowl", "parts": 7}])
    assert run.path is not None and run.path.is_file()
    return json.loads(run.path.read_text())


def test_a_run_writes_one_record_with_what_the_figures_rest_on(tmp_path):
    record = run_demo(tmp_path)
    (path,) = tmp_path.glob("demo/*.json")
    date, commit = record["date"][:10], record["commit"][:7]
    assert path.name == f"{date}-{commit}.json"
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", record["date"])
    assert re.fullmatch(r"[0-9a-f]{40}", record["commit"])  # the tests run in a git checkout
    assert isinstance(record["dirty"], bool)
    assert record["command"] == "demo --n 3"
    # a path in the repository is recorded relative to it: the digest is the same in any checkout
    assert record["config"]["arguments"] == {"n": 3, "objects": "objects", "out": "/elsewhere/x"}
    machine = record["machine"]
    assert machine["cores"] >= 1 and machine["memory_gib"] > 0 and machine["cpu"] and machine["python"]
    assert {"pybullet", "numpy", "trimesh", "coacd"} <= set(record["libraries"])
    assert all(len(record["load"][k]) == 3 for k in ("before", "after"))
    assert record["seconds"] >= 0
    # figures in the order they were recorded, NaN as null; the table's columns in first-seen order
    assert [f["name"] for f in record["figures"]] == ["candidates_per_s", "failed_share"]
    assert record["figures"][1]["value"] is None
    assert record["ratios"] == [
        {"name": "ours_over_peer", "value": 0.93, "note": "ms per candidate", "min": 0.9, "max": 0.95}
    ]
    (table,) = record["tables"]
    assert table["columns"] == ["object", "ms", "parts"]
    assert table["rows"] == [["mug", 3.25, None], ["bowl", None, 7]]
    # stable: keys sorted, so the same record is the same file
    assert path.read_text() == json.dumps(record, sort_keys=True, indent=1) + "\n"


def test_the_configuration_digest_follows_the_arguments_and_the_annotator_config(tmp_path):
    base = run_demo(tmp_path / "a")["config"]
    assert run_demo(tmp_path / "b")["config"] == base
    physics = dataclasses.replace(AnnotatorConfig().physics, solver_iterations=100)
    changed = run_demo(tmp_path / "c", annotator=AnnotatorConfig(physics=physics))["config"]
    assert changed["digest"] != base["digest"] and changed["annotator_digest"] != base["annotator_digest"]
    assert base["annotator_changes"] == {}
    assert changed["annotator_changes"] == {"physics": {"solver_iterations": 100}}
    with Run("demo", config={"n": 4}, results=tmp_path / "d", command="demo") as run:
        pass
    assert json.loads(run.path.read_text())["config"]["digest"] != base["digest"]


def test_a_run_that_raises_writes_nothing(tmp_path):
    with pytest.raises(RuntimeError), Run("demo", results=tmp_path, command="demo") as run:
        run.figure("x", 1.0)
        raise RuntimeError("the benchmark failed")
    assert run.path is None and not list(tmp_path.rglob("*.json"))


@pytest.mark.parametrize(
    ("record", "error"),
    [
        (lambda run: run.figure("Bad Name", 1.0), ValueError),
        (lambda run: (run.figure("x", 1.0), run.ratio("x", 2.0)), ValueError),
        (lambda run: run.figure("x", "fast"), TypeError),
        (lambda run: run.figure("x", True), TypeError),
        (lambda run: run.table("t", [{"cell": [1, 2]}]), TypeError),
    ],
)
def test_a_figure_is_a_named_number_recorded_once(tmp_path, record, error):
    with Run("demo", results=tmp_path, command="demo") as run, pytest.raises(error):
        record(run)


def test_the_command_is_given_as_the_module_is_run():
    assert (
        harness.command_line([str(BENCH / "peers.py"), "--rounds", "1"]) == "python -m bench.peers --rounds 1"
    )
    assert harness.command_line(["/usr/bin/other", "a b"]) == "/usr/bin/other 'a b'"


def test_a_tree_is_dirty_when_a_tracked_file_changed_but_not_for_the_bench_outputs(tmp_path):
    def git(*args):
        subprocess.run(["git", "-C", str(tmp_path), *args], check=True, capture_output=True)

    git("init", "-q")
    git("config", "user.email", "bench@example.com")
    git("config", "user.name", "bench")
    (tmp_path / "bench" / "results" / "demo").mkdir(parents=True)
    (tmp_path / "code.py").write_text("a = 1\n")
    (tmp_path / "bench" / "results" / "demo" / "r.json").write_text("{}\n")
    git("add", ".")
    git("commit", "-qm", "start")
    assert not harness.git_state(tmp_path).dirty
    (tmp_path / "bench" / "results" / "demo" / "r.json").write_text('{"a": 1}\n')
    (tmp_path / "untracked.py").write_text("")
    assert not harness.git_state(tmp_path).dirty
    (tmp_path / "code.py").write_text("a = 2\n")
    state = harness.git_state(tmp_path)
    assert state.dirty and state.changed == ("code.py",)
    assert harness.git_state(tmp_path / "nowhere").commit == "unknown"


def test_the_newest_record_of_each_benchmark_is_the_one_shown(tmp_path):
    old = run_demo(tmp_path)
    new = {**old, "date": "2999-01-01T00:00:00Z", "figures": [{**old["figures"][0], "value": 99.25}]}
    harness.write_record(new, tmp_path)
    assert harness.newest(harness.read_records(tmp_path))["demo"]["date"] == new["date"]
    page = docs.render(harness.newest(harness.read_records(tmp_path)))
    assert "99.25" in page and "| 12.5 |" not in page
    # ratios before figures, the command and the machine with them
    assert page.index("ours_over_peer") < page.index("candidates_per_s")
    assert "`demo --n 3`" in page and old["machine"]["cpu"] in page


def page_numbers_not_in(page: str, records: dict[str, dict]) -> list[str]:
    """Numbers on ``page`` that no record holds (as the page formats it): hand-typed figures.
    Code spans (commands, commits, digests) are identifiers, not figures, and are left out."""
    page = re.sub(r"`[^`]*`", "", page)
    allowed = {str(docs.MAX_ROWS)}

    def walk(value):
        if isinstance(value, dict):
            for k, v in value.items():
                allowed.update(NUMBER.findall(k))
                walk(v)
        elif isinstance(value, list):
            allowed.add(str(len(value)))
            for v in value:
                walk(v)
        elif isinstance(value, str):
            allowed.update(NUMBER.findall(value))
        elif isinstance(value, (int, float)) and not isinstance(value, bool):
            allowed.update(NUMBER.findall(docs.fmt(value)))

    walk(records)
    return [n for n in NUMBER.findall(page) if n not in allowed]


def test_every_number_on_the_page_comes_from_a_record(tmp_path):
    records = {"demo": run_demo(tmp_path)}
    page = docs.render(records)
    assert page_numbers_not_in(page, records) == []
    typed = page.replace("| ours_over_peer |", "| ours_over_peer (was 0.871) |")
    assert page_numbers_not_in(typed, records) == ["0.871"]


def test_performance_page_is_what_the_committed_records_make():
    """docs/performance.md is generated (`python -m bench.docs`) from bench/results/, every number
    on it comes from a record, and every benchmark has a record there."""
    records = harness.newest(harness.read_records())
    page = (ROOT / "docs" / "performance.md").read_text()
    assert page == docs.render(records), "docs/performance.md is stale: run python -m bench.docs"
    assert docs.main(["--check"]) == 0
    assert page_numbers_not_in(page, records) == []
    assert page.startswith("<!-- Generated by `python -m bench.docs`")
    for record in records.values():
        assert not record["dirty"], f"{record['benchmark']}: measured on a changed tree"


def benchmarks() -> dict[str, list[str]]:
    """{bench module (``peers``, ``experiments.widths``): the names of the records it writes
    (``Run("name"``)}: the standing benchmarks and the one-off experiments."""
    out = {}
    for path in sorted([*BENCH.glob("*.py"), *(BENCH / "experiments").glob("*.py")]):
        if path.stem not in HELPERS and path.stem != "__init__":
            module = ".".join(path.relative_to(BENCH).with_suffix("").parts)
            out[module] = re.findall(r'Run\(\s*"([a-z0-9_]+)"', path.read_text())
    return out


def test_every_benchmark_writes_a_record_has_one_and_is_in_the_index():
    recorded = {r["benchmark"] for r in harness.read_records()}
    index = (BENCH / "README.md").read_text()
    for module, names in benchmarks().items():
        assert names, f"bench/{module}.py writes no record through bench.harness.Run"
        assert set(names) <= recorded, (
            f"bench/{module}.py: no record of {set(names) - recorded} in bench/results"
        )
        assert f"python -m bench.{module}" in index, f"bench/README.md does not list bench.{module}"
        assert not re.search(
            r"^\s*(from|import) (_variants|light_objects|peers)\b",
            (BENCH / module.replace(".", "/")).with_suffix(".py").read_text(),
            re.M,
        )


def test_values_the_page_cannot_show_are_said_so():
    assert docs.fmt(None) == docs.fmt(math.nan) == "n/a"
    assert (docs.fmt(0.93124), docs.fmt(812.0), docs.fmt(12345.6), docs.fmt(7), docs.fmt(True)) == (
        "0.9312",
        "812",
        "12346",
        "7",
        "yes",
    )


def test_a_file_that_is_not_a_record_stops_the_page_with_one_line(tmp_path, capsys):
    (tmp_path / "demo").mkdir()
    (tmp_path / "demo" / "x.json").write_text('{"schema": 1, "benchmark": "other"}')
    assert docs.main(["--results", str(tmp_path), "--out", str(tmp_path / "p.md")]) == 2
    assert "x.json: not a schema-1 record of 'demo'" in capsys.readouterr().err
    assert not (tmp_path / "p.md").exists()
