"""Pictures of labelled grasps: a sheet of gripper poses around an object and an overview of every grasp.

* :func:`grasp_sheet`: for each chosen grasp the gripper (the one the labels were made with) at the
  label's pose and width (posed with the
  model's own kinematics) around the object's mesh, seen from the front (along the TCP y axis:
  both fingers and the object between them) and from the side (along the closing axis, from
  above), titled with grasp id, outcome and width.
* :func:`overview`: the object alone from two viewpoints with every grasp drawn as a small
  gripper glyph coloured by outcome (parts hidden behind the object drawn faint).

Rendering is PyBullet's TinyRenderer in a private DIRECT client: no display, no GPU.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from annotator.config import GripperConfig
from annotator.dataset import OUTCOMES, poses_as_matrices
from annotator.geometry import Transform
from annotator.grippers import GripperDescription, load_gripper
from annotator.outcome import OUTCOME_RGB
from annotator.render import Camera, Frame, look_at_camera, project, render_frame
from annotator.rng import keyed_rng
from annotator.sim import rigid
from annotator.sim.body import Body
from annotator.sim.gripper import ParallelGripper
from annotator.sim.world import World

log = logging.getLogger(__name__)

OUTCOME_COLORS = OUTCOME_RGB  # outcome -> RGB 0..255 (annotator.outcome)
OBJECT_RGBA = (0.55, 0.68, 0.85, 1.0)  # light blue: apart from the grey gripper and the glyphs
BACKGROUND = (255, 255, 255)
# PyBullet refuses visual meshes with more indices than this in one shape (objects.py's limit);
# bigger meshes are drawn as several shapes.
MAX_VISUAL_INDICES = 24_000
VIEW_SIZE = 260  # pixels, each view of the sheet (square)
TITLE_HEIGHT = 22  # pixels above each grasp's pair of views
FOV = 40.0  # deg, vertical field of view of every picture
# Glyph of a grasp in its TCP frame (m): fingers from the pad tips (half the gripper's pad length
# beyond the TCP: the RG2's 29.8 mm pads reach 15 mm) back to the palm, a stem behind.
GLYPH_PALM = -0.025  # the palm bar, behind the TCP along the approach
GLYPH_STEM = -0.045  # end of the stem that points back towards the robot
# Collisions are never simulated and often the majority: drawn thinner and lighter, under the rest.
GLYPH_WIDTH = {"collision": 1}  # pixels; 2 for every other outcome
GLYPH_ALPHA = {"collision": 150}  # 0..255; 255 for every other outcome


def _visual_bodies(client: int, mesh, rgba=OBJECT_RGBA) -> list[int]:
    """Visual-only, massless bodies that draw ``mesh`` (trimesh) at the world origin (flat shading).

    Every face gets its own three vertices with the face normal, so TinyRenderer shades flat
    faces flat; meshes over PyBullet's index limit are split into several bodies.
    """
    faces = np.asarray(mesh.faces)
    verts = np.asarray(mesh.vertices)[faces].reshape(-1, 3)
    normals = np.repeat(np.asarray(mesh.face_normals), 3, axis=0)
    per_body = MAX_VISUAL_INDICES // 3
    uids = []
    for start in range(0, len(faces), per_body):
        sl = slice(3 * start, 3 * min(len(faces), start + per_body))
        n = sl.stop - sl.start
        vis = rigid.visual_shape(
            client,
            "mesh",
            vertices=verts[sl].tolist(),
            indices=list(range(n)),
            normals=normals[sl].tolist(),
            rgbaColor=list(rgba),
        )
        if vis < 0:
            raise RuntimeError("PyBullet rejected the object's visual mesh")
        uids.append(
            rigid.multibody(
                client,
                baseMass=0.0,
                baseCollisionShapeIndex=-1,
                baseVisualShapeIndex=vis,
                basePosition=[0, 0, 0],
            )
        )
    return uids


class GraspRenderer:
    """A private DIRECT world with an object's mesh at the origin and the gripper, posed kinematically.

    ``mesh`` : trimesh.Trimesh in the object's mesh frame (m); label poses are in that frame.
    ``description``: the gripper drawn (a name or folder is loaded; default the RG2).
    """

    def __init__(
        self,
        mesh,
        gripper: GripperConfig | None = None,
        description: GripperDescription | str | None = None,
    ) -> None:
        self.world = World()
        self.client = self.world.client
        self.mesh = mesh
        self.description = load_gripper(description)
        self.body = Body.load(self.client, self.description.urdf, fixed_base=True)
        self.gripper = ParallelGripper(self.body, self.description, gripper or GripperConfig())
        self.object_uids = _visual_bodies(self.client, mesh)
        self.hide_gripper()

    def close(self) -> None:
        """Disconnect the renderer's private PyBullet client."""
        self.world.close()

    def __enter__(self) -> GraspRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def pose_gripper(self, T_obj_tcp: Transform, width: float) -> None:
        """The gripper with its TCP at ``T_obj_tcp`` and the pads ``width`` (m) apart (its own FK)."""
        self.body.reset_base_pose(T_obj_tcp * self.gripper.T_base_tcp(width).inverse())
        self.gripper.reset_width(width)

    @property
    def pad_tip(self) -> float:
        """How far the fingertips reach beyond the TCP along the approach (m): half the pad length."""
        return 0.5 * self.gripper.pad_face[1]

    def hide_gripper(self) -> None:
        """Move the gripper out of view (the overview draws the object alone)."""
        self.body.reset_base_pose(Transform([0.0, 0.0, 50.0], [0, 0, 0, 1]))

    def render(self, camera: Camera) -> Frame:
        """One :class:`annotator.render.Frame` from ``camera``: RGB, depth and segmentation."""
        return render_frame(self.client, camera)

    def object_mask(self, frame: Frame) -> np.ndarray:
        """(h, w) bool: pixels where the object is drawn."""
        return np.isin(frame.segmentation, self.object_uids)


