"""The record every benchmark writes: what was measured, on which code, machine and load.

    from bench.harness import Run

    with Run("peers", config=vars(args), annotator=config) as run:
        ...
        run.ratio("ours_vs_vgn_per_candidate", 1.08, note="CPU ms per candidate, vgn / ours")
        run.figure("ours_ms_per_candidate", 6.1, unit="ms")
        run.table("per_object", [{"object": "duck", "ms_trial": 9.3}, ...])

On entering, a :class:`Run` notes the time, the load average and the process's CPU time; when the
block ends without an exception it writes one JSON record to
``bench/results/<name>/<UTC date>-<short commit>.json`` (``$RG2_BENCH_RESULTS`` or ``results=``
moves the folder; a second run of the same benchmark on the same day and commit replaces the
first) and prints where. A block that raises writes nothing: a failed run is not a measurement.

The record (keys sorted, lists in the order they were added) holds the benchmark's name and what
it measures (the first paragraph of the script's docstring), the command that ran it, the commit and
whether the working tree differed from it, the UTC start time, wall and CPU seconds, the machine
(CPU model, cores, memory, Python, platform), the versions of the libraries the figures depend on,
the load average before and after, the configuration (the script's arguments, the
``AnnotatorConfig`` used: its digest and its changes from the default, and one digest of both), and
the figures, ratios and tables. ``python -m bench.docs`` turns the newest record of each benchmark
into ``docs/performance.md``.

Ratios are the figures that survive a slower or busier machine: each compares two things measured
in the same run (ours against a peer, a candidate against a free step of the gripper, the model
against the model before), so record a ratio for every throughput figure.
"""

from __future__ import annotations

import dataclasses
import datetime
import hashlib
import importlib.metadata
import json
import math
import os
import platform
import re
import resource
import shlex
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from annotator.config import AnnotatorConfig

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results"
RESULTS_ENV = "RG2_BENCH_RESULTS"
SCHEMA = 1
# the libraries whose versions move the figures (physics, geometry, decomposition, the tables)
LIBRARIES = ("rg2-annotator", "pybullet", "numpy", "trimesh", "coacd", "scipy", "manifold3d", "pandas")
# files the bench writes itself: they do not make the measured tree "dirty"
GENERATED = ("bench/results/", "docs/performance.md")
TAG = re.compile(r"^[a-z0-9][a-z0-9-]*$")
NAME = re.compile(r"^[a-z][a-z0-9_]*$")


@dataclasses.dataclass(frozen=True)
class GitState:
    """The commit the working tree is on, and the tracked files that differ from it."""

    commit: str  # 40 hex digits, or "unknown" outside a git checkout
    changed: tuple[str, ...]  # paths relative to the repository, GENERATED excluded

    @property
    def dirty(self) -> bool:
        return bool(self.changed)


def git_state(root: Path = ROOT) -> GitState:
    """The commit of ``root`` and its changed tracked files (untracked files are not looked at)."""

    def git(*args: str) -> str:
        return subprocess.run(
            ["git", "-C", str(root), *args], capture_output=True, text=True, check=True
        ).stdout

    try:
        commit = git("rev-parse", "HEAD").strip()
        status = git("status", "--porcelain", "--untracked-files=no").splitlines()
    except (OSError, subprocess.CalledProcessError):
        return GitState("unknown", ())
    changed = tuple(
        path for path in (line[3:].split(" -> ")[-1] for line in status) if not path.startswith(GENERATED)
    )
    return GitState(commit, changed)


def machine() -> dict[str, Any]:
    """CPU model, cores (all and usable by this process), memory (GiB), Python and platform."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "usable_cores": usable,
        "memory_gib": round(memory, 1),
        "python": platform.python_version(),
        "platform": platform.platform(),
    }


def libraries() -> dict[str, str | None]:
    """Installed versions of LIBRARIES (None: not installed)."""
    out: dict[str, str | None] = {}
    for name in LIBRARIES:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = None
    return out


def digest(data: Any) -> str:
    """SHA-256 (16 hex digits) of ``data`` as canonical JSON."""
    text = json.dumps(_plain(data), sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def changes(config: AnnotatorConfig, base: AnnotatorConfig | None = None) -> dict[str, dict[str, Any]]:
    """The fields of ``config`` that differ from ``base`` (the default): {section: {field: value}}."""
    a, b = config.to_dict(), (base or AnnotatorConfig()).to_dict()
    out: dict[str, dict[str, Any]] = {}
    for section, values in a.items():
        diff = {k: v for k, v in values.items() if b.get(section, {}).get(k) != v}
        if diff:
            out[section] = diff
    return out


def command_line(argv: Sequence[str] | None = None) -> str:
    """How the running benchmark was started, as ``python -m bench.NAME ARGS``."""
    argv = list(sys.argv if argv is None else argv)
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    module = spec.name if spec is not None and spec.name.startswith("bench.") else None
    if module is None and argv and argv[0].endswith(".py"):
        script = Path(argv[0]).resolve()
        if script.parent in (ROOT / "bench", ROOT / "bench" / "experiments"):
            module = ".".join(script.relative_to(ROOT).with_suffix("").parts)
    if module is None:
        return shlex.join(argv)
    return shlex.join(["python", "-m", module, *argv[1:]])


def _about() -> str:
    """The first paragraph of the ``__main__`` module's docstring, on one line."""
    doc = getattr(sys.modules.get("__main__"), "__doc__", None) or ""
    return " ".join(doc.strip().split("\n\n")[0].split())


