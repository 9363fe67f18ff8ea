"""The package's structure, measured from its files: import cycles (runtime, and counting the imports
made for type checking only), the floors inside ``annotator/pipeline/`` and the imports running up
them, raw PyBullet calls outside ``annotator/sim/``, radon's complexity blocks, mypy's errors and
``duplicates``' pairs, of this tree or of another checkout.

    python -m bench.structure                      # this tree
    python -m bench.structure --repo ../old        # another checkout, measured by this code
    python -m bench.structure --no-mypy --no-duplicates    # the quick figures only

- cycles: strongly connected components of more than one module in the graph of ``annotator``'s
  imports read from the files (function-local imports included); ``runtime`` leaves out the
  imports under ``if TYPE_CHECKING:``, ``with type-only`` counts them.
- the floors inside ``pipeline/``: each module's floor is one above the highest floor of the
  pipeline modules it imports at runtime; an import (type-only ones included) of a module on the
  importer's floor or above runs up.
- raw ``pb.*``: attribute uses of the ``pb`` module (``pb.stepSimulation``, ``pb.GEOM_MESH``) in
  ``annotator/`` outside ``sim/``, and the modules importing ``pybullet`` there.
- radon: blocks (functions, methods, classes) of cyclomatic complexity rank C and worse, D and
  worse (``radon cc -n C annotator``).
- mypy: errors over the package as ``tests/test_types.py`` runs it (pyproject's ``[tool.mypy]``).
- duplicates: the pairs of places sharing six or more lines, as ``duplicates --repo DIR`` counts
  them over ``annotator/``.

Prints one line per figure and writes a record (bench/harness.py) of them; asserts nothing.
"""

from __future__ import annotations

import argparse
import ast
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from bench.arguments import Parser, existing_folder
from bench.harness import Run

ROOT = Path(__file__).resolve().parents[1]


def _module_name(path: Path, package: Path) -> str:
    parts = list(path.relative_to(package.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _type_checking_lines(tree: ast.AST) -> set[int]:
    lines: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for child in node.body:
                lines.update(range(child.lineno, (child.end_lineno or child.lineno) + 1))
    return lines


@dataclass(frozen=True)
class Graph:
    """The package's imports: module -> modules it imports at runtime, and those it imports for
    type checking only."""

    runtime: dict[str, set[str]]
    type_only: dict[str, set[str]]

    def all(self) -> dict[str, set[str]]:
        return {m: self.runtime[m] | self.type_only[m] for m in self.runtime}


def import_graph(package: Path) -> Graph:
    """``package``'s import graph (``from a.b import c``: ``a.b.c`` when that is a module, else ``a.b``)."""
    files = {_module_name(p, package): p for p in package.rglob("*.py")}
    runtime: dict[str, set[str]] = {}
    type_only: dict[str, set[str]] = {}
    for name, path in files.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        typing_lines = _type_checking_lines(tree)
        owner = name if path.name == "__init__.py" else name.rpartition(".")[0]
        runtime[name], type_only[name] = set(), set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    anchor = owner.split(".")[: len(owner.split(".")) - node.level + 1]
                    base = ".".join([*anchor, base] if base else anchor)
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in files else base for a in node.names]
            else:
                continue
            edges = type_only[name] if node.lineno in typing_lines else runtime[name]
            for target in targets:
                while target and target not in files:
                    target = target.rpartition(".")[0]
                if target and target != name:
                    edges.add(target)
    return Graph(runtime, type_only)


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(out)


@dataclass(frozen=True)
class Floors:
    """The floors of a subpackage's modules (``floor``: module -> floor, from 0) and the imports
    that run up them (importer, imported)."""

    floor: dict[str, int]
    up: list[tuple[str, str]]


def floors(graph: Graph, subpackage: str) -> Floors:
    """Each module of ``subpackage`` on the floor one above the highest it imports at runtime
    (within the subpackage); the imports, type-only ones too, of a module on the importer's
    floor or above."""
    modules = sorted(m for m in graph.runtime if m.startswith(subpackage + "."))
    floor: dict[str, int] = {}

    def of(module: str, seen: frozenset[str]) -> int:
        if module not in floor:
            below = [d for d in graph.runtime[module] if d in modules and d not in seen]
            floor[module] = 1 + max((of(d, seen | {module}) for d in below), default=-1)
        return floor[module]

    for module in modules:
        of(module, frozenset())
    everything = graph.all()
    up = sorted((m, d) for m in modules for d in everything[m] if d in floor and floor[d] >= floor[m])
    return Floors(floor, up)


def raw_pybullet(package: Path) -> tuple[int, int, list[str]]:
    """Attribute uses of ``pb`` outside ``package/sim``, the calls among them, and the modules
    there importing pybullet."""
    uses, calls, importers = 0, 0, []
    for path in sorted(package.rglob("*.py")):
        if path.relative_to(package).parts[0] == "sim":
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "pb":
                uses += 1
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
                calls += isinstance(node.func.value, ast.Name) and node.func.value.id == "pb"
            names: list[str] = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [node.module or ""] + [f"{node.module}.{a.name}" for a in node.names]
            if any(n == "pybullet" or n.startswith("pybullet.") or n == "annotator.sim.pb" for n in names):
                importers.append(str(path.relative_to(package.parent)))
    return uses, calls, sorted(set(importers))


def radon_blocks(package: Path) -> dict[str, list[str]]:
    """Blocks of rank C and worse, and D and worse, as ``radon cc -n C`` lists them: ``file:line
    name (rank complexity)``."""
    # the radon installed beside this Python (a virtual environment not activated), else on PATH
    radon = shutil.which("radon", path=str(Path(sys.executable).parent)) or shutil.which("radon")
    if radon is None:
        raise SystemExit("bench.structure: radon is not installed: pip install -e '.[bench]'")
    proc = subprocess.run(
        [radon, "cc", "-j", "-n", "C", str(package)], capture_output=True, text=True, check=True
    )
    out: dict[str, list[str]] = {"C": [], "D": []}
    for path, blocks in sorted(json.loads(proc.stdout).items()):
        for block in blocks:
            where = Path(path).resolve().relative_to(package.parent)
            line = f"{where}:{block['lineno']} {block['name']} ({block['rank']} {block['complexity']})"
            out["C"].append(line)
            if block["rank"] >= "D":
                out["D"].append(line)
    return out


def mypy_errors(repo: Path) -> int:
    """mypy's errors over ``repo``'s package, with its pyproject's configuration."""
    from mypy import api

    with tempfile.TemporaryDirectory(prefix="mypy-cache-") as cache:
        args = ["--config-file", str(repo / "pyproject.toml"), "--no-error-summary", "--cache-dir", cache]
        here = os.getcwd()
        os.chdir(repo)
        try:
            stdout, _, _ = api.run(args)
        finally:
            os.chdir(here)
    return sum(1 for line in stdout.splitlines() if ": error:" in line)


def duplicate_pairs(repo: Path) -> int:
    """The pairs ``duplicates`` finds over ``repo/annotator`` (its first line counts them)."""
    proc = subprocess.run(
        ["duplicates", "--repo", str(repo / "annotator"), "--seconds", "300"],
        capture_output=True,
        text=True,
    )
    first = proc.stdout.strip().splitlines()[0] if proc.stdout.strip() else ""
    if first.startswith("no duplicates"):
        return 0
    count = re.match(r"\D*(\d+)", first)
    if count is None:
        raise SystemExit(f"duplicates: unexpected output {first!r}")
    return int(count.group(1))


def parser() -> Parser:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--repo", type=existing_folder, default=ROOT, help="the checkout measured [default: this one]"
    )
    ap.add_argument("--no-mypy", action="store_true", help="leave out mypy (a minute or two)")
    ap.add_argument("--no-duplicates", action="store_true", help="leave out duplicates")
    return ap


