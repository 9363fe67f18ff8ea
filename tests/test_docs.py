"""The documentation stays true: a project that stands alone, a short README, code blocks that run.

- Nothing in the repository points outside it: no paths to planning notes that are not part of
  the project, no tracker numbers, no words about when or where something was measured instead
  of the command that measured it.
- A LICENSE that says what pyproject says; a README of at most ~250 lines that holds the two
  commands CI runs; relative links and anchors that resolve; tests the docs name that exist;
  configuration comments of at most two lines per field, pointing to decision records that exist.
- Every ```python block of README.md, CHANGELOG.md and docs/ runs, as written, in a fresh
  interpreter, in a folder prepared the way the docs assume (see :func:`docs_folder`).
"""

from __future__ import annotations

import ast
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
README_MAX_LINES = 250
CHANGELOG = REPO / "CHANGELOG.md"
DOC_FILES = sorted(p for p in [README, CHANGELOG, *(REPO / "docs").rglob("*.md")] if p.is_file())

# What must not appear in any tracked file. The patterns are written so that this file does not
# match them itself (a character class around one letter).
FORBIDDEN: dict[str, re.Pattern[str]] = {
    "a path to planning notes outside the repository": re.compile(r"shared[/]"),
    "the design notes": re.compile(r"DESIGN[.]md"),
    "the robot-facts notes": re.compile(r"ROBOT[_]FACTS"),
    "the style notes": re.compile(r"STYLE[.]md"),
    "a tracker number (cite the docs page instead)": re.compile(r"\bissues?[ -]?#?[0-9]", re.IGNORECASE),
    "a working period instead of a command": re.compile(r"s[e]ssions?\b", re.IGNORECASE),
    "the machine instead of a command": re.compile(r"\bthis V[M]\b", re.IGNORECASE),
    "a numbered item of planning notes": re.compile(r"\bpitfal[l] [0-9]", re.IGNORECASE),
}
# Unrelated words a pattern catches, allowed explicitly (file, exact text): none so far.
ALLOWED: set[tuple[str, str]] = set()
# Directories that are never part of the project, for a tree without git.
NOT_PROJECT = {".git", ".venv", "venv", "__pycache__", ".pytest_cache", ".ruff_cache", "build", ".cache"}

# The sections of annotator/config.py whose comments are kept to two lines per field here (the
# others' owners keep theirs: GripperConfig in the gripper docs, ObjectConfig in the objects docs).
SHORT_SECTIONS = (
    "PhysicsConfig",
    "SamplerConfig",
    "ProtocolConfig",
    "RobustConfig",
    "CellConfig",
    "KinectConfig",
)
MAX_FIELD_COMMENT_LINES = 2


def project_files() -> list[Path]:
    """Every file of the project: what git tracks, or the tree without build and cache folders."""
    try:
        out = subprocess.run(
            ["git", "-C", str(REPO), "ls-files", "-z"], capture_output=True, check=True, timeout=60
        ).stdout
        names = [n for n in out.decode().split("\0") if n]
    except (OSError, subprocess.CalledProcessError):
        names = []
    if names:
        return [REPO / n for n in names if (REPO / n).is_file()]
    return [
        p
        for p in REPO.rglob("*")
        if p.is_file() and not (set(p.relative_to(REPO).parts) & NOT_PROJECT) and "egg-info" not in str(p)
    ]


def test_nothing_points_outside_the_project():
    """Grep every project file for the patterns above; list each hit as ``path:line: text``."""
    files = project_files()
    assert len(files) > 50, f"found only {len(files)} project files under {REPO}"
    hits = []
    for path in files:
        data = path.read_bytes()
        if b"\0" in data:  # binary (pictures, meshes in binary formats)
            continue
        rel = path.relative_to(REPO).as_posix()
        for number, line in enumerate(data.decode("utf-8", errors="replace").splitlines(), 1):
            for what, pattern in FORBIDDEN.items():
                for match in pattern.finditer(line):
                    if (rel, match.group(0)) not in ALLOWED:
                        hits.append(f"{rel}:{number}: {what}: {line.strip()[:140]}")
    assert not hits, f"{len(hits)} reference(s) to things outside the project:\n" + "\n".join(hits)


def test_license_is_mit_as_pyproject_says():
    text = (REPO / "LICENSE").read_text()
    assert text.startswith("MIT License") and "rg2-annotator contributors" in text
    assert "WITHOUT WARRANTY OF ANY KIND" in text
    assert re.search(r'license\s*=\s*\{\s*text\s*=\s*"MIT"', (REPO / "pyproject.toml").read_text())


