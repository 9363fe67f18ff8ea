"""Configuration variants for the benchmarks: ``"it100:physics.solver_iterations=100,shake_paired=false"``.

A variant is a comma-separated list of ``section.field=value`` (or ``field=value`` when the field
name is unique across sections) applied to the default configuration; values are TOML literals
(``100``, ``0.5``, ``false``, ``"simulated"``). An optional ``name:`` prefix labels it in the output.
Used by ``bench.fidelity --variant``, ``bench.peers --variant`` and
``bench.experiments.light_threshold --set``.
"""

from __future__ import annotations

import dataclasses
import sys

from annotator.config import AnnotatorConfig

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib


def parse_variant(spec: str, base: AnnotatorConfig | None = None) -> tuple[str, AnnotatorConfig]:
    """``(label, configuration)`` for ``spec``; exits with one line on an unknown field or value."""
    base = base or AnnotatorConfig()
    label, _, body = spec.rpartition(":") if ":" in spec.split("=", 1)[0] else ("", "", spec)
    overrides: dict[str, dict] = {}
    for item in filter(None, (s.strip() for s in body.split(","))):
        key, sep, text = item.partition("=")
        if not sep:
            raise SystemExit(f"variant {spec!r}: expected FIELD=VALUE, got {item!r}")
        section, _, name = key.rpartition(".")
        sections = (
            [section]
            if section
            else [
                f.name
                for f in dataclasses.fields(base)
                if name in {g.name for g in dataclasses.fields(getattr(base, f.name))}
            ]
        )
        if len(sections) != 1:
            raise SystemExit(f"variant {spec!r}: {key!r} names {len(sections)} configuration fields")
        try:
            value = tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError:
            value = text  # a bare word is a string
        overrides.setdefault(sections[0], {})[name] = value
    current = base.to_dict()
    for section, values in overrides.items():
        current.setdefault(section, {}).update(values)
    try:
        config = AnnotatorConfig.from_dict(current)
    except ValueError as exc:
        raise SystemExit(f"variant {spec!r}: {exc}") from exc
    return label or body, config
