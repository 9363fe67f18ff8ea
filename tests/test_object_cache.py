"""A worker's one object cache (annotator.pipeline.object_cache), every mode's: an object met again is
the model kept, another scale or object configuration is another object, the memory budget evicts
the least recently used, and an object that could not be loaded fails again at once, without a
second load; all on real meshes read and given their collision shapes."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import pytest

from annotator.config import ObjectConfig
from annotator.objects import ObjectError, discover_objects
from annotator.pipeline import object_cache
from annotator.pipeline.object_cache import ObjectCache, footprint

SAMPLES = Path(__file__).resolve().parent.parent / "objects"


@pytest.fixture
def objects(tmp_path: Path) -> dict:
    folder = tmp_path / "objects"
    folder.mkdir()
    for name in ("box.obj", "can.stl"):  # convex: no decomposition
        shutil.copy(SAMPLES / name, folder)
    (folder / "broken.obj").write_text("v 0 0 0\nv 1 0 0\n")  # no face: cannot be loaded
    return {s.object_id: s for s in discover_objects(folder)}


@pytest.fixture
def loads(monkeypatch) -> list[str]:
    """The object ids the cache loads (the real loader, counted)."""
    seen: list[str] = []
    real = object_cache.load_model

    def counted(source, *args, **kwargs):
        seen.append(source.object_id)
        return real(source, *args, **kwargs)

    monkeypatch.setattr(object_cache, "load_model", counted)
    return seen


def _get(cache: ObjectCache, source, tmp_path: Path, scale=None, config=None):
    return cache.get(
        source,
        digest=None,
        scale=scale,
        config=config or ObjectConfig(),
        cache_dir=str(tmp_path / "shapes"),
        status_dir=None,
    )


def test_an_object_met_again_is_the_model_kept(objects, loads, tmp_path):
    cache = ObjectCache()
    first = _get(cache, objects["box"], tmp_path)
    again = _get(cache, objects["box"], tmp_path)
    assert first.loaded and not again.loaded and again.model is first.model and again.key == first.key
    assert again.candidates is first.candidates  # what was sampled of it travels with it
    larger = _get(cache, objects["box"], tmp_path, scale=2.0)
    other = _get(
        cache, objects["box"], tmp_path, config=dataclasses.replace(ObjectConfig(), lateral_friction=0.9)
    )
    assert larger.loaded and other.loaded and len({first.key, larger.key, other.key}) == 3
    assert larger.model.mesh.extents == pytest.approx(2.0 * first.model.mesh.extents)
    assert loads == ["box", "box", "box"] and len(cache) == 3


def test_the_budget_keeps_the_most_recently_used(objects, loads, tmp_path):
    probe = ObjectCache()
    box = _get(probe, objects["box"], tmp_path)
    can = _get(probe, objects["can"], tmp_path)
    assert footprint(box.model, {}) > 0 and footprint(can.model, {}) > 0
    # room for the larger of the two, not for both
    cache = ObjectCache(budget=max(footprint(box.model, {}), footprint(can.model, {})))
    loads.clear()
    box = _get(cache, objects["box"], tmp_path)
    can = _get(cache, objects["can"], tmp_path)
    assert can.key in cache and box.key not in cache and len(cache) == 1
    assert _get(cache, objects["box"], tmp_path).loaded  # evicted: loaded again
    assert loads == ["box", "can", "box"]
    nothing = ObjectCache(budget=0)  # keeps nothing: every use loads
    assert _get(nothing, objects["can"], tmp_path).loaded and _get(nothing, objects["can"], tmp_path).loaded
    assert len(nothing) == 0


def test_an_object_that_cannot_be_loaded_fails_again_without_a_second_load(objects, loads, tmp_path):
    cache = ObjectCache()
    with pytest.raises(ObjectError) as first:
        _get(cache, objects["broken"], tmp_path)
    with pytest.raises(ObjectError) as again:
        _get(cache, objects["broken"], tmp_path)
    assert str(again.value) == str(first.value) and loads == ["broken"]
    assert _get(cache, objects["box"], tmp_path).loaded and len(cache) == 1  # the others load