def test_readme_is_short_and_holds_the_commands_ci_runs():
    lines = README.read_text().splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines (at most {README_MAX_LINES})"
    ci = (REPO / ".ci" / "run").read_text().splitlines()
    marker = next(i for i, line in enumerate(ci) if "the README's test command, verbatim" in line)
    test_command = next(line for line in ci[marker + 1 :] if line.startswith("python3 -m venv"))
    assert test_command in lines, "the README's test command is not the one .ci/run runs"
    main = "annotate --objects objects/ --n 500"
    assert any(line.startswith("python3 -m venv") and line.endswith(main) for line in lines)


# ----------------------------------------------------------------------------------- links


def _slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[`*]", "", heading.strip().lower())
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    anchors: set[str] = set()
    in_code = False
    for line in path.read_text().splitlines():
        if line.lstrip().startswith("```"):
            in_code = not in_code
        elif not in_code and line.startswith("#"):
            slug = _slug(line.lstrip("#"))
            k, name = 1, slug
            while name in anchors:  # GitHub numbers repeated headings
                name, k = f"{slug}-{k}", k + 1
            anchors.add(name)
    return anchors


LINK = re.compile(r"\]\(([^)\s]+)\)")


def _links(path: Path) -> list[tuple[int, str]]:
    out, in_code = [], False
    for number, line in enumerate(path.read_text().splitlines(), 1):
        if line.lstrip().startswith("```"):
            in_code = not in_code
        elif not in_code:
            out += [(number, target) for target in LINK.findall(line)]
    return out


@pytest.mark.parametrize("doc", DOC_FILES, ids=lambda p: p.relative_to(REPO).as_posix())
def test_relative_links_and_anchors_resolve(doc: Path):
    broken = []
    for number, target in _links(doc):
        if re.match(r"[a-z]+:", target):  # http:, https:, mailto:
            continue
        file_part, _, anchor = target.partition("#")
        dest = (doc.parent / file_part).resolve() if file_part else doc
        if not dest.exists():
            broken.append(f"{number}: {target} (no such file)")
        elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
            broken.append(f"{number}: {target} (no such heading)")
    assert not broken, f"{doc.relative_to(REPO)}:\n" + "\n".join(broken)


def test_tests_the_docs_name_exist():
    """``tests/x.py::test_name`` in the docs (the reliability table names one per fault)."""
    named = re.compile(r"(tests/[\w/]+\.py)::(\w+)")
    missing = []
    for doc in DOC_FILES:
        for file, name in named.findall(doc.read_text()):
            source = REPO / file
            if not source.is_file() or not re.search(rf"^\s*def {name}\(", source.read_text(), re.M):
                missing.append(f"{doc.relative_to(REPO)}: {file}::{name}")
    assert not missing, "tests named in the docs that do not exist:\n" + "\n".join(missing)


# ------------------------------------------------------------------------- configuration


def _field_comment_blocks(source: str, class_name: str) -> dict[str, list[str]]:
    """The comment lines right above each field of ``class_name`` (and its docstring)."""
    tree = ast.parse(source)
    lines = source.splitlines()
    cls = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == class_name)
    blocks = {}
    for node in cls.body:
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            above, i = [], node.lineno - 2
            while i >= 0 and lines[i].strip().startswith("#"):
                above.insert(0, lines[i].strip())
                i -= 1
            blocks[node.target.id] = above
    return blocks


def test_config_fields_keep_two_lines_and_point_to_records_that_exist():
    source = (REPO / "annotator" / "config.py").read_text()
    long = []
    for section in SHORT_SECTIONS:
        for name, comments in _field_comment_blocks(source, section).items():
            if len(comments) > MAX_FIELD_COMMENT_LINES:
                long.append(f"{section}.{name}: {len(comments)} comment lines")
    assert not long, "history belongs in docs/decisions/, not config comments:\n" + "\n".join(long)
    records = set(re.findall(r"docs/decisions/[\w.-]+\.md", source))
    assert records, "config.py points to no decision record"
    missing = sorted(r for r in records if not (REPO / r).is_file())
    assert not missing, f"config.py points to decision records that do not exist: {missing}"


