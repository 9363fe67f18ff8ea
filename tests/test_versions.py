"""One list of the libraries that shape labels (annotator/versions.py), bound by the manifest and
held by the decomposition cache's key: a resume after any of them changed is refused in one line,
and an object decomposed with other versions is decomposed again, so a folder never mixes two."""

from __future__ import annotations

import json

import pandas as pd
import pytest
import trimesh
from helpers import run_annotate

from annotator import versions
from annotator.objects import cache
from annotator.store import MANIFEST_NAME
from annotator.store.manifest import bound_versions


def test_the_manifest_and_the_cache_key_use_the_one_list(monkeypatch):
    assert set(versions.LABEL_LIBRARIES) >= {
        "pybullet",
        "numpy",
        "trimesh",
        "coacd",
        "scipy",
        "fast-simplification",
        "pymeshfix",
        "manifold3d",
    }
    assert set(bound_versions()) == {"annotator", *versions.LABEL_LIBRARIES}
    arrays = [trimesh.creation.box().vertices]
    key = cache.entry_key("coacd", arrays, ())
    real = versions.library_versions()
    for library in versions.LABEL_LIBRARIES:
        changed = {**real, library: "0.0.0+other"}
        monkeypatch.setattr(versions, "library_versions", lambda changed=changed: dict(changed))
        assert bound_versions()[library] == "0.0.0+other"
        assert cache.entry_key("coacd", arrays, ()) != key, library


@pytest.mark.slow
def test_a_resume_after_a_label_library_changed_is_refused_and_mixes_nothing(tmp_path, monkeypatch):
    """A real run of one box (in process, one worker), then the same command as if SciPy, then
    fast-simplification, pymeshfix or manifold3d had been upgraded in between: each resume is
    refused in one line with exit 2, naming the library, and the folder's labels are untouched."""
    monkeypatch.setenv("RG2_CACHE_DIR", str(tmp_path / "cache"))
    objects = tmp_path / "objects"
    objects.mkdir()
    trimesh.creation.box((0.05, 0.04, 0.10)).export(objects / "box.obj")
    out = tmp_path / "out"
    args = ("--objects", objects, "--n", 6, "--out", out, "--workers", 1, "-q")
    run_annotate(*args)
    manifest = (out / MANIFEST_NAME).read_bytes()
    labels = pd.read_parquet(out)
    assert len(labels) == 6
    recorded = json.loads(manifest)["run"]["versions"]
    assert {lib: recorded[lib] for lib in versions.LABEL_LIBRARIES} == versions.library_versions()

    real = versions.library_versions()
    for library in ("scipy", "fast-simplification", "pymeshfix", "manifold3d"):
        changed = {**real, library: "0.0.0+other"}
        monkeypatch.setattr(versions, "library_versions", lambda changed=changed: dict(changed))
        result = run_annotate(*args, check=2)
        assert "Traceback" not in result.output, result.output
        errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
        assert len(errors) == 1, result.output
        message = errors[0]
        assert f"{library} {real[library]} in the folder, 0.0.0+other now" in message, message
        assert (out / MANIFEST_NAME).read_bytes() == manifest
        pd.testing.assert_frame_equal(pd.read_parquet(out), labels, check_exact=True)