def _plain(value: Any) -> Any:
    """``value`` as JSON data: numpy scalars and arrays, paths (relative to the repository when in
    it), tuples, dataclasses; NaN and infinities as None."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return _plain(dataclasses.asdict(value))
    if isinstance(value, (str, bool)) or value is None:
        return value
    if isinstance(value, Path):  # inside the repository: relative, so the digest is the checkout's own
        path = value.resolve()
        return path.relative_to(ROOT).as_posix() if path.is_relative_to(ROOT) else str(value)
    if hasattr(value, "tolist"):  # numpy scalar or array
        return _plain(value.tolist())
    if isinstance(value, int):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, (list, tuple, set, frozenset)):
        return [_plain(v) for v in (sorted(value) if isinstance(value, (set, frozenset)) else value)]
    raise TypeError(f"cannot record {type(value).__name__} {value!r}")


def _number(name: str, value: Any) -> float | int | None:
    plain = _plain(value)
    if isinstance(plain, bool) or not (plain is None or isinstance(plain, (int, float))):
        raise TypeError(f"{name}: a figure is a number, not {type(value).__name__} {value!r}")
    return plain


def _cpu_seconds() -> float:
    """User + system CPU seconds of this process and its reaped children."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


class Run:
    """One run of a benchmark; a context manager that writes its record on a clean exit.

    ``name``: the benchmark (``[a-z][a-z0-9_]*``, the results folder's name). ``config``: the
    script's own arguments (JSON-able values; paths become strings). ``annotator``: the
    configuration measured (default ``AnnotatorConfig()``). ``about``: one line on what is
    measured (default: the first paragraph of the ``__main__`` module's docstring). ``command``: how it
    was run (default: from ``sys.argv``). ``results``: the folder of records (default
    ``$RG2_BENCH_RESULTS`` or ``bench/results``). ``tag``: what sets this run apart from the
    benchmark's other runs on the same day and commit (its data set's digest, say); it ends the
    record's file name, and the newest record of each tag is kept apart from the others'.
    """

    def __init__(
        self,
        name: str,
        config: Mapping[str, Any] | None = None,
        *,
        annotator: AnnotatorConfig | None = None,
        about: str | None = None,
        command: str | None = None,
        results: Path | None = None,
        tag: str | None = None,
    ) -> None:
        if not NAME.match(name):
            raise ValueError(f"benchmark name {name!r}: lower case letters, digits and _")
        if tag is not None and not TAG.match(tag):
            raise ValueError(f"record tag {tag!r}: lower case letters, digits and -")
        self.name = name
        self.tag = tag
        self.arguments = _plain(dict(config or {}))
        self.annotator = annotator or AnnotatorConfig()
        self.about = _about() if about is None else about
        self.command = command_line() if command is None else command
        self.results = Path(results or os.environ.get(RESULTS_ENV) or RESULTS)
        self.figures: list[dict[str, Any]] = []
        self.ratios: list[dict[str, Any]] = []
        self.tables: list[dict[str, Any]] = []
        self.path: Path | None = None  # the record, once written

    # --- what a benchmark records ------------------------------------------------------------------

    def figure(
        self,
        name: str,
        value: float,
        unit: str = "",
        *,
        note: str = "",
        spread: Sequence[float] | None = None,
    ) -> None:
        """A measured value in ``unit`` (``"s"``, ``"ms"``, ``"MB"``, ``"%"``, ``""`` for a count);
        ``spread``: its (min, max) over repeats, ``value`` being their median."""
        self.figures.append(self._entry(name, value, note, spread) | {"unit": unit})

    def ratio(
        self, name: str, value: float, *, note: str = "", spread: Sequence[float] | None = None
    ) -> None:
        """A dimensionless ratio of two quantities measured in this run; ``note`` says which over
        which."""
        self.ratios.append(self._entry(name, value, note, spread))

    def table(self, name: str, rows: Sequence[Mapping[str, Any]], *, note: str = "") -> None:
        """Rows of scalars (str, number, bool, None); the columns are the rows' keys in first-seen order."""
        self._check_name(name, self.tables)
        columns = list(dict.fromkeys(k for row in rows for k in row))
        cells = [[_plain(row.get(c)) for c in columns] for row in rows]
        for row in cells:
            for cell in row:
                if isinstance(cell, (list, dict)):
                    raise TypeError(f"table {name}: a cell is a scalar, not {cell!r}")
        self.tables.append({"name": name, "note": note, "columns": columns, "rows": cells})

    def _entry(self, name: str, value: float, note: str, spread: Sequence[float] | None) -> dict[str, Any]:
        self._check_name(name, self.figures + self.ratios)
        entry = {"name": name, "value": _number(name, value), "note": note}
        if spread is not None:
            lo, hi = (_number(name, v) for v in spread)
            entry |= {"min": lo, "max": hi}
        return entry

    @staticmethod
    def _check_name(name: str, taken: list[dict[str, Any]]) -> None:
        if not NAME.match(name):
            raise ValueError(f"figure name {name!r}: lower case letters, digits and _")
        if any(e["name"] == name for e in taken):
            raise ValueError(f"{name!r} recorded twice")

    # --- the record --------------------------------------------------------------------------------

    def __enter__(self) -> Run:
        self._started = datetime.datetime.now(datetime.timezone.utc)
        self._t0, self._cpu0 = time.perf_counter(), _cpu_seconds()
        self._load0 = os.getloadavg()
        return self

    def __exit__(self, kind, exc, tb) -> None:
        if kind is not None:
            return
        record = self.record(
            load_after=os.getloadavg(),
            seconds=time.perf_counter() - self._t0,
            cpu_seconds=_cpu_seconds() - self._cpu0,
        )
        self.path = write_record(record, self.results)
        print(f"record: {self.path}")

    def record(self, *, load_after: Sequence[float], seconds: float, cpu_seconds: float) -> dict[str, Any]:
        """The record as JSON data."""
        git = git_state()
        annotator = self.annotator.to_dict()
        return _plain(
            {
                "schema": SCHEMA,
                "benchmark": self.name,
                **({"tag": self.tag} if self.tag else {}),
                "about": self.about,
                "command": self.command,
                "commit": git.commit,
                "dirty": git.dirty,
                "changed_files": list(git.changed),
                "date": self._started.strftime("%Y-%m-%dT%H:%M:%SZ"),
                "seconds": round(seconds, 3),
                "cpu_seconds": round(cpu_seconds, 3),
                "machine": machine(),
                "libraries": libraries(),
                "load": {
                    "before": [round(v, 2) for v in self._load0],
                    "after": [round(v, 2) for v in load_after],
                },
                "config": {
                    "arguments": self.arguments,
                    "annotator_digest": digest(annotator),
                    "annotator_changes": changes(self.annotator),
                    "digest": digest({"annotator": annotator, "arguments": self.arguments}),
                },
                "figures": self.figures,
                "ratios": self.ratios,
                "tables": self.tables,
            }
        )


