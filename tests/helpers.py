"""Helpers shared by several test modules (pytest puts tests/ on sys.path: ``from helpers import``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import trimesh
from click.testing import CliRunner, Result

import annotator.dataset as ds
from annotator.cli import annotate_command, main
from annotator.config import AnnotatorConfig
from annotator.rng import object_rng
from annotator.sampler import sample_candidates

SCENE_RUN_N = 40  # grasps per scene of the run-wide ``convex_scene_run`` (conftest.py)
QUICK_VIEWS = "[kinect]\nviews_color_scale = 0.25\n"  # colour views at a quarter of the Kinect's size


def run_annotate(*args, check: int | None = 0) -> Result:
    """Run ``annotate`` in process with ``args`` (anything str() turns into an argument); assert
    the exit code when ``check`` is not None, showing the output when it differs."""
    result = CliRunner().invoke(annotate_command, [str(a) for a in args], catch_exceptions=False)
    if check is not None:
        assert result.exit_code == check, f"exit {result.exit_code}, output:\n{result.output}"
    return result


def run_annotator(*args, check: int | None = 0) -> Result:
    """Run the ``annotator`` command group in process with ``args`` (a subcommand first); assert
    the exit code when ``check`` is not None, showing the output when it differs."""
    result = CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)
    if check is not None:
        assert result.exit_code == check, f"exit {result.exit_code}, output:\n{result.output}"
    return result


def synthetic_labels(object_id: str, n: int = 10, start: int = 0, seed: int = 0) -> pd.DataFrame:
    """A realistic label table of ``n`` rows (grasp ids ``start``..): poses from the real sampler
    on a 40 mm box, outcomes drawn at random (no simulation), plus an extra column to be kept."""
    rng = object_rng(seed, object_id)
    cand = sample_candidates(
        trimesh.creation.box(extents=(0.04, 0.04, 0.04)), n, rng, AnnotatorConfig().sampler, 0.11
    )
    outcomes = np.array(ds.OUTCOMES)[rng.integers(len(ds.OUTCOMES), size=n)]
    df = ds.pose_columns(cand.T_obj_tcp)
    df.insert(0, "object_id", object_id)
    df.insert(1, "grasp_id", np.arange(start, start + n, dtype=np.int64))
    df["width"] = cand.width_expected
    df["success"] = outcomes == "success"
    df["outcome"] = outcomes
    df["score"] = df["success"].astype(np.float64)
    df["object_scale"] = 1.0
    df["mesh_sha256"] = "ab" * 32
    df["seed"] = np.int64(seed)
    df["antipodal"] = cand.antipodal  # an extra column is kept
    return df


def write_l(path: Path, size: float = 1.0) -> Path:
    """A concave L-shaped block, 60 x 20 x 50 mm times ``size``, as an .obj at ``path`` (CoACD
    splits it in two within a second: a decomposition that is real but quick)."""
    outline = np.array([(-0.03, 0), (0.03, 0), (0.03, 0.02), (-0.01, 0.02), (-0.01, 0.05), (-0.03, 0.05)])
    fan = np.array([(0, 1, 2), (0, 2, 3), (0, 3, 4), (0, 4, 5)])
    path.parent.mkdir(parents=True, exist_ok=True)
    trimesh.creation.extrude_triangulation(outline * size, fan, 0.02 * size).export(path)
    return path


def dimpled(mesh: trimesh.Trimesh, depth: float = 1e-4) -> trimesh.Trimesh:
    """``mesh`` (closed, convex) subdivided once, the vertex nearest the middle of its top pushed
    ``depth`` (m) down: convex within any volume tolerance, but not its own hull, so its hull's
    error is measured and cached as a hull's is."""
    out = mesh.subdivide()
    vertices = np.array(out.vertices)
    top = vertices[:, 2].max()
    middle = vertices[:, :2].mean(axis=0)
    on_top = np.flatnonzero(np.isclose(vertices[:, 2], top))
    pick = on_top[np.argmin(np.linalg.norm(vertices[on_top, :2] - middle, axis=1))]
    vertices[pick, 2] -= depth
    return trimesh.Trimesh(vertices, out.faces, process=False)


def mount_tmpfs(where: Path, size: str) -> None:
    """A tmpfs of ``size`` mounted at ``where`` (root only: the test is skipped where it cannot be)."""
    import subprocess

    import pytest

    where.mkdir(parents=True, exist_ok=True)
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)], capture_output=True
    )
    if done.returncode:
        pytest.skip(f"cannot mount a tmpfs here ({done.stderr.decode().strip()})")


def umount(where: Path) -> None:
    """Unmount ``where`` (lazily: a process still in it does not keep it)."""
    import subprocess

    subprocess.run(["umount", "-l", str(where)], capture_output=True)
