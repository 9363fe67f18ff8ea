"""No import cycle among the modules of ``annotator/``: read statically (``ast``) from the files
(:func:`bench.structure.import_graph`), with the imports inside functions counted (they run too)
and those under ``if TYPE_CHECKING:`` too (a module that names another's types for the checker
depends on it all the same: a circle of them is a circle to read)."""

from __future__ import annotations

from pathlib import Path

from bench.structure import cycles as import_cycles
from bench.structure import import_graph as package_graph

PACKAGE = Path(__file__).resolve().parent.parent / "annotator"


def import_graph(root: Path = PACKAGE) -> dict[str, set[str]]:
    """Module -> the package's modules it imports, at runtime or for type checking only
    (``from a.b import c``: ``a.b.c`` when that is a module, else ``a.b``)."""
    return package_graph(root).all()


def test_the_graph_sees_the_package():
    graph = import_graph()
    assert "annotator.outcome" in graph["annotator.label_row"]
    assert "annotator.label_table" in graph["annotator.dataset"]
    assert "annotator.schema" in graph["annotator.label_table"]
    assert "annotator.objects.model" in graph["annotator.objects.bodies"]  # a type-only import
    assert import_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


# Cycles known and being removed (none today): each entry goes when its cycle does, and this test says so.
BEING_REMOVED: list[list[str]] = []


def test_no_import_cycle_in_the_package():
    cycles = import_cycles(import_graph())
    new = [c for c in cycles if c not in BEING_REMOVED]
    assert new == [], "import cycles: " + "; ".join(" <-> ".join(c) for c in new)
    gone = [c for c in BEING_REMOVED if c not in cycles]
    assert gone == [], f"no longer cycles, drop them from BEING_REMOVED: {gone}"


if __name__ == "__main__":  # python tests/test_import_cycles.py: list the cycles
    for cycle in import_cycles(import_graph()):
        print(" <-> ".join(cycle))
