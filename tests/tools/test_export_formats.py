"""The export formats are one registry (:mod:`annotator.tools.formats`): each format is one module of
the package, found by listing it, whose record gives the command line its choices and help, the
folders an overwrite clears and the writer; a format written as one module exports end to end."""

from __future__ import annotations

import json
import pkgutil
import textwrap
from pathlib import Path

import pytest
from click.testing import CliRunner

import annotator.tools.formats as formats
from annotator.cli import main
from annotator.tools.export import export


@pytest.fixture
def fresh_registry():
    formats.exporters.cache_clear()
    yield
    formats.exporters.cache_clear()


def test_the_registry_is_the_packages_modules_in_the_commands_order():
    modules = {m.name for m in pkgutil.iter_modules(formats.__path__)}
    found = formats.exporters()
    assert set(found) == {"acronym", "graspgen", "vgn", "contact_graspnet"} and len(modules) == len(found)
    assert list(found) == ["acronym", "graspgen", "vgn", "contact_graspnet"]  # --format's choices
    assert {e.unit for e in found.values()} == {"object", "scene"}
    help_text = CliRunner().invoke(main, ["export", "--help"]).output
    assert "[acronym|graspgen|vgn|contact_graspnet]" in help_text
    assert " ".join(help_text.split()).count(" ".join(formats.format_help().split()[:6])) == 1
    every = formats.folders()
    assert every.index("dataset/scenes") < every.index("dataset")  # a folder after those inside it
    assert all(f in every for e in found.values() for f in e.folders)


TOY = textwrap.dedent(
    '''
    """A format of one CSV per object: the grasps' base poses, flattened."""

    import numpy as np

    from annotator.tools.formats import Exporter


    def write_csv(folder, stem, rows, T_obj_base, mesh_file, extra):
        table = T_obj_base.reshape(len(rows), 16)
        return folder.write(f"toy/{stem}.csv", lambda tmp: np.savetxt(tmp, table, delimiter=","))


    EXPORTER = Exporter(name="toy", unit="object", help="a CSV per object", order=9, folders=("toy",),
                        write_object=write_csv)
    '''
)


def test_a_format_is_one_module(labelled, tmp_path: Path, monkeypatch, fresh_registry) -> None:
    package = tmp_path / "more_formats"
    package.mkdir()
    (package / "toy.py").write_text(TOY)
    monkeypatch.setattr(formats, "__path__", [*formats.__path__, str(package)])
    monkeypatch.syspath_prepend(str(tmp_path))
    assert list(formats.exporters())[-1] == "toy" and "toy" in formats.folders()
    out = tmp_path / "out"
    result = export(labelled.labels_dir, "toy", out, labelled.objects_dir)
    written = json.loads((out / "_export.json").read_text())
    assert written["format"] == "toy" and len(result.files) == 2 and result.n_grasps == len(labelled.df)
    assert sorted(p.parent.name for p in result.files) == ["toy", "toy"]
    # each file through the folder's one writer, its digest recorded
    assert {f"toy/{p.name}" for p in result.files} <= set(written["sha256"])
    again = export(labelled.labels_dir, "toy", out, labelled.objects_dir, overwrite=True)
    assert [p.name for p in again.files] == [p.name for p in result.files]