# ------------------------------------------------------------------------------------ choosing


def choose_grasps(
    rows: pd.DataFrame, n: int, seed: int = 0, outcomes: tuple[str, ...] = (), grasp_ids: tuple[int, ...] = ()
) -> pd.DataFrame:
    """Up to ``n`` grasps of one object: the given ``grasp_ids``, else a seeded random choice
    among ``outcomes`` (all outcomes if empty), sorted by grasp id."""
    if grasp_ids:
        missing = sorted(set(grasp_ids) - set(rows["grasp_id"].tolist()))
        if missing:
            raise ValueError(f"no grasp(s) {missing} (grasp ids run 0..{int(rows['grasp_id'].max())})")
        return rows[rows["grasp_id"].isin(grasp_ids)].sort_values("grasp_id").reset_index(drop=True)
    pool = rows[rows["outcome"].isin(outcomes)] if outcomes else rows
    pool = pool.sort_values("grasp_id")
    oid = str(rows["object_id"].iloc[0]) if len(rows) else ""
    pick = np.sort(keyed_rng("show", int(seed), oid).permutation(len(pool))[:n])
    return pool.iloc[pick].reset_index(drop=True)


# ------------------------------------------------------------------------------------ cameras


def _radius(mesh, centre: np.ndarray) -> float:
    return float(np.linalg.norm(np.asarray(mesh.vertices) - centre, axis=1).max())


def grasp_cameras(T_obj_tcp: Transform, mesh, size: int = VIEW_SIZE) -> tuple[Camera, Camera]:
    """Front and side cameras of one grasp, aimed between the TCP and the object's centre.

    Front looks along the TCP's +y (closing axis across the image, approach pointing down);
    side looks along the closing axis from 35 degrees above the TCP's x-y plane, towards the
    gripper. Both fit the object and the fingers.
    """
    R = T_obj_tcp.rotation
    centre = np.asarray(mesh.bounds, dtype=float).mean(axis=0)
    target = 0.5 * (T_obj_tcp.pos + centre)
    reach = max(_radius(mesh, target), 0.07)  # the fingers reach ~ 6 cm around the TCP
    dist = 1.15 * reach / np.tan(np.radians(FOV / 2)) + 0.5 * reach
    up = -R[:, 2]  # the gripper above, approaching downwards
    front = look_at_camera(target - dist * R[:, 1], target, up, size, size, FOV, far=4 * dist)
    side_dir = np.cos(np.radians(35)) * R[:, 0] - np.sin(np.radians(35)) * R[:, 2]
    side = look_at_camera(target + dist * side_dir, target, up, size, size, FOV, far=4 * dist)
    return front, side


