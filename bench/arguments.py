"""Arguments of the benchmarks, checked as the commands check theirs: a bad value is one line on
stderr naming the option and the range, exit 2, before any work.

    from bench.arguments import Parser, count, existing_file, existing_folder

    def parser() -> Parser:
        parser = Parser(description=__doc__.splitlines()[0])
        parser.add_argument("--rounds", type=count(0, 100_000), default=40)
        parser.add_argument("--objects", type=existing_folder, required=True)
        return parser

Every benchmark builds its options in a function ``parser()`` of its module (its ``main`` parses
with it), so that ``tests/test_bench.py`` checks each one's refusals without running it. Counts,
sizes, fractions and paths take one of the types below; the bounds of counts are the commands'
(``N_MAX``, ``WORKERS_MAX``).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn

SEED_MAX = 2**63 - 1  # seeds are stored as int64, as the commands' --seed
N_MAX = 1_000_000  # candidates per object or scene, as annotate's --n
WORKERS_MAX = 1024  # as the commands' --workers
REPEAT_MAX = 1000  # repeats of a measurement


class Parser(argparse.ArgumentParser):
    """argparse whose errors are one line, ``prog: error: message`` (exit 2), without the usage
    block (``--help`` still prints it)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


def count(low: int, high: int | None = None) -> Callable[[str], int]:
    """An argparse type: a whole number in ``low .. high`` (``high`` None: no upper bound)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
        if value < low or (high is not None and value > high):
            span = f"{low} .. {high:,}" if high is not None else f"at least {low}"
            raise argparse.ArgumentTypeError(f"{value} is not in {span}")
        return value

    parse.__name__ = "count"
    return parse


def number(
    low: float, high: float, *, low_open: bool = False, high_open: bool = False
) -> Callable[[str], float]:
    """An argparse type: a finite number in ``low .. high`` (``low_open``/``high_open``: the bound
    itself excluded)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        below = value <= low if low_open else value < low
        above = value >= high if high_open else value > high
        if not math.isfinite(value) or below or above:
            span = f"{'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"
            raise argparse.ArgumentTypeError(f"{text} is not in {span}")
        return value

    parse.__name__ = "number"
    return parse


def fraction(text: str) -> float:
    """An argparse type: a share, 0 .. 1."""
    return number(0.0, 1.0)(text)


def seed(text: str) -> int:
    """An argparse type: a seed, 0 .. 2^63 - 1."""
    return count(0, SEED_MAX)(text)


def existing_folder(text: str) -> Path:
    """An argparse type: a folder that exists."""
    path = Path(text)
    if not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: {'not a folder' if path.exists() else 'no such folder'}")
    return path


def existing_file(text: str) -> Path:
    """An argparse type: a file that exists."""
    path = Path(text)
    if not path.is_file():
        raise argparse.ArgumentTypeError(f"{text}: {'not a file' if path.exists() else 'no such file'}")
    return path


def writable_folder(text: str) -> Path:
    """An argparse type: a folder that exists or can be made, and takes a file."""
    from annotator.files import probe_writable

    path = Path(text)
    try:
        probe_writable(path)
    except OSError as exc:
        raise argparse.ArgumentTypeError(f"{text}: cannot be written ({exc.strerror or exc})") from None
    return path


def writable_file(text: str) -> Path:
    """An argparse type: a file to write (or append to), whose folder exists or can be made and
    takes a file; not a folder."""
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: is a folder; give a file name")
    writable_folder(str(path.parent))
    return path
