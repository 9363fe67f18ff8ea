"""``annotator show --scene ID``: a picture of a labelled scene with its grasps coloured by outcome.

Two views of the scene as it was settled (the seed's table and every kept object, each in its own
colour and named ``instance:object`` at its centre of mass): from above the table's far side and
straight down; over them a glyph per chosen grasp (as in :func:`annotator.tools.show.overview`),
coloured by outcome, parts hidden behind something drawn faint, successes on top. Rendered with
PyBullet's TinyRenderer in a private DIRECT client: no display, no GPU.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from annotator.dataset import OUTCOMES
from annotator.geometry import Transform, quat_to_matrix
from annotator.render import Camera, look_at_camera, project, render_frame
from annotator.rng import keyed_rng
from annotator.scenes.labels import TABLE_TCP_COLUMNS
from annotator.scenes.records import SceneRecord
from annotator.sim import rigid
from annotator.sim.world import World
from annotator.tools.show import FOV, Overview, _font, _visual_bodies, draw_glyphs, drawing_order

log = logging.getLogger(__name__)

VIEW_SIZE = 520  # pixels, each view (square)
# Instance colours (light, apart from the outcome colours of the glyphs), RGBA 0..1.
INSTANCE_RGBA = (
    (0.55, 0.68, 0.85, 1.0),
    (0.85, 0.78, 0.55, 1.0),
    (0.70, 0.85, 0.62, 1.0),
    (0.88, 0.64, 0.64, 1.0),
    (0.74, 0.66, 0.86, 1.0),
    (0.62, 0.84, 0.84, 1.0),
)
PAD_TIP = 0.015  # m: glyph fingers reach this far beyond the TCP (half the RG2's 29.8 mm pad)


def choose_scene_grasps(
    rows: pd.DataFrame, n: int, seed: int, outcomes: tuple[str, ...] = ()
) -> pd.DataFrame:
    """Up to ``n`` of a scene's grasps (of ``outcomes`` if given), a seeded choice, by grasp id."""
    pool = rows[rows["outcome"].isin(outcomes)] if outcomes else rows
    pool = pool.sort_values("grasp_id")
    scene = int(rows["scene_id"].iloc[0]) if len(rows) else -1
    pick = np.sort(keyed_rng("show-scene", int(seed), scene).permutation(len(pool))[:n])
    return pool.iloc[pick].reset_index(drop=True)


def scene_cameras(record: SceneRecord, size: int = VIEW_SIZE) -> tuple[Camera, Camera]:
    """An oblique camera (from the table's far side, 40 deg above it) and a top-down one, both on the
    workspace's centre on the table, framing the workspace cube."""
    T = record.T_world_table
    centre = T.apply(np.array([record.workspace.center[0], record.workspace.center[1], 0.05]))
    dist = 0.6 * record.workspace.size / np.tan(np.radians(FOV / 2)) + 0.1
    up_world = T.rotation[:, 2]
    elev = np.radians(40.0)
    oblique_dir = T.rotation @ np.array([np.cos(elev), 0.0, np.sin(elev)])  # the table's +x side
    oblique = look_at_camera(centre + dist * oblique_dir, centre, up_world, size, size, FOV, far=4 * dist)
    top = look_at_camera(centre + dist * up_world, centre, -T.rotation[:, 0], size, size, FOV, far=4 * dist)
    return oblique, top


def table_poses(rows: pd.DataFrame) -> np.ndarray:
    """The grasps' TCP poses in the table frame, (n, 4, 4), from the rows' table_tcp_* columns."""
    v = rows[list(TABLE_TCP_COLUMNS)].to_numpy(dtype=np.float64)
    T = np.zeros((len(rows), 4, 4))
    if len(rows):
        T[:, :3, :3] = quat_to_matrix(v[:, 3:7])
    T[:, :3, 3] = v[:, :3]
    T[:, 3, 3] = 1.0
    return T


@dataclass
class ScenePicture:
    """The picture (h, w, 3) uint8 and what a test needs: each view's object masks per instance and
    the chosen grasps' TCP pixels (rows in the order of ``grasp_ids``)."""

    image: np.ndarray
    overview: Overview
    instance_masks: list[dict[int, np.ndarray]]


# A clutter-removal attempt's ``failure`` drawn in the colour of the label outcome it resembles.
ATTEMPT_OUTCOMES = {
    "": "success",
    "nothing_there": "no_contact",
    "no_contact": "no_contact",
    "arm_touched_table": "collision",
    "gripper_pushed_object": "collision",
    "not_lifted": "slipped_lift",
    "slipped": "slipped_shake",
}
ATTEMPT_COLUMNS = ("round_id", "attempt", "x", "y", "z", "qx", "qy", "qz", "qw", "width", "label", "failure")


