"""A small declarative checker for JSON documents the tool reads back (the manifest, the journal).

A schema is a tree of :class:`Check` objects; ``check(value, where)`` raises :class:`Invalid`
naming the first bad place (``objects_done['mug'].stats.n: expected an integer``). Checks are
plain data, so a document's shape is written once, read top to bottom, and every reader of it
gets the same answer.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

INT64_MIN, INT64_MAX = -(2**63), 2**63 - 1


class Invalid(ValueError):
    """The document is not of the expected shape; the message names where and why."""


class Check:
    """One node of a schema."""

    def check(self, value: Any, where: str) -> None:  # pragma: no cover - interface
        raise NotImplementedError


@dataclass(frozen=True)
class Str(Check):
    """A string, optionally one accepted by ``valid`` (described by ``what``)."""

    valid: Callable[[str], bool] | None = None
    what: str = "a string"

    def check(self, value: Any, where: str) -> None:
        if not isinstance(value, str) or (self.valid is not None and not self.valid(value)):
            raise Invalid(f"{where}: expected {self.what}, found {_show(value)}")


@dataclass(frozen=True)
class Int(Check):
    """An integer (not a bool) within ``lo..hi`` (int64 by default)."""

    lo: int = INT64_MIN
    hi: int = INT64_MAX

    def check(self, value: Any, where: str) -> None:
        if isinstance(value, bool) or not isinstance(value, int) or not self.lo <= value <= self.hi:
            raise Invalid(f"{where}: expected an integer in {self.lo}..{self.hi}, found {_show(value)}")


@dataclass(frozen=True)
class Num(Check):
    """A finite number (int or float, not a bool); ``optional`` also admits null."""

    optional: bool = False

    def check(self, value: Any, where: str) -> None:
        if value is None and self.optional:
            return
        ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
        if not ok:
            what = "a finite number or null" if self.optional else "a finite number"
            raise Invalid(f"{where}: expected {what}, found {_show(value)}")


@dataclass(frozen=True)
class Nullable(Check):
    """Null, or a value that passes ``check``."""

    check_: Check

    def check(self, value: Any, where: str) -> None:
        if value is not None:
            self.check_.check(value, where)


@dataclass(frozen=True)
class Any_(Check):
    """Anything JSON holds (the value is not interpreted by the tool)."""

    def check(self, value: Any, where: str) -> None:
        return None


@dataclass(frozen=True)
class Map(Check):
    """A JSON object whose keys pass ``key`` and whose values pass ``value``."""

    value: Check
    key: Str = field(default_factory=Str)

    def check(self, value: Any, where: str) -> None:
        if not isinstance(value, dict):
            raise Invalid(f"{where}: expected a JSON object, found {_show(value)}")
        for k, v in value.items():
            self.key.check(k, f"{where} key")
            self.value.check(v, f"{where}[{k!r}]")


@dataclass(frozen=True)
class Seq(Check):
    """A JSON array whose items pass ``item``."""

    item: Check

    def check(self, value: Any, where: str) -> None:
        if not isinstance(value, list):
            raise Invalid(f"{where}: expected a JSON array, found {_show(value)}")
        for i, v in enumerate(value):
            self.item.check(v, f"{where}[{i}]")


@dataclass(frozen=True)
class Record(Check):
    """A JSON object with ``required`` fields, ``optional`` ones, and (unless ``open``) no others."""

    required: dict[str, Check]
    optional: dict[str, Check] = field(default_factory=dict)
    open: bool = False

    def check(self, value: Any, where: str) -> None:
        if not isinstance(value, dict):
            raise Invalid(f"{where}: expected a JSON object, found {_show(value)}")
        for name, check in self.required.items():
            if name not in value:
                raise Invalid(f"{where}: the field {name!r} is missing")
            check.check(value[name], f"{where}.{name}")
        for name, check in self.optional.items():
            if name in value:
                check.check(value[name], f"{where}.{name}")
        if not self.open:
            unknown = sorted(set(value) - set(self.required) - set(self.optional))
            if unknown:
                raise Invalid(f"{where}: unknown field(s) {unknown}")


def _show(value: Any) -> str:
    text = repr(value)
    return f"{type(value).__name__} {text[:40]}{'...' if len(text) > 40 else ''}"
