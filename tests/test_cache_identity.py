"""A decomposition cache entry names what it is (annotator/objects/cache.py): the inputs of its key
are stored in it and checked on read, so a valid entry copied under another object's key is a miss,
said once, and never simulated."""

from __future__ import annotations

import shutil
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
import trimesh
from helpers import dimpled

from annotator.config import ObjectConfig
from annotator.objects import cache, decomposition, load_object


def _sorted(df: pd.DataFrame) -> pd.DataFrame:
    return df.sort_values(["object_id", "grasp_id"], kind="stable").reset_index(drop=True)


def _assert_same_entry(a, b) -> None:
    """Two entries hold the same shape and name the same inputs (their zip timestamps and the CPU
    seconds they took may differ)."""
    first, second = cache.load_arrays(a), cache.load_arrays(b)
    assert sorted(first) == sorted(second)
    for name in set(first) - {"seconds"}:
        assert np.array_equal(first[name], second[name]), name
    with np.load(a) as za, np.load(b) as zb:
        assert str(za[cache.INPUTS]) == str(zb[cache.INPUTS])


def test_an_entry_stores_its_inputs_and_a_reader_checks_them(tmp_path):
    box = trimesh.creation.box((0.05, 0.04, 0.10))
    ring = trimesh.creation.annulus(0.03, 0.05, 0.02)
    mine = cache.entry_inputs("hull", [box.vertices, box.faces], (1024,))
    other = cache.entry_inputs("hull", [ring.vertices, ring.faces], (1024,))
    assert mine.key != other.key
    path = tmp_path / f"{mine.key}.npz"
    cache.save_arrays(path, {"vertices": np.asarray(box.vertices)}, mine)
    assert np.array_equal(cache.load_arrays(path, mine)["vertices"], box.vertices)
    shutil.copyfile(path, tmp_path / f"{other.key}.npz")  # a whole, valid entry under another key
    with pytest.raises(cache.ForeignEntry, match="arrays differ"):
        cache.load_arrays(tmp_path / f"{other.key}.npz", other)
    settings = cache.entry_inputs("hull", [box.vertices, box.faces], (2048,))
    with pytest.raises(cache.ForeignEntry, match="settings differ"):
        cache.load_arrays(path, settings)
    cache.save_arrays(tmp_path / "anonymous.npz", {"vertices": np.asarray(box.vertices)})
    with pytest.raises(cache.ForeignEntry, match="does not name"):
        cache.load_arrays(tmp_path / "anonymous.npz", mine)


def test_a_foreign_entry_is_a_miss_said_once_and_replaced(tmp_path, caplog):
    """In process: the cylinder's hull read from a cache where the box's entry sits under its key
    (both dimpled: their hulls' errors are measured and cached; a plain box or cylinder is its own
    hull, never cached)."""
    box = dimpled(trimesh.creation.box((0.05, 0.04, 0.10)))
    cylinder = dimpled(trimesh.creation.cylinder(radius=0.03, height=0.09, sections=24))
    config = ObjectConfig().decomposition
    own = decomposition.collision_geometry(box, "hull", config, tmp_path / "box")
    fresh = decomposition.collision_geometry(cylinder, "hull", config, tmp_path / "clean")
    target = tmp_path / "poisoned" / fresh.file.name
    target.parent.mkdir()
    shutil.copyfile(own.file, target)
    with caplog.at_level("WARNING", logger="annotator.objects.collision_entry"):
        got = decomposition.collision_geometry(cylinder, "hull", config, tmp_path / "poisoned")
        again = decomposition.collision_geometry(cylinder, "hull", config, tmp_path / "poisoned")
    foreign = [r.getMessage() for r in caplog.records if "foreign collision cache entry" in r.getMessage()]
    assert len(foreign) == 1 and target.name in foreign[0] and "arrays differ" in foreign[0], foreign
    for geometry in (got, again):
        assert np.array_equal(geometry.parts[0].vertices, fresh.parts[0].vertices)
    _assert_same_entry(target, fresh.file)


def _annotate(*args) -> subprocess.CompletedProcess:
    """``annotate`` in a process of its own: no worker of an earlier run holds the objects."""
    cmd = [sys.executable, "-c", "from annotator.cli import annotate_main; annotate_main()"]
    proc = subprocess.run([*cmd, *map(str, args)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return proc


@pytest.mark.slow
def test_a_valid_entry_copied_under_another_objects_key_is_not_used(tmp_path):
    """A clean run of a box and a cylinder; then, in a cache of their own, the box's entry copied
    over the cylinder's: the run labels the cylinder exactly as the clean run did, says once that
    the entry is foreign, and the cylinder's own entry replaces the copy."""
    objects = tmp_path / "objects"
    objects.mkdir()
    # dimpled: cached hulls (a plain box or cylinder is its own hull, never cached)
    dimpled(trimesh.creation.box((0.05, 0.04, 0.10))).export(objects / "box.obj")
    dimpled(trimesh.creation.cylinder(radius=0.03, height=0.09, sections=24)).export(objects / "cylinder.obj")
    common = ("--objects", objects, "--n", 12, "--workers", 1)
    _annotate(*common, "-q", "--out", tmp_path / "clean", "--cache", tmp_path / "clean-cache")
    clean = _sorted(pd.read_parquet(tmp_path / "clean"))
    assert set(clean["object_id"]) == {"box", "cylinder"}

    entries = {}
    for name in ("box", "cylinder"):  # each object's entry, loaded alone as a worker loads it
        load_object(objects / f"{name}.obj", ObjectConfig(), cache_dir=tmp_path / f"{name}-cache")
        (entries[name],) = (tmp_path / f"{name}-cache").glob("*.npz")
    # the entries the clean run's worker wrote, by name
    assert {p.name for p in (tmp_path / "clean-cache").glob("*.npz")} == {p.name for p in entries.values()}
    poisoned = tmp_path / "poisoned-cache"
    poisoned.mkdir()
    shutil.copyfile(entries["box"], poisoned / entries["box"].name)
    # the box's shape under the cylinder's name
    shutil.copyfile(entries["box"], poisoned / entries["cylinder"].name)

    proc = _annotate(*common, "--out", tmp_path / "poisoned", "--cache", poisoned)
    labels = _sorted(pd.read_parquet(tmp_path / "poisoned"))
    pd.testing.assert_frame_equal(labels, clean, check_exact=True)
    said = [line for line in proc.stderr.splitlines() if "foreign collision cache entry" in line]
    assert len(said) == 1 and entries["cylinder"].name in said[0], proc.stderr
    _assert_same_entry(poisoned / entries["cylinder"].name, entries["cylinder"])