def attempt_rows(path: Path, round_id: int) -> pd.DataFrame:
    """Round ``round_id``'s attempts in a ``clutter-removal --out`` ``grasps.csv`` as rows
    :func:`render_scene` draws: the TCP in the table frame (``table_tcp_*``), width, ``outcome``
    (:data:`ATTEMPT_OUTCOMES` of its ``failure``), ``grasp_id`` the attempt's number, ``text`` what
    it went for and how it ended. ToolError (one line) for a file that is not such a table."""
    from annotator.tools.common import ToolError

    try:
        table = pd.read_csv(path, keep_default_na=False)
    except (OSError, ValueError) as exc:
        raise ToolError(f"--attempts {path}: cannot read it as a CSV ({exc})") from None
    missing = [c for c in ATTEMPT_COLUMNS if c not in table.columns]
    if missing:
        no = ", ".join(missing)
        raise ToolError(f"--attempts {path}: not a clutter-removal grasps.csv (no column {no})")
    rows = table[pd.to_numeric(table["round_id"], errors="coerce") == round_id].reset_index(drop=True)
    numbers = _attempt_numbers(rows, path)
    rows = (
        rows.assign(attempt=numbers["attempt"]).sort_values("attempt", kind="stable").reset_index(drop=True)
    )
    numbers = numbers.sort_values("attempt", kind="stable").reset_index(drop=True)
    if rows.empty:
        rounds = sorted(set(table["round_id"].tolist()))
        raise ToolError(f"--attempts {path}: no attempt of round {round_id} (rounds {rounds[:10]})")
    unknown = sorted(set(rows["failure"]) - set(ATTEMPT_OUTCOMES))
    if unknown:
        raise ToolError(f"--attempts {path}: unknown failure(s) {unknown}")
    out = pd.DataFrame({c: numbers[c[len("table_tcp_") :]] for c in TABLE_TCP_COLUMNS})
    out["width"] = numbers["width"]
    out["outcome"] = [ATTEMPT_OUTCOMES[f] for f in rows["failure"]]
    out["grasp_id"] = rows["attempt"].astype(int)
    target = rows["target_object"] if "target_object" in rows else pd.Series([""] * len(rows))
    held = rows["label"].astype(bool)
    out["text"] = [
        f"{a}: {t or '?'} {'held' if ok else f}"
        for a, t, ok, f in zip(rows["attempt"], target, held, rows["failure"], strict=True)
    ]
    return out


def _attempt_numbers(rows: pd.DataFrame, path: Path) -> pd.DataFrame:
    """The numbers of a round's attempts (``x .. qw``, ``width`` float64, ``attempt`` int64),
    checked: finite, a quaternion of non-zero length (normalised), a width >= 0, whole attempt
    numbers; ToolError (one line) naming the row and column otherwise."""
    from annotator.tools.common import ToolError

    names = [c[len("table_tcp_") :] for c in TABLE_TCP_COLUMNS] + ["width", "attempt"]
    out = pd.DataFrame({c: pd.to_numeric(rows[c], errors="coerce").astype(np.float64) for c in names})
    for c in names:
        bad = ~np.isfinite(out[c].to_numpy())
        if c == "width":
            bad |= out[c].to_numpy() < 0
        if c == "attempt":
            bad |= out[c].to_numpy() != np.round(out[c].to_numpy())
        if bad.any():
            k = int(np.argmax(bad))
            raise ToolError(
                f"--attempts {path}: an attempt of the round has {c} {rows[c].iloc[k]!r}: not a valid number"
            )
    q = out[["qx", "qy", "qz", "qw"]].to_numpy()
    norm = np.linalg.norm(q, axis=1)
    if (norm < 1e-6).any():
        k = int(np.argmax(norm < 1e-6))
        raise ToolError(
            f"--attempts {path}: attempt {int(out.attempt.iloc[k])}: a zero quaternion is no rotation"
        )
    out[["qx", "qy", "qz", "qw"]] = q / norm[:, None]
    out["attempt"] = out["attempt"].astype(np.int64)
    return out


def render_scene(
    record: SceneRecord,
    meshes: dict[str, object],
    chosen: pd.DataFrame,
    counts: dict[str, int],
    title: str,
    *,
    numbered: bool = False,
) -> ScenePicture:
    """Render ``record`` (meshes: object id -> trimesh in its mesh frame) with ``chosen``'s glyphs;
    ``numbered``: each glyph's ``grasp_id`` written beside its TCP (a round's attempts)."""
    from annotator.cell.world import build_cell
    from annotator.config import CellConfig

    chosen = drawing_order(chosen)
    T_world_tcp = record.T_world_table.as_matrix() @ table_poses(chosen)
    with World() as world:
        build_cell(world, CellConfig(), robot=False, kinect=False)
        bodies: dict[int, list[int]] = {}
        for k, inst in enumerate(record.kept):
            uids = _visual_bodies(world.client, meshes[inst.object_id], INSTANCE_RGBA[k % len(INSTANCE_RGBA)])
            pos, quat = record.T_world_obj(inst.instance_id).to_pybullet()
            for uid in uids:
                rigid.reset_pose(world.client, uid, pos, quat)
            bodies[inst.instance_id] = uids
        out = Overview([], [], [], [], chosen["grasp_id"].to_numpy())
        masks = []
        for camera in scene_cameras(record):
            frame = render_frame(world.client, camera)
            image = draw_glyphs(frame, T_world_tcp, chosen["width"].to_numpy(), chosen["outcome"], PAD_TIP)
            image = _named(image, camera, record)
            if numbered:
                image = _numbered(image, camera, T_world_tcp[:, :3, 3], chosen["grasp_id"].to_numpy())
            out.images.append(image)
            out.frames.append(frame)
            masks.append({i: np.isin(frame.segmentation, uids) for i, uids in bodies.items()})
            out.object_masks.append(np.any(list(masks[-1].values()), axis=0))
            out.tcp_pixels.append(project(camera, T_world_tcp[:, :3, 3])[0])
    return ScenePicture(out.picture(title, counts), out, masks)


