"""The one atomic write (annotator/files.py): whole or not at all, shared permissions, temporary
names the store recognises, and every package writes through it."""

from __future__ import annotations

import ast
import os
from pathlib import Path

import pytest

from annotator.files import atomic_write, atomic_write_bytes, atomic_write_path, atomic_write_text
from annotator.store.names import is_temp_file_name

ROOT = Path(__file__).resolve().parents[1] / "annotator"


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    path = tmp_path / "data.bin"
    atomic_write_bytes(path, b"old")

    def half(fh):
        fh.write(b"new but")
        raise RuntimeError("disk gone")

    with pytest.raises(RuntimeError, match="disk gone"):
        atomic_write(path, half)
    assert path.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.bin"]


def test_the_file_is_replaced_whole_with_shared_permissions(tmp_path):
    path = tmp_path / "sub" / "t.txt"
    atomic_write_text(path, "één", make_parents=True)
    atomic_write_text(path, "two", durable=False)
    assert path.read_text(encoding="utf-8") == "two"
    mask = os.umask(0)
    os.umask(mask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~mask


def test_a_writer_by_name_gets_a_temporary_the_store_recognises(tmp_path):
    seen: list[str] = []

    def write(tmp: Path) -> None:
        seen.append(tmp.name)
        tmp.write_bytes(b"x")

    atomic_write_path(tmp_path / "labels.parquet", write)
    assert len(seen) == 1 and is_temp_file_name(seen[0]), seen
    assert (tmp_path / "labels.parquet").read_bytes() == b"x"


def test_only_the_atomic_write_replaces_a_file_it_wrote():
    """``os.replace`` outside annotator/files.py only renames files that already exist whole (the
    store's merges and recoveries, a gripper package's staged folder); a temporary file written then
    replaced is annotator.files' job."""
    allowed = {"files.py", "store/reconcile.py", "store/store.py", "grippers/package.py"}
    offenders = []
    for path in ROOT.rglob("*.py"):
        rel = path.relative_to(ROOT).as_posix()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if (
                isinstance(node, ast.Call)
                and isinstance(node.func, ast.Attribute)
                and node.func.attr in {"replace", "rename"}
                and isinstance(node.func.value, ast.Name)
                and node.func.value.id == "os"
                and rel not in allowed
            ):
                offenders.append(f"{rel}:{node.lineno}")
    assert offenders == [], offenders
