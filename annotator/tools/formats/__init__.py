"""The formats ``annotator export`` writes, one module each in this package, found by listing it: a
module defines ``EXPORTER`` (an :class:`Exporter`: the format's name, what it exports, the folders
it makes, what it needs and its writer), so a new format is one module here and its test.

Object formats (``unit = "object"``) get one call of ``write_object`` per object (its rows, their
base poses and what the file says of the object) and, once, ``finish``; scene formats (``unit =
"scene"``) get every scene of the run at once (``write_scenes``). The export's driver is
:mod:`annotator.tools.export` (objects) or :mod:`annotator.tools.export_scenes` (scenes). Every
file goes through the export folder's one output writer (``folder.write(name, fill)``, or
``folder.write_path`` where a writer takes paths): written whole, recorded with its SHA-256 in
``_export.json``, a file the export did not write never replaced. A format module imports what its
writer needs inside the writer: the command line lists the formats without loading them.
"""

from __future__ import annotations

import functools
import importlib
import pkgutil
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Exporter:
    """A format: ``name`` (``--format``), ``unit`` (``object``: a file per object; ``scene``: a run's
    scenes), ``help`` (what ``--format`` says of it), ``folders`` it makes in ``--out`` (deepest
    first: ``--overwrite`` removes them once empty), ``needs`` a module (and the line that says
    how to install it), ``balance`` (it takes ``--balance``), ``order`` (its place in ``--format``'s
    list) and its writer: ``write_object`` and ``finish`` for an object format, ``write_scenes``
    for a scene format."""

    name: str
    unit: str
    help: str
    order: int
    folders: tuple[str, ...] = ()
    needs: tuple[str, str] | None = None
    balance: bool = False
    write_object: Callable[..., Any] | None = None
    finish: Callable[..., Any] | None = None
    write_scenes: Callable[..., Any] | None = None


@functools.cache
def exporters() -> dict[str, Exporter]:
    """Every format of this package, by name, in ``--format``'s order."""
    found = []
    for info in pkgutil.iter_modules(__path__):
        module = importlib.import_module(f"{__name__}.{info.name}")
        exporter = getattr(module, "EXPORTER", None)
        if isinstance(exporter, Exporter):
            found.append(exporter)
    names = [e.name for e in found]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ValueError(f"export formats named twice: {twice}")
    return {e.name: e for e in sorted(found, key=lambda e: (e.order, e.name))}


def of_unit(unit: str) -> dict[str, Exporter]:
    """The formats that export ``unit`` (``object``, ``scene``)."""
    return {name: e for name, e in exporters().items() if e.unit == unit}


def folders() -> tuple[str, ...]:
    """Every folder an export makes, deepest first (removed once empty, in this order)."""
    every = {f for e in exporters().values() for f in e.folders}
    return tuple(sorted(every, key=lambda f: (-f.count("/"), f)))


def format_help() -> str:
    """What ``--format`` says: the object formats, then those of scene labels."""
    objects = "; ".join(f"{e.name}: {e.help}" for e in of_unit("object").values())
    scenes = [f"{e.name} ({e.help})" for e in of_unit("scene").values()]
    listed = ", ".join(scenes[:-1]) + (" or " if len(scenes) > 1 else "") + scenes[-1] if scenes else ""
    return f"{objects}; for labels of annotate --scenes: {listed}." if listed else f"{objects}."