def record_path(record: Mapping[str, Any], results: Path) -> Path:
    """``results/<benchmark>/<UTC date>-<short commit>[-<tag>].json``."""
    tag = f"-{record['tag']}" if record.get("tag") else ""
    return results / record["benchmark"] / f"{record['date'][:10]}-{record['commit'][:7]}{tag}.json"


def record_key(record: Mapping[str, Any]) -> str:
    """What a record is the newest of: its benchmark, with its tag where it has one."""
    return f"{record['benchmark']}-{record['tag']}" if record.get("tag") else str(record["benchmark"])


def dumps(record: Mapping[str, Any]) -> str:
    """The record's file content: JSON, keys sorted, one entry a line."""
    return json.dumps(record, sort_keys=True, indent=1, allow_nan=False) + "\n"


def write_record(record: Mapping[str, Any], results: Path) -> Path:
    """Write ``record`` (atomically: a reader never sees half a file); its path."""
    path = record_path(record, results)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_text(dumps(record))
    os.replace(tmp, path)
    return path


def read_records(results: Path = RESULTS) -> list[dict[str, Any]]:
    """Every record under ``results`` (unreadable files are an error, not skipped)."""
    out = []
    for path in sorted(results.glob("*/*.json")):
        try:
            record = json.loads(path.read_text())
        except ValueError as exc:
            raise ValueError(f"{path}: not a bench record ({exc})") from exc
        if record.get("schema") != SCHEMA or record.get("benchmark") != path.parent.name:
            raise ValueError(f"{path}: not a schema-{SCHEMA} record of {path.parent.name!r}")
        out.append(record)
    return out


def newest(records: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """The newest record of each benchmark and tag (by start time, then commit): {key: record}
    (:func:`record_key`)."""
    out: dict[str, dict[str, Any]] = {}
    for record in sorted(records, key=lambda r: (r["date"], r["commit"])):
        out[record_key(record)] = dict(record)
    return out
