"""Types checked: mypy over annotator/ (the configuration in pyproject.toml) inside pytest, so CI's
one test command runs it. The modules of :data:`CLEAN` have no error at all (a new one fails with
its text); every other package is held to its recorded count (tests/mypy_baseline.json): a rise
fails, and so does a fall until it is recorded (``python -m tests.test_types`` writes the lower
counts), so the baseline only goes down.

mypy runs once per test run, its cache in pytest's cache folder (``.pytest_cache``, ignored by git;
in pytest's temporary folder when the cache is off), so an unchanged tree is checked again in a few
seconds and the work tree gets no ``.mypy_cache``.
"""

from __future__ import annotations

import collections
import json
import re
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
BASELINE = REPO / "tests" / "mypy_baseline.json"

# Type-clean: no mypy error, and (pyproject's [[tool.mypy.overrides]]) every function annotated and
# its body checked; paths from the repository's root, a folder ending in "/".
CLEAN = (
    "annotator/sim/",
    "annotator/store/",
    "annotator/grippers/",
    "annotator/objects/",
    "annotator/dataset.py",
    "annotator/pipeline/",
)

_ERROR = re.compile(r"^(annotator/[^:]+\.py):\d+: error: ")


@dataclass(frozen=True, repr=False)
class MypyErrors:
    """mypy's errors over the package: ``lines`` each error's line of text, ``by_file`` the lines
    per file (path from the repository's root)."""

    lines: list[str]
    by_file: dict[str, list[str]]

    def __repr__(self) -> str:  # a failure shows the errors it is about, not every error
        return f"MypyErrors({len(self.lines)} errors in {len(self.by_file)} files)"

    def per_package(self) -> collections.Counter[str]:
        """Errors per package or top-level module of annotator/ (``pipeline``, ``config``)."""
        return collections.Counter(_package(path) for path, lines in self.by_file.items() for _ in lines)

    def in_clean(self) -> list[str]:
        return [line for path in sorted(self.by_file) if is_clean(path) for line in self.by_file[path]]


def _package(path: str) -> str:
    return Path(path).relative_to("annotator").parts[0].removesuffix(".py")


def is_clean(path: str) -> bool:
    return any(path.startswith(c) if c.endswith("/") else path == c for c in CLEAN)


def run_mypy(cache_dir: Path) -> MypyErrors:
    """mypy from the repository's root (``[tool.mypy]`` of pyproject.toml), its cache in ``cache_dir``."""
    api = pytest.importorskip("mypy.api")
    config = ["--config-file", str(REPO / "pyproject.toml")]
    stdout, stderr, status = api.run([*config, "--no-error-summary", "--cache-dir", str(cache_dir)])
    lines = [line for line in stdout.splitlines() if ": error:" in line]
    assert status in (0, 1) and (status == 0) == (not lines), f"mypy did not run (exit {status}):\n{stderr}"
    by_file: dict[str, list[str]] = collections.defaultdict(list)
    for line in lines:
        m = _ERROR.match(line)
        assert m, f"an error outside the package's files: {line}"
        by_file[m.group(1)].append(line)
    return MypyErrors(lines, dict(by_file))


def read_baseline() -> dict[str, int]:
    return json.loads(BASELINE.read_text())["errors"]


@pytest.fixture(scope="module")
def mypy_errors(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> MypyErrors:
    cache = getattr(request.config, "cache", None)
    cache_dir = cache.mkdir("mypy") if cache is not None else tmp_path_factory.mktemp("mypy-cache")
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(REPO)
        return run_mypy(cache_dir)


def test_clean_modules_exist():
    """Every entry of :data:`CLEAN` names a module or package that is there (the list cannot
    silently cover nothing)."""
    missing = [c for c in CLEAN if not (REPO / c).exists() or (REPO / c).is_dir() != c.endswith("/")]
    assert missing == []


@pytest.mark.slow
def test_clean_modules_have_no_mypy_error(mypy_errors):
    """The modules of :data:`CLEAN` are type-clean: any error there fails, with its text."""
    errors = mypy_errors.in_clean()
    assert errors == [], f"{len(errors)} mypy error(s) in the type-clean modules:\n" + "\n".join(errors)


@pytest.mark.slow
def test_mypy_errors_per_package_only_go_down(mypy_errors):
    """A package with more errors than its baseline fails (fix them, or the change that made them);
    one with fewer fails until the lower count is recorded (``python -m tests.test_types``)."""
    baseline, counts = read_baseline(), mypy_errors.per_package()
    risen = {p: (n, baseline.get(p, 0)) for p, n in sorted(counts.items()) if n > baseline.get(p, 0)}
    by_file = sorted(mypy_errors.by_file.items())
    shown = [line for path, lines in by_file if _package(path) in risen for line in lines]
    assert risen == {}, "more mypy errors than recorded (now, baseline):\n" + "\n".join([str(risen), *shown])
    fallen = {p: (counts[p], n) for p, n in sorted(baseline.items()) if counts[p] < n}
    assert fallen == {}, (
        f"fewer mypy errors than recorded (now, baseline): {fallen}; record them with "
        "`python -m tests.test_types`"
    )


def test_baseline_is_only_for_packages_not_clean():
    """A package of :data:`CLEAN` has no count in the baseline (it is held at zero), and no count
    is zero (a package at zero is left out)."""
    baseline = read_baseline()
    assert not [p for p in baseline if is_clean(f"annotator/{p}/") or is_clean(f"annotator/{p}.py")]
    assert all(n > 0 for n in baseline.values())


def record(cache_dir: Path) -> int:
    """Write the baseline's lower counts (a package at zero is dropped); refuses while any count
    rose or a clean module has an error. Returns the exit status."""
    errors = run_mypy(cache_dir)
    baseline, counts = read_baseline(), errors.per_package()
    risen = {p: n for p, n in counts.items() if n > baseline.get(p, 0)}
    if risen or errors.in_clean():
        print(f"not recorded: errors rose {risen} or are in the clean modules", file=sys.stderr)
        print("\n".join(errors.in_clean()), file=sys.stderr)
        return 1
    data = json.loads(BASELINE.read_text())
    data["errors"] = {p: counts[p] for p in sorted(baseline) if counts[p] > 0}
    BASELINE.write_text(json.dumps(data, indent=2) + "\n")
    print(f"recorded {sum(data['errors'].values())} errors: {data['errors']}")
    return 0


if __name__ == "__main__":
    import os
    import tempfile

    os.chdir(REPO)
    with tempfile.TemporaryDirectory(prefix="mypy-cache-") as tmp:
        sys.exit(record(Path(tmp)))
