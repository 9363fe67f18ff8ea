"""Each thing on its floor: a package or top-level module of ``annotator`` imports only from its
own package and from floors below its own (docs/architecture.md, "Floors"), checked statically over
every ``import`` in ``annotator/``, function-local ones included (a lazy import is a dependency all
the same). The imports that still run up or across the floors are listed in ``KNOWN`` and may only
go: a new one fails, and so does one listed that is gone (remove it from the list)."""

from __future__ import annotations

import ast
import collections
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "annotator"

# floor: the packages and top-level modules on it (the package root, ``annotator/__init__.py``,
# is "annotator"). The same table is docs/architecture.md's.
FLOORS: dict[int, tuple[str, ...]] = {
    0: ("annotator", "config", "files", "geometry", "outcome", "paths", "rng", "schema", "versions"),
    1: ("agreement", "confidence", "grippers", "label_table", "sampler"),
    2: ("sim",),
    3: ("objects", "render", "trial"),
    4: ("k_trials", "store"),
    5: ("dataset", "label_row"),
    6: ("cell",),
    7: ("scenes",),
    8: ("pipeline", "policies"),
    9: ("learn", "seed_scene", "tools"),
    10: ("cli",),
    11: ("entry",),
}
FLOOR_OF = {unit: floor for floor, units in FLOORS.items() for unit in units}

# (importing module, imported unit): the imports against the floors today, each to be removed.
KNOWN: set[tuple[str, str]] = {
    # ``python -m annotator.seed_scene`` runs the ``annotator scene`` command
    ("annotator.seed_scene.__main__", "cli"),
}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _unit(module: str) -> str:
    """The floor table's name for ``annotator.x.y``: ``x`` (``annotator`` for the root)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "annotator"


def _imported(tree: ast.AST) -> set[str]:
    """Every ``annotator`` module an import statement in ``tree`` names (``from annotator import
    x`` names ``annotator.x`` when ``x`` is a module, else the root)."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.split(".")[0] == "annotator"}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            if node.module == "annotator":
                for alias in node.names:
                    sub = f"annotator.{alias.name}"
                    is_module = (PACKAGE / alias.name).is_dir() or (PACKAGE / f"{alias.name}.py").is_file()
                    out.add(sub if is_module else "annotator")
            elif node.module.split(".")[0] == "annotator":
                out.add(node.module)
    return out


def floor_violations() -> dict[tuple[str, str], list[str]]:
    """{(importing module, imported unit): [import lines]} for every import that is not down."""
    found: dict[tuple[str, str], list[str]] = collections.defaultdict(list)
    for path in sorted(PACKAGE.rglob("*.py")):
        module = _module_name(path)
        mine = _unit(module)
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for target in sorted(_imported(tree)):
            theirs = _unit(target)
            if theirs == mine:
                continue
            if FLOOR_OF[theirs] >= FLOOR_OF[mine]:
                found[(module, theirs)].append(f"{module} imports {target}")
    return found


def test_every_package_has_a_floor():
    units = {_unit(_module_name(p)) for p in PACKAGE.rglob("*.py")}
    assert units - set(FLOOR_OF) == set(), "put it on a floor in FLOORS and docs/architecture.md"
    assert set(FLOOR_OF) - units == set(), "a floor names a package that is gone"


def test_imports_run_down_the_floors_only():
    found = floor_violations()
    new = sorted(line for key, lines in found.items() if key not in KNOWN for line in lines)
    assert new == [], "imports up or across the floors:\n" + "\n".join(new)
    gone = sorted(KNOWN - set(found))
    assert gone == [], f"fixed: remove {gone} from KNOWN"


def test_the_docs_floors_are_the_tests():
    """docs/architecture.md's table ``| floor | packages | ... |`` lists the same floors."""
    text = (REPO / "docs" / "architecture.md").read_text(encoding="utf-8")
    section = text.split("## Floors", 1)[1].split("\n## ", 1)[0]
    documented = {}
    for line in section.splitlines():
        row = re.match(r"\|\s*(\d+)\s*\|([^|]*)\|", line)
        if row:
            documented[int(row.group(1))] = tuple(sorted(re.findall(r"`([a-z_]+)`", row.group(2))))
    assert documented == {floor: tuple(sorted(units)) for floor, units in FLOORS.items()}


def test_no_two_classes_in_the_package_share_a_name():
    where = collections.defaultdict(list)
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ClassDef):
                where[node.name].append(f"{path.relative_to(REPO)}:{node.lineno}")
    assert {name: places for name, places in where.items() if len(places) > 1} == {}