def _named(image: np.ndarray, camera: Camera, record: SceneRecord) -> np.ndarray:
    """``image`` with each kept instance named ``id:object`` at its origin's pixel."""
    from PIL import Image, ImageDraw

    img = Image.fromarray(image)
    draw = ImageDraw.Draw(img)
    font = _font(12)
    for inst in record.kept:
        T: Transform = record.T_world_obj(inst.instance_id)
        uv, _ = project(camera, T.pos[None])
        text = f"{inst.instance_id}:{inst.object_id}"
        draw.text((float(uv[0, 0]) + 4, float(uv[0, 1]) - 6), text, fill=(20, 20, 20), font=font)
    return np.asarray(img)


def _numbered(image: np.ndarray, camera: Camera, points: np.ndarray, numbers: np.ndarray) -> np.ndarray:
    """``image`` with ``numbers`` (n,) written at ``points`` (n, 3) world m (grasps' TCPs)."""
    from PIL import Image, ImageDraw

    img = Image.fromarray(image)
    draw = ImageDraw.Draw(img)
    font = _font(14)
    uv, _ = project(camera, points)
    for (u, v), number in zip(uv, numbers, strict=True):
        draw.text((float(u) + 6, float(v) + 2), str(int(number)), fill=(0, 0, 0), font=font)
    return np.asarray(img)


@dataclass(frozen=True)
class ShowSceneResult:
    """What ``show --scene`` wrote, the grasps drawn, the scene's kept instances."""

    png: Path
    n_grasps: int
    kept: int


def show_scene(
    labels_dir: Path,
    scene_id: int,
    png: Path,
    n: int = 40,
    seed: int = 0,
    outcomes: tuple[str, ...] = (),
    objects_dir: Path | None = None,
    overwrite: bool = False,
    attempts: Path | None = None,
) -> ShowSceneResult:
    """Write the picture of scene ``scene_id`` of the scene run in ``labels_dir`` to ``png`` (a
    picture of that name this tool did not write only with ``overwrite``). ``attempts``: a
    ``clutter-removal --out`` ``grasps.csv`` whose round ``scene_id`` (the same scene when both ran
    with the same objects, seed, arrangement and objects per pile) is drawn instead of the labels,
    each attempt numbered, on the scene as it first settled."""
    from annotator.tools.common import claim_outputs

    with claim_outputs("annotator show --scene", {"--png": png}, overwrite) as claimed:
        return _write_show_scene(claimed, labels_dir, scene_id, n, seed, outcomes, objects_dir, attempts)


def _write_show_scene(
    claimed, labels_dir, scene_id, n, seed, outcomes, objects_dir, attempts
) -> ShowSceneResult:
    """:func:`show_scene`'s work once its picture is claimed (``claimed``: the
    :class:`annotator.tools.common.ToolOutputs`)."""
    from annotator.tools.common import ToolError, object_mesh, png_bytes
    from annotator.tools.scene_labels import open_scene_labels

    bad = sorted(set(outcomes) - set(OUTCOMES))
    if bad:
        raise ToolError(f"unknown outcome(s) {bad}; choose from {', '.join(OUTCOMES)}")
    scenes = open_scene_labels(labels_dir, "show --scene")
    rows = scenes.rows(scene_id)
    record = scenes.records[scene_id]
    if attempts is None:
        chosen = choose_scene_grasps(rows, n, seed, outcomes)
    else:
        chosen = attempt_rows(attempts, scene_id)
    if chosen.empty:
        have = ", ".join(f"{k} {v}" for k, v in rows["outcome"].value_counts().items())
        raise ToolError(f"scene {scene_id} has no {'/'.join(outcomes)} grasps ({have})")
    labels = scenes.labels
    meshes = {}
    for oid in sorted({i.object_id for i in record.kept}):
        meshes[oid] = object_mesh(labels_dir, oid, objects_dir, labels[labels["object_id"] == oid])
    counts = {str(k): int(v) for k, v in chosen["outcome"].value_counts().items()}
    title = (
        f"scene {scene_id} ({record.arrangement}, {len(record.kept)} of {len(record.instances)} objects "
        f"kept): {len(chosen)} of {len(rows)} grasps"
    )
    if attempts is not None:
        title = f"round {scene_id} ({record.arrangement}, as first settled): " + ", ".join(chosen["text"])
    picture = render_scene(record, meshes, chosen, counts, title, numbered=attempts is not None)
    png = claimed.write_bytes("--png", png_bytes(picture.image))
    return ShowSceneResult(png, len(chosen), len(record.kept))