def test_decision_records_are_numbered_once_and_complete():
    folder = REPO / "docs" / "decisions"
    records = sorted(p for p in folder.glob("*.md") if p.name != "README.md")
    assert records, "no decision records"
    numbers, problems = {}, []
    index = (folder / "README.md").read_text()
    for path in records:
        match = re.fullmatch(r"(\d{4})-[a-z0-9]+(?:-[a-z0-9]+)*\.md", path.name)
        if not match:
            problems.append(f"{path.name}: not NNNN-slug.md")
            continue
        if match.group(1) in numbers:
            problems.append(f"{path.name}: number also used by {numbers[match.group(1)]}")
        numbers[match.group(1)] = path.name
        text = path.read_text()
        for heading in ("## Context", "## Decision", "## Consequences"):
            if heading not in text:
                problems.append(f"{path.name}: no '{heading}'")
        if f"({path.name})" not in index:
            problems.append(f"{path.name}: not listed in docs/decisions/README.md")
    assert not problems, "\n".join(problems)


# --------------------------------------------------------------------------- code blocks

FENCE = re.compile(r"^( *)```python[ \t]*\n(.*?)^\1```[ \t]*$", re.M | re.S)


def python_blocks() -> list[tuple[str, str]]:
    """``(id, code)`` of every fenced python block, id = ``file:line``."""
    blocks = []
    for doc in DOC_FILES:
        text = doc.read_text()
        for match in FENCE.finditer(text):
            indent = len(match.group(1))
            code = "\n".join(line[indent:] for line in match.group(2).splitlines())
            line = text.count("\n", 0, match.start()) + 1
            blocks.append((f"{doc.relative_to(REPO).as_posix()}:{line}", code))
    return blocks


BLOCKS = python_blocks()
# What the prepared folder holds (the docs' examples read only these).
LABELLED_OBJECTS = ("box.obj", "can.stl", "mug.obj")  # labels/ : floating labels, --n DOCS_N
CELL_OBJECTS = ("box.obj", "can.stl")  # cell_labels/ : --cell --views 2, --n DOCS_N
DOCS_N = 20


def _annotate(folder: Path, *args: str) -> subprocess.Popen:
    """``annotate *args --quiet`` started in ``folder`` by the installed console script."""
    bindir = Path(sys.executable).parent
    exe = shutil.which("annotate", path=str(bindir)) or shutil.which("annotate")
    assert exe, "the annotate console script is not installed (pip install -e '.[test]')"
    return subprocess.Popen(
        [exe, *args, "--quiet"], cwd=folder, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )


@pytest.fixture(scope="module")
def docs_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The folder the docs' examples run in: ``objects/`` (box, can, mug from the sample objects),
    ``labels/`` (``annotate --objects objects/ --n 20``), ``cell_labels/`` (box and can,
    ``--cell --views 2 --n 20``) and ``scene_labels/`` (one pile of two of box and can, 20 grasps).
    The three runs write apart and run side by side."""
    folder = tmp_path_factory.mktemp("docs")
    for sub, names in (("objects", LABELLED_OBJECTS), ("cell_objects", CELL_OBJECTS)):
        (folder / sub).mkdir()
        for name in names:
            shutil.copy(REPO / "objects" / name, folder / sub / name)
    runs = [
        ("--objects", "objects/", "--n", str(DOCS_N), "--out", "labels/", "--workers", "1"),
        (
            "--objects", "cell_objects/", "--n", str(DOCS_N), "--cell", "--views", "2",
            "--out", "cell_labels/", "--workers", "1",
        ),
        (
            "--objects", "cell_objects/", "--scenes", "1", "--per-scene", "2", "--n", str(DOCS_N),
            "--out", "scene_labels/", "--workers", "1",
        ),
    ]  # fmt: skip
    procs = [(args, _annotate(folder, *args)) for args in runs]
    try:
        for args, proc in procs:
            output, _ = proc.communicate(timeout=900)
            assert proc.returncode == 0, f"annotate {' '.join(args)} exited {proc.returncode}:\n{output}"
    finally:
        for _, proc in procs:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    return folder


def test_the_docs_have_python_blocks():
    assert CHANGELOG.is_file() and (REPO / "docs" / "labels.md").is_file()
    ids = {block_id.split(":")[0] for block_id, _ in BLOCKS}
    assert "README.md" in ids and len(BLOCKS) >= 5, ids


@pytest.mark.slow
@pytest.mark.parametrize("block", [code for _, code in BLOCKS], ids=[block_id for block_id, _ in BLOCKS])
def test_python_block_runs_as_written(block: str, docs_folder: Path):
    proc = subprocess.run(
        [sys.executable, "-c", block], cwd=docs_folder, capture_output=True, text=True, timeout=600
    )
    assert proc.returncode == 0, f"the block failed:\n{block}\n--- stderr:\n{proc.stderr[-4000:]}"