def overview_cameras(mesh, size: int = 2 * VIEW_SIZE, extra: float = 0.03) -> tuple[Camera, Camera]:
    """Two cameras around the object: from the front-right above and from the back-left below.

    ``extra`` (m) is added to the object's radius so glyphs outside it stay in the picture.
    """
    centre = np.asarray(mesh.bounds, dtype=float).mean(axis=0)
    radius = _radius(mesh, centre) + extra
    dist = radius / np.tan(np.radians(FOV / 2))
    cams = []
    for yaw, pitch in ((35.0, 30.0), (215.0, -25.0)):
        y, p = np.radians(yaw), np.radians(pitch)
        direction = np.array([np.cos(p) * np.cos(y), np.cos(p) * np.sin(y), np.sin(p)])
        cams.append(
            look_at_camera(centre + dist * direction, centre, [0, 0, 1], size, size, FOV, far=4 * dist)
        )
    return cams[0], cams[1]


# ------------------------------------------------------------------------------------ drawing


def _font(size: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: a fixed bitmap font
        return ImageFont.load_default()


def grasp_title(row) -> str:
    """A sheet cell's title: grasp id, outcome and width (mm)."""
    return f"grasp {int(row.grasp_id)} · {row.outcome} · {1000 * float(row.width):.1f} mm"


def grasp_sheet(
    renderer: GraspRenderer, rows: pd.DataFrame, columns: int = 2, size: int = VIEW_SIZE
) -> np.ndarray:
    """A (H, W, 3) uint8 sheet: per grasp, front and side views under a title; ``columns`` grasps
    per row."""
    from PIL import Image, ImageDraw

    n = len(rows)
    if n == 0:
        raise ValueError("no grasps to draw")
    columns = max(1, min(columns, n))
    n_rows = -(-n // columns)
    cell_w, cell_h = 2 * size, size + TITLE_HEIGHT
    sheet = Image.new("RGB", (columns * cell_w + (columns - 1) * 8, n_rows * cell_h), BACKGROUND)
    draw = ImageDraw.Draw(sheet)
    font = _font(14)
    T_all = poses_as_matrices(rows)
    for k, row in enumerate(rows.itertuples(index=False)):
        T = Transform.from_matrix(T_all[k])
        renderer.pose_gripper(T, float(row.width))
        x0, y0 = (k % columns) * (cell_w + 8), (k // columns) * cell_h
        for j, camera in enumerate(grasp_cameras(T, renderer.mesh, size)):
            sheet.paste(Image.fromarray(renderer.render(camera).rgb), (x0 + j * size, y0 + TITLE_HEIGHT))
        colour = OUTCOME_COLORS.get(row.outcome, (0, 0, 0))
        draw.rectangle([x0, y0 + 4, x0 + 12, y0 + 16], fill=colour)
        draw.text((x0 + 18, y0 + 3), grasp_title(row) + "   (front | side)", fill=(20, 20, 20), font=font)
    renderer.hide_gripper()
    return np.asarray(sheet)


def glyph_segments(T_obj_tcp: np.ndarray, width: np.ndarray, pad_tip: float = 0.015) -> np.ndarray:
    """Line segments of gripper glyphs, (n, 4, 2, 3) float in the object frame.

    Per grasp: the two fingers (from the pad tips, ``pad_tip`` m beyond the TCP, back to the palm,
    ``width`` apart along the closing axis), the palm bar and the stem, all in the plane of the
    TCP's x and z axes.
    """
    T = np.asarray(T_obj_tcp, dtype=float).reshape(-1, 4, 4)
    half = np.asarray(width, dtype=float).reshape(-1) / 2
    n = len(T)
    local = np.zeros((n, 4, 2, 3))
    local[:, 0, :, 0] = -half[:, None]
    local[:, 1, :, 0] = half[:, None]
    local[:, 0:2, 0, 2] = pad_tip
    local[:, 0:2, 1, 2] = GLYPH_PALM
    local[:, 2, 0, 0], local[:, 2, 1, 0] = -half, half
    local[:, 2, :, 2] = GLYPH_PALM
    local[:, 3, 0, 2], local[:, 3, 1, 2] = GLYPH_PALM, GLYPH_STEM
    return np.einsum("nij,nsej->nsei", T[:, :3, :3], local) + T[:, None, None, :3, 3]


@dataclass
class Overview:
    """The overview pictures and what a test needs to check them.

    ``images`` : per view (h, w, 3) uint8 with glyphs; ``frames`` : the object-only renders;
    ``object_masks`` : per view (h, w) bool; ``tcp_pixels`` : per view (n, 2) float pixel
    (column, row) of each grasp's TCP, rows in the order of ``grasp_ids``.
    """

    images: list[np.ndarray]
    frames: list[Frame]
    object_masks: list[np.ndarray]
    tcp_pixels: list[np.ndarray]
    grasp_ids: np.ndarray

    def picture(self, title: str, counts: dict[str, int]) -> np.ndarray:
        """Both views side by side under ``title`` and a legend of outcome colours with counts."""
        from PIL import Image, ImageDraw

        h, w = self.images[0].shape[:2]
        legend = 26
        sheet = Image.new("RGB", (len(self.images) * w, h + TITLE_HEIGHT + legend), BACKGROUND)
        for k, img in enumerate(self.images):
            sheet.paste(Image.fromarray(img), (k * w, TITLE_HEIGHT))
        draw = ImageDraw.Draw(sheet)
        draw.text((6, 3), title, fill=(20, 20, 20), font=_font(15))
        x = 6
        font = _font(13)
        for outcome in OUTCOMES:
            if counts.get(outcome, 0) == 0:
                continue
            y = h + TITLE_HEIGHT + 6
            draw.rectangle([x, y + 2, x + 12, y + 14], fill=OUTCOME_COLORS[outcome])
            text = f"{outcome} {counts[outcome]}"
            draw.text((x + 17, y), text, fill=(20, 20, 20), font=font)
            x += 30 + int(draw.textlength(text, font=font))
        return np.asarray(sheet)


def overview(renderer: GraspRenderer, rows: pd.DataFrame, size: int = 2 * VIEW_SIZE) -> Overview:
    """Every grasp in ``rows`` as a glyph coloured by outcome over the object (two views).

    Glyph parts behind the object (depth test against the render) are drawn faint; successes
    are drawn last so they stay on top.
    """
    renderer.hide_gripper()
    rows = drawing_order(rows)
    T = poses_as_matrices(rows)
    out = Overview([], [], [], [], rows["grasp_id"].to_numpy())
    for camera in overview_cameras(renderer.mesh, size):
        frame = renderer.render(camera)
        out.images.append(draw_glyphs(frame, T, rows["width"].to_numpy(), rows["outcome"], renderer.pad_tip))
        out.frames.append(frame)
        out.object_masks.append(renderer.object_mask(frame))
        out.tcp_pixels.append(project(camera, T[:, :3, 3])[0])
    return out


def drawing_order(rows: pd.DataFrame) -> pd.DataFrame:
    """``rows`` in the order their glyphs are drawn: collisions first, successes last (on top)."""
    rank = {"collision": 0, "success": 2}  # drawn first .. last
    order = np.argsort([rank.get(o, 1) for o in rows["outcome"]], kind="stable")
    return rows.iloc[order].reset_index(drop=True)


def draw_glyphs(frame: Frame, T: np.ndarray, widths: np.ndarray, outcomes, pad_tip: float) -> np.ndarray:
    """``frame``'s picture (h, w, 3) uint8 with a glyph per grasp ``T`` (n, 4, 4) (the frame's
    world), ``widths`` (n,) m, coloured by ``outcomes`` (n,) and drawn in that order; parts behind
    what the frame shows (its depth) faint."""
    from PIL import Image, ImageDraw

    camera = frame.camera
    segs = glyph_segments(T, widths, pad_tip)
    samples = np.linspace(0.0, 1.0, 12)
    img = Image.fromarray(frame.rgb).convert("RGBA")
    faint = Image.new("RGBA", img.size, (0, 0, 0, 0))
    draw_faint = ImageDraw.Draw(faint)
    pts = segs[..., None, :, :]  # (n, 4, 1, 2, 3)
    line = pts[..., 0, :] + samples[:, None] * (pts[..., 1, :] - pts[..., 0, :])  # (n, 4, s, 3)
    uv, depth = project(camera, line.reshape(-1, 3))
    uv = uv.reshape(*line.shape[:3], 2)
    depth = depth.reshape(line.shape[:3])
    col = np.clip(np.round(uv[..., 0]).astype(int), 0, camera.width - 1)
    row_ = np.clip(np.round(uv[..., 1]).astype(int), 0, camera.height - 1)
    visible = depth <= frame.depth[row_, col] + 0.002
    layer = Image.new("RGBA", img.size, (0, 0, 0, 0))
    draw = ImageDraw.Draw(layer)
    for i, outcome in enumerate(outcomes):
        rgb = OUTCOME_COLORS.get(outcome, (0, 0, 0))
        width, alpha = GLYPH_WIDTH.get(outcome, 2), GLYPH_ALPHA.get(outcome, 255)
        for s in range(4):
            p = uv[i, s]
            for k in range(len(samples) - 1):
                seg = [tuple(p[k]), tuple(p[k + 1])]
                if visible[i, s, k] and visible[i, s, k + 1]:
                    draw.line(seg, fill=(*rgb, alpha), width=width)
                else:
                    draw_faint.line(seg, fill=(*rgb, alpha * 2 // 5), width=1)
    return np.asarray(Image.alpha_composite(Image.alpha_composite(img, faint), layer).convert("RGB"))


# ------------------------------------------------------------------------------------ the command


@dataclass(frozen=True)
class ShowResult:
    """What ``show`` wrote: the sheet, how many grasps, the overview."""

    sheet: Path
    overview: Path
    n_grasps: int


def show(
    labels_dir: Path,
    object_id: str,
    png: Path,
    n: int = 8,
    seed: int = 0,
    outcomes: tuple[str, ...] = (),
    grasp_ids: tuple[int, ...] = (),
    objects_dir: Path | None = None,
    overview_png: Path | None = None,
    labels: pd.DataFrame | None = None,
    mesh=None,
    gripper: GripperDescription | str | None = None,
    overwrite: bool = False,
) -> ShowResult:
    """Write the grasp sheet to ``png`` and the overview to ``overview_png`` (default
    ``<png stem>-overview.png``). ``labels``/``mesh``: already loaded (the report passes them);
    ``gripper``: the gripper the labels were made with (default the RG2); ``overwrite``: replace
    pictures of these names that this tool did not write (else ToolError before any work)."""
    from annotator.tools.common import claim_outputs

    overview_png = overview_png or png.with_name(f"{png.stem}-overview{png.suffix or '.png'}")
    outputs = {"--png": png, "--overview": overview_png}
    with claim_outputs("annotator show", outputs, overwrite) as claimed:
        return _write_show(
            claimed, labels_dir, object_id, n, seed, outcomes, grasp_ids, objects_dir, labels, mesh, gripper
        )


def _write_show(
    claimed, labels_dir, object_id, n, seed, outcomes, grasp_ids, objects_dir, labels, mesh, gripper
) -> ShowResult:
    """:func:`show`'s work once its outputs are claimed (``claimed``: their
    :class:`annotator.tools.common.ToolOutputs`)."""
    from annotator.tools.common import ToolError, object_mesh, object_rows, png_bytes, read_labels

    labels = read_labels(labels_dir) if labels is None else labels
    rows = object_rows(labels, object_id)
    bad = sorted(set(outcomes) - set(OUTCOMES))
    if bad:
        raise ToolError(f"unknown outcome(s) {bad}; choose from {', '.join(OUTCOMES)}")
    try:
        chosen = choose_grasps(rows, n, seed, outcomes, grasp_ids)
    except ValueError as exc:
        raise ToolError(f"{object_id}: {exc}") from None
    if chosen.empty:
        have = ", ".join(f"{k} {v}" for k, v in rows["outcome"].value_counts().items())
        raise ToolError(f"{object_id} has no {'/'.join(outcomes)} grasps ({have})")
    mesh = object_mesh(labels_dir, object_id, objects_dir, rows) if mesh is None else mesh
    with GraspRenderer(mesh, description=gripper) as renderer:
        sheet = png_bytes(grasp_sheet(renderer, chosen))
        pool = rows[rows["outcome"].isin(outcomes)] if outcomes else rows
        ov = overview(renderer, pool)
    counts = pool["outcome"].value_counts().to_dict()
    title = f"{object_id}: {len(pool)} grasps by outcome (faint: behind the object)"
    png = claimed.write_bytes("--png", sheet)
    overview_png = claimed.write_bytes("--overview", png_bytes(ov.picture(title, counts)))
    log.info("wrote %s (%d grasps) and %s", png, len(chosen), overview_png)
    return ShowResult(png, overview_png, len(chosen))
