"""Per-object physical properties from a sidecar ``objects.toml`` at the root of the objects folder.

Each table is keyed by an object id or a glob over object ids (``fnmatch``: ``*``, ``?``,
``[ab]``); every table whose key matches applies, in file order, a later value overriding an
earlier one. A multi-part file's parts (``file/part``) also match tables keyed by the file's id::

    ["mug"]
    mass = 0.35            # kg; overrides the density model (inertia scaled to match)
    ["ycb/*"]
    density = 300          # kg/m^3 for the solid model
    friction = 0.8         # lateral friction coefficient of the object
    scale = 0.001          # file units -> metres (overrides --scale for these objects)
    mass_model = "shell"   # "auto" (default), "solid" or "shell"
    ["scenes/kitchen"]
    merge_parts = true     # keep a multi-node .glb as one object

A broken sidecar is a usage error (ObjectDiscoveryError), named in one line.
"""

from __future__ import annotations

import dataclasses
import fnmatch
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from annotator.objects.errors import ObjectDiscoveryError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

SIDECAR_NAME = "objects.toml"
MASS_MODELS = ("auto", "solid", "shell")


@dataclass(frozen=True)
class ObjectProperties:
    """What the sidecar sets for one object; ``None``: not set (the configuration decides)."""

    mass: float | None = None
    density: float | None = None
    friction: float | None = None
    scale: float | None = None
    mass_model: str | None = None
    shell_thickness: float | None = None
    merge_parts: bool | None = None

    def as_dict(self) -> dict[str, Any]:
        """The fields that are set, for the digest and the geometry record."""
        return {k: v for k, v in dataclasses.asdict(self).items() if v is not None}


_POSITIVE = ("mass", "density", "scale", "shell_thickness")


def _check(key: str, values: Any, path: Path) -> ObjectProperties:
    where = f"{path.name} [{key!r}]"
    if not isinstance(values, dict):
        raise ObjectDiscoveryError(f"{where}: expected a table of properties, got {type(values).__name__}")
    known = {f.name for f in dataclasses.fields(ObjectProperties)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise ObjectDiscoveryError(f"{where}: unknown field(s) {unknown}; known: {sorted(known)}")
    for name, value in values.items():
        if name == "mass_model":
            if value not in MASS_MODELS:
                raise ObjectDiscoveryError(f"{where}: mass_model must be one of {MASS_MODELS}, got {value!r}")
        elif name == "merge_parts":
            if not isinstance(value, bool):
                raise ObjectDiscoveryError(f"{where}: merge_parts must be true or false, got {value!r}")
        else:
            ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
            if not ok or (name in _POSITIVE and value <= 0) or (name == "friction" and value < 0):
                rule = "a number >= 0" if name == "friction" else "a positive number"
                raise ObjectDiscoveryError(f"{where}: {name} must be {rule}, got {value!r}")
    typed: dict[str, Any] = {
        k: (float(v) if k not in ("mass_model", "merge_parts") else v) for k, v in values.items()
    }
    return ObjectProperties(**typed)


@dataclass(frozen=True)
class Sidecar:
    """The parsed ``objects.toml`` (empty when there is none): (key, properties) in file order."""

    entries: tuple[tuple[str, ObjectProperties], ...] = ()
    path: Path | None = None

    @classmethod
    def load(cls, root: Path) -> Sidecar:
        path = Path(root) / SIDECAR_NAME
        if not path.is_file():
            return cls()
        try:
            with path.open("rb") as fh:
                data = tomllib.load(fh)
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise ObjectDiscoveryError(f"{path}: not valid TOML ({exc})") from None
        return cls(tuple((k, _check(k, v, path)) for k, v in data.items()), path)

    def for_object(self, *ids: str) -> ObjectProperties:
        """The merged properties of the object known by any of ``ids`` (its id, its file's id)."""
        merged: dict[str, Any] = {}
        for key, props in self.entries:
            if any(fnmatch.fnmatchcase(i, key) for i in ids):
                merged.update(props.as_dict())
        return ObjectProperties(**merged)
