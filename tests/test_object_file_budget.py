"""Object files are checked by size and header before the main process reads or hashes them: a
20 GB mesh is refused at once with its figure, never scanned (a sparse file here: no disk used)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from helpers import run_annotate

from annotator.objects import ObjectError, ObjectSource, source_digest

REPO = Path(__file__).resolve().parents[1]


def _sparse(path: Path, size: int) -> Path:
    with open(path, "wb") as f:
        f.truncate(size)
    return path


def test_a_20_gb_obj_is_refused_by_its_size_naming_the_file_and_the_figure(tmp_path):
    huge = _sparse(tmp_path / "huge.obj", 20 * 1024**3)
    with pytest.raises(ObjectError) as info:
        source_digest(ObjectSource("huge", huge), budget_mb=4096.0)
    assert str(info.value) == (
        "huge.obj is 20,480 MB, above the memory budget of 4,096 MB per worker "
        "(ObjectConfig.memory_budget): reading it alone would exceed it"
    )


def test_a_mesh_referenced_by_a_urdf_is_checked_too(tmp_path):
    _sparse(tmp_path / "part.stl", 5 * 1024**3)
    urdf = tmp_path / "thing.urdf"
    urdf.write_text(
        '<robot name="thing"><link name="base"><collision><geometry><mesh filename="part.stl"/>'
        "</geometry></collision></link></robot>"
    )
    with pytest.raises(ObjectError, match="part.stl is 5,120 MB, above the memory budget of 4,096 MB"):
        source_digest(ObjectSource("thing", urdf))


def test_a_mesh_whose_header_is_not_its_format_is_refused_before_it_is_hashed(tmp_path):
    zeros = _sparse(tmp_path / "zeros.obj", 1024**2)
    with pytest.raises(ObjectError, match="not an OBJ mesh \\(binary data in a text format\\): zeros.obj"):
        source_digest(ObjectSource("zeros", zeros))


def test_the_digest_is_streamed_and_unchanged(tmp_path):
    import hashlib

    box = REPO / "objects" / "box.obj"
    data = box.read_bytes()
    h = hashlib.sha256(b"rg2-annotator object v1\0")
    h.update(f"box.obj\0{len(data)}\0".encode() + data)
    h.update(b"node\0None\0")
    from annotator.objects.properties import ObjectProperties  # noqa: F401  (the sidecar default)

    source = ObjectSource("box", box)
    import json

    h.update(json.dumps(source.properties.as_dict(), sort_keys=True).encode())
    assert source_digest(source) == h.hexdigest()


@pytest.mark.slow
def test_a_run_labels_the_good_objects_and_names_the_huge_one(tmp_path):
    objects = tmp_path / "objects"
    objects.mkdir()
    shutil.copy(REPO / "objects" / "box.obj", objects)
    _sparse(objects / "huge.obj", 20 * 1024**3)
    out = tmp_path / "labels"
    result = run_annotate("--objects", objects, "--n", 2, "--out", out, "--workers", 1, "-q", check=1)
    assert "huge.obj is 20,480 MB, above the memory budget of 4,096 MB per worker" in result.output
    assert "Traceback" not in result.output
    import pandas as pd

    assert set(pd.read_parquet(out)["object_id"]) == {"box"}