def main() -> None:
    args = parser().parse_args()
    repo = args.repo.resolve()
    where = "this tree" if repo == ROOT else f"the checkout {repo.name}"  # no local folder's name
    package = repo / "annotator"
    graph = import_graph(package)
    runtime, typed = cycles(graph.runtime), cycles(graph.all())
    pipeline = floors(graph, "annotator.pipeline")
    pb_uses, pb_calls, pb_importers = raw_pybullet(package)
    radon = radon_blocks(package)
    with Run("structure", config={**{k: str(v) for k, v in vars(args).items()}, "repo": where}) as record:
        figures = [
            ("cycles_runtime", len(runtime), "import cycles at runtime", runtime),
            ("cycles_type_only", len(typed), "import cycles counting type-only imports", typed),
            ("pipeline_modules", len(pipeline.floor), "modules in annotator/pipeline/", None),
            ("pipeline_floors", 1 + max(pipeline.floor.values(), default=-1), "floors in pipeline/", None),
            ("pipeline_imports_up", len(pipeline.up), "imports running up inside pipeline/", pipeline.up),
            ("raw_pb_outside_sim", pb_uses, "pb.* uses outside annotator/sim/", None),
            ("raw_pb_calls_outside_sim", pb_calls, "pb.*(...) calls outside annotator/sim/", None),
            (
                "pb_importers_outside_sim",
                len(pb_importers),
                "modules importing pb outside sim/",
                pb_importers,
            ),
            ("radon_c_or_worse", len(radon["C"]), "radon blocks rank C or worse", None),
            ("radon_d_or_worse", len(radon["D"]), "radon blocks rank D or worse", radon["D"]),
        ]
        if not args.no_mypy:
            figures.append(("mypy_errors", mypy_errors(repo), "mypy errors over annotator/", None))
        if not args.no_duplicates:
            figures.append(("duplicate_pairs", duplicate_pairs(repo), "duplicates pairs in annotator/", None))
        for key, value, what, detail in figures:
            print(f"{what:45s} {value}")
            for item in detail or []:
                print(f"    {item}")
            record.figure(key, value, "", note=f"{what}, {where}")


if __name__ == "__main__":
    main()
