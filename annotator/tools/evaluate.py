"""Simulating grasps someone else proposed (a network's predictions, hand-picked poses, real trials).

Input: a Parquet or CSV file with ``object_id``, the TCP pose as the labels give it (``x y z``,
``qx qy qz qw`` in the object's mesh frame, metres, xyzw) and optionally ``width`` (m, the opening
at the grasp: the chord between the pads) and ``grasp_id``. Output: the label columns for every
row, written by the job's own pipeline (spans of given poses instead of sampled candidates), with
the same resume, determinism and worker behaviour as ``annotate``.

With ``frame="base"`` the pose columns are the pose of the gripper's base link instead (ACRONYM's
and GraspGen's convention): each becomes a TCP pose through the gripper model's own forward
kinematics, ``T_obj_tcp = T_obj_base · T_base_tcp(width)`` (:func:`tcp_from_base`). With
``--resting`` a table may also give ``rest_qx rest_qy rest_qz rest_qw``: the orientation the
object rests in on the table (its mesh frame in the table frame, :mod:`annotator.cell.resting`;
a cell label's settled ``obj_q*`` serve when those are absent).

A grasp is executed as a sampled candidate whose expected chord is ``width``: the RG2 is placed so
that its TCP at that opening is at the pose, opened ``2 x pregrasp_clearance`` wider, checked along
the approach and closed from ``width + 2 x preclose_gap``. Without a ``width`` column the opening is
measured on the mesh over the pads' faces (:func:`expected_width`): the pad face (its width
across, its length along the approach: :func:`pad_face`) is swept along the closing axis between
the fully open pads, and the opening is twice the farthest the object reaches from the TCP there,
so that the open pads, centred on the TCP, clear it, also where the TCP's own line misses the
object (an off-centre grasp); 0 when the pads would close on nothing. The mesh is read
and cleaned here, as the workers see it, but never decomposed: the decompositions are the
workers' (:mod:`annotator.pipeline.schedule`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from annotator.agreement import Agreement
from annotator.dataset import POSE_COLUMNS
from annotator.tools.given import CMD_COLUMNS, records_commands, replay_grasps

log = logging.getLogger(__name__)

# A quaternion this far from unit norm is renormalised silently (float32 predictions); further
# off is an error in the input, not noise.
QUAT_RENORMALISE_TOL = 1e-3
# The orientation an object rests in (evaluate --resting): its mesh frame in the table frame, xyzw;
# a cell label's settled orientation (obj_q*, the world's axes are the table's) serves without them.
REST_COLUMNS = ("rest_qx", "rest_qy", "rest_qz", "rest_qw")
CELL_ORIENTATION_COLUMNS = ("obj_qx", "obj_qy", "obj_qz", "obj_qw")
FRAMES = ("tcp", "base")  # what the pose columns of a grasp table are the pose of


def read_grasps(path: str | Path, frame: str = "tcp") -> pd.DataFrame:
    """The proposed grasps, validated: ``object_id`` (str), pose columns (float64, unit xyzw),
    ``width`` (float64, NaN where not given) and ``grasp_id`` (int64, unique per object; the row
    number within its object when not given); a label table's commanded grasps (``cmd_*``) and
    ``outcome`` are kept, and so are resting orientations (``rest_q*``, or a cell label's ``obj_q*``,
    as ``rest_q*``; unit xyzw). ``frame``: what
    the pose columns hold, the TCP's pose or the gripper base link's (``"base"``; a label table's
    are always TCP poses). Raises :class:`annotator.tools.common.ToolError` naming the file and
    the first bad row: nothing is dropped or replaced silently.
    """
    from annotator.tools.common import ToolError

    if frame not in FRAMES:
        raise ToolError(f"--frame {frame!r}: choose from {', '.join(FRAMES)}")
    path = Path(path)
    df = _read_table(path)
    out = pd.DataFrame({"object_id": df["object_id"].astype(str).to_numpy(dtype=object)})
    out[list(POSE_COLUMNS)] = _numbers(df, POSE_COLUMNS, path)
    out[["qx", "qy", "qz", "qw"]] = _unit_quaternions(out[["qx", "qy", "qz", "qw"]].to_numpy(), path, "")
    out["width"] = _widths(df, path)
    out["grasp_id"] = _grasp_ids(df, out, path)
    labels = any(c in df.columns for c in CMD_COLUMNS) or "outcome" in df.columns
    if labels and frame != "tcp":
        raise ToolError(f"{path} is a label table: its poses are TCP poses; drop --frame {frame}")
    if any(c in df.columns for c in CMD_COLUMNS):  # a label table: its commanded grasps, bit for bit
        _commanded(df, out, path)
    if "outcome" in df.columns:
        out["outcome"] = df["outcome"].astype(str).to_numpy(dtype=object)
    for columns, prefix in ((REST_COLUMNS, "rest_"), (CELL_ORIENTATION_COLUMNS, "obj_")):
        if any(c in df.columns for c in columns):
            missing = [c for c in columns if c not in df.columns]
            if missing:
                raise ToolError(f"{path}: has some of {list(columns)} but not {missing}; give all or none")
            out[list(REST_COLUMNS)] = _unit_quaternions(_numbers(df, columns, path), path, prefix)
            break
    return out


def _read_table(path: Path) -> pd.DataFrame:
    from annotator.tools.common import ToolError, read_table

    df = read_table(path, "grasps file")  # a column named twice is refused, not the first one used
    missing = [c for c in ("object_id", *POSE_COLUMNS) if c not in df.columns]
    if missing:
        raise ToolError(
            f"{path}: missing column(s) {missing}; need object_id, {', '.join(POSE_COLUMNS)} [, width]"
        )
    if df.empty:
        raise ToolError(f"{path}: no grasps")
    return df


def _numbers(df: pd.DataFrame, columns, path: Path) -> np.ndarray:
    """Columns as float64 (n, k); ToolError naming the first row with a missing or non-number."""
    from annotator.tools.common import ToolError

    values = np.column_stack(
        [pd.to_numeric(df[c], errors="coerce").to_numpy(dtype=np.float64) for c in columns]
    )
    bad = ~np.isfinite(values)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise ToolError(f"{path}: row {row}: {columns[col]} is missing or not a finite number")
    return values


def _unit_quaternions(q: np.ndarray, path: Path, prefix: str) -> np.ndarray:
    """xyzw quaternions renormalised (within QUAT_RENORMALISE_TOL of unit) with w >= 0."""
    from annotator.tools.common import ToolError

    norm = np.linalg.norm(q, axis=1)
    bad = np.abs(norm - 1.0) > QUAT_RENORMALISE_TOL
    if bad.any():
        row = int(np.argmax(bad))
        names = ", ".join(f"{prefix}q{a}" for a in "xyzw")
        raise ToolError(f"{path}: row {row}: quaternion ({names}) has norm {norm[row]:.4g}, not 1")
    from annotator.geometry import canonical_quat

    return canonical_quat(q / norm[:, None])  # w >= 0, as the labels


def _widths(df: pd.DataFrame, path: Path) -> np.ndarray:
    from annotator.tools.common import ToolError

    if "width" not in df.columns:
        return np.full(len(df), np.nan)
    width = pd.to_numeric(df["width"], errors="coerce").to_numpy(dtype=np.float64)
    if (width[np.isfinite(width)] < 0).any():
        raise ToolError(f"{path}: width must be >= 0 (metres)")
    return width


def _grasp_ids(df: pd.DataFrame, out: pd.DataFrame, path: Path) -> np.ndarray:
    from annotator.tools.common import ToolError

    if "grasp_id" not in df.columns:
        return out.groupby("object_id", sort=False).cumcount().astype(np.int64).to_numpy()
    ids = pd.to_numeric(df["grasp_id"], errors="coerce")
    bad = ids.isna() | (ids < 0) | (ids != ids.round()) | (ids > 2**62)
    if bad.any():
        row = int(np.argmax(bad.to_numpy()))
        raise ToolError(
            f"{path}: row {row}: grasp_id {df['grasp_id'].astype(str).iloc[row]} "
            "is not a non-negative integer"
        )
    keyed = pd.DataFrame({"object_id": out["object_id"].to_numpy(), "grasp_id": ids.to_numpy(dtype=np.int64)})
    if keyed.duplicated().any():
        first = keyed[keyed.duplicated()].iloc[0]
        raise ToolError(f"{path}: grasp {int(first.grasp_id)} of {first.object_id!r} appears twice")
    return keyed["grasp_id"].to_numpy()


def _commanded(df: pd.DataFrame, out: pd.DataFrame, path: Path) -> None:
    """A label table's commanded grasps, checked row by row: all of ``CMD_COLUMNS`` or none, every
    value finite, unit quaternions. A bad row is named (the rows are replayed from exactly these
    values; dropping them would replay every row from another pose)."""
    from annotator.tools.common import ToolError

    missing = [c for c in CMD_COLUMNS if c not in df.columns]
    if missing:
        raise ToolError(f"{path}: has some commanded-grasp columns but not {missing}; give all or none")
    cmd = _numbers(df, CMD_COLUMNS, path)
    norm = np.linalg.norm(cmd[:, 3:7], axis=1)
    bad = np.abs(norm - 1.0) > 1e-9
    if bad.any():
        row = int(np.argmax(bad))
        raise ToolError(
            f"{path}: row {row}: commanded quaternion (cmd_qx .. cmd_qw) has norm {norm[row]:.6g}, not 1; "
            "fix the row, or drop every cmd_* column to evaluate the end-of-close poses instead"
        )
    out[list(CMD_COLUMNS)] = cmd


@dataclass(frozen=True)
class PadFace:
    """The part of a pad that meets the object, in the TCP's axes: ``width`` (m) across (y) and
    ``length`` (m) along the approach (z), centred on the TCP's (y, z) (the TCP is the pad-centre
    midpoint)."""

    width: float
    length: float


def pad_face(gripper=None, config=None) -> PadFace:
    """The pad face of a gripper model (a description, name or folder; None: the RG2): the
    description's ``[pads] size``, else the pad link's collision box (a private DIRECT client)."""
    from annotator.config import GripperConfig
    from annotator.grippers import load_gripper
    from annotator.sim.body import Body
    from annotator.sim.gripper import ParallelGripper
    from annotator.sim.world import World

    description = load_gripper(gripper)
    extents: tuple[float, float, float] | np.ndarray
    if description.pad_size is not None:
        extents = description.pad_size
    else:
        with World() as world:
            body = Body.load(world.client, description.urdf, fixed_base=True)
            extents = ParallelGripper(body, description, config or GripperConfig())._pad_extents()
    return PadFace(float(extents[1]), float(extents[2]))


def expected_width(mesh, T_obj_tcp: np.ndarray, max_width: float, pads: PadFace | None = None) -> np.ndarray:
    """The opening each grasp needs, (n,) m, so that the pads, open that wide and centred on the
    TCP, clear the object: twice the farthest the mesh reaches from the TCP along the closing axis
    (the TCP's x), over the pad face swept along that axis (``pads``: the prism ``|y| <= width/2``,
    ``|z| <= length/2`` of the TCP's frame, exactly, triangle by triangle; None: the one line
    through the TCP: the chord the open pads meet moving towards the TCP, 0 when one meets nothing
    before it), counting only the surface between the fully open pads (``|x| <= max_width/2``).

    0 when the mesh meets the swept face nowhere between the open pads (nothing to close on: such
    a row comes back ``no_contact``); ``max_width`` when the object reaches the open pads (the
    row is then a collision of the approach with the object). For a grasp centred on its chord,
    the chord. ``mesh`` : trimesh.Trimesh in the object frame; ``T_obj_tcp`` : (n, 4, 4).
    """
    T = np.asarray(T_obj_tcp, dtype=np.float64).reshape(-1, 4, 4)
    triangles = np.asarray(mesh.triangles, dtype=np.float64)
    half = max_width / 2
    if pads is None:
        return _line_width(triangles, T, max_width)
    a, b = pads.width / 2, pads.length / 2
    centres = triangles.mean(axis=1)
    radius = np.linalg.norm(triangles - centres[:, None, :], axis=2).max(axis=1)
    out = np.zeros(len(T))
    for k in range(len(T)):
        R, p = T[k, :3, :3], T[k, :3, 3]
        c = (centres - p) @ R  # triangle centres in the TCP frame
        near = (np.abs(c[:, 1]) <= a + radius) & (np.abs(c[:, 2]) <= b + radius)
        near &= np.abs(c[:, 0]) <= half + radius
        if not near.any():
            continue
        local = (triangles[near] - p) @ R  # (f, 3, 3)
        lo, hi = _x_range_in_prism(local, a, b)
        meets = np.isfinite(lo) & (hi >= -half) & (lo <= half)
        if meets.any():
            reach = np.minimum(np.maximum(np.abs(lo[meets]), np.abs(hi[meets])), half)
            # a triangle spanning the TCP plane's far side has its nearest point inside: its
            # farthest is what the pad must clear
            out[k] = 2.0 * float(reach.max())
    return np.clip(out, 0.0, max_width)


def _x_range_in_prism(tri: np.ndarray, a: float, b: float) -> tuple[np.ndarray, np.ndarray]:
    """For triangles ``tri`` (f, 3, 3) in the TCP frame, the range (lo, hi) (f,) of x over each
    one's part inside the prism ``|y| <= a, |z| <= b`` (inf, -inf where it has none): the extremes
    of x over that convex polygon are at its corners, which are the triangle's corners inside the
    prism, its edges' crossings of the prism's four faces, and the prism's four edges' crossings
    of the triangle."""
    f = tri.shape[0]
    lo, hi = np.full(f, np.inf), np.full(f, -np.inf)

    def take(x: np.ndarray, ok: np.ndarray) -> None:  # x, ok : (f, k)
        nonlocal lo, hi
        lo = np.minimum(lo, np.where(ok, x, np.inf).min(axis=1))
        hi = np.maximum(hi, np.where(ok, x, -np.inf).max(axis=1))

    eps = 1e-12
    y, z = tri[:, :, 1], tri[:, :, 2]
    take(tri[:, :, 0], (np.abs(y) <= a + eps) & (np.abs(z) <= b + eps))  # corners inside
    p0, p1 = tri, np.roll(tri, -1, axis=1)  # the three edges, (f, 3, 3) each
    d = p1 - p0
    for axis, bound, other, other_bound in ((1, a, 2, b), (2, b, 1, a)):
        for plane in (-bound, bound):
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (plane - p0[:, :, axis]) / d[:, :, axis]
            ok = (t >= 0) & (t <= 1)
            t = np.where(ok, t, 0.0)
            hit = p0 + t[:, :, None] * d
            take(hit[:, :, 0], ok & (np.abs(hit[:, :, other]) <= other_bound + eps))
    # the prism's edges (lines along x at y = +-a, z = +-b) through each triangle: barycentric
    # coordinates of (y, z) in the triangle's projection on the yz plane
    e1, e2 = tri[:, 1, 1:] - tri[:, 0, 1:], tri[:, 2, 1:] - tri[:, 0, 1:]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    flat = np.abs(det) < 1e-18  # the triangle contains the x direction: its edges bound it
    det = np.where(flat, 1.0, det)
    xs, oks = [], []
    for cy in (-a, a):
        for cz in (-b, b):
            q = np.array([cy, cz]) - tri[:, 0, 1:]
            u = (q[:, 0] * e2[:, 1] - q[:, 1] * e2[:, 0]) / det
            v = (e1[:, 0] * q[:, 1] - e1[:, 1] * q[:, 0]) / det
            ok = ~flat & (u >= 0) & (v >= 0) & (u + v <= 1)
            xs.append(tri[:, 0, 0] + u * (tri[:, 1, 0] - tri[:, 0, 0]) + v * (tri[:, 2, 0] - tri[:, 0, 0]))
            oks.append(ok)
    take(np.stack(xs, axis=1), np.stack(oks, axis=1))
    return lo, hi


def _line_width(triangles: np.ndarray, T: np.ndarray, max_width: float) -> np.ndarray:
    """The chord along the one line through each TCP: the fully open pads moved towards the TCP
    until each meets the mesh; 0 when one meets nothing before the TCP."""
    from annotator.sampler import _first_hits

    x, p = T[:, :3, 0], T[:, :3, 3]
    half = max_width / 2
    t1, _ = _first_hits(triangles, p - half * x, x)  # pad 1 moving along +x
    t2, _ = _first_hits(triangles, p + half * x, -x)  # pad 2 moving along -x
    width = max_width - t1 - t2
    ok = (t1 <= half) & (t2 <= half) & np.isfinite(width)
    return np.where(ok, np.clip(width, 0.0, max_width), 0.0)


def tcp_from_base(
    T_obj_base: np.ndarray,
    width: np.ndarray,
    depth,
    mesh=None,
    iterations: int = 4,
    pads: PadFace | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """TCP poses (n, 4, 4) and chords (n,) of grasps given as base-link poses ``T_obj_base`` (n, 4, 4).

    ``T_obj_tcp = T_obj_base · T_base_tcp(width)`` with the gripper model's FK (``depth``: an
    :class:`annotator.tools.export.TcpDepth`). Where ``width`` is NaN the chord is measured on
    ``mesh`` (:func:`expected_width`) at the TCP of the opening found so far, from the full stroke
    on: a linkage's TCP moves along the approach as it opens, so this is repeated ``iterations``
    times (a sliding gripper's TCP does not move: once is exact); 0 where the pads meet nothing.
    ``pads``: the pad face swept (:func:`expected_width`; None: the line through the TCP).
    """
    T_obj_base = np.asarray(T_obj_base, dtype=np.float64).reshape(-1, 4, 4)
    width = np.asarray(width, dtype=np.float64).copy()
    todo = ~np.isfinite(width)
    if todo.any():
        if mesh is None:
            raise ValueError("widths to measure but no mesh")
        guess = np.full(int(todo.sum()), depth.max_width)
        for _ in range(iterations):
            T_tcp = T_obj_base[todo] @ depth.T_base_tcp(guess)
            found = expected_width(mesh, T_tcp, depth.max_width, pads)
            converged = np.array_equal(found, guess)
            guess = found
            if converged:
                break
        width[todo] = guess
    width = np.clip(width, 0.0, depth.max_width)
    return T_obj_base @ depth.T_base_tcp(width), width


def given_candidates(
    grasps: pd.DataFrame,
    objects_dir: Path,
    config,
    scale: float | None,
    max_width: float,
    *,
    gripper=None,
    frame: str = "tcp",
    resting: bool = False,
):
    """The grasps as the pipeline's :class:`GivenCandidates`.

    Per object the grasps keep their ``grasp_id``, which must be exactly 0..k-1 (a label table, or
    ids given so; :func:`read_grasps` numbers them in the file's order when the table has none):
    other ids are a :class:`ToolError`, never renumbered, since a user joins outcomes by them. Rows of a label
    table (an ``outcome`` column) are replayed (:func:`annotator.tools.given.replay_grasps`: their
    commanded grasps bit for bit, so their outcomes are reproduced exactly). Missing widths are
    measured on the mesh (:func:`expected_width`; read, not decomposed: :func:`read_object_mesh`).
    ``frame="base"``: the poses are the gripper's base link's (``gripper``: its description), turned
    into TCP poses (:func:`tcp_from_base`).
    ``resting``: each grasp carries the orientation its object rests in (``rest_q*``, else upright).
    """
    import hashlib

    from annotator.pipeline.source import GivenCandidates
    from annotator.tools.common import ToolError

    sources = _sources(objects_dir)
    out = {}
    digest = hashlib.sha256()
    depth = None
    if frame == "base":
        from annotator.tools.export import TcpDepth

        depth = TcpDepth(gripper, config.gripper)
    pads = _pads_to_measure(grasps, gripper, config)
    for oid, rows in grasps.groupby("object_id", sort=True):
        ids = rows["grasp_id"].to_numpy()
        if not np.array_equal(np.sort(ids), np.arange(len(rows))):
            shown = ", ".join(str(int(i)) for i in np.sort(ids)[:4]) + (" ..." if len(ids) > 4 else "")
            raise ToolError(
                f"the grasp_ids of {oid!r} ({shown}) are not 0..{len(rows) - 1}: evaluate writes each "
                "object's grasps as 0..k-1 and never renumbers ids a table gives; give 0..k-1 per object "
                "(keep your own ids in a column of another name), or leave out grasp_id to number them "
                "in the file's order"
            )
        rows = rows.sort_values("grasp_id", kind="stable")
        given = _object_grasps(str(oid), rows, sources, config, scale, max_width, depth, pads)
        if resting:
            given = _with_rest(given, rows)
        out[str(oid)] = given
        digest.update(str(oid).encode() + b"\0" + given.T_obj_tcp.tobytes() + given.width.tobytes())
        if given.rest_quat is not None:
            digest.update(given.rest_quat.tobytes())
    return GivenCandidates(out, digest.hexdigest())


def _sources(objects_dir: Path) -> dict:
    from annotator.objects import ObjectDiscoveryError, discover_objects
    from annotator.tools.common import ToolError

    try:
        return {s.object_id: s for s in discover_objects(Path(objects_dir))}
    except ObjectDiscoveryError as exc:
        raise ToolError(str(exc)) from None


def _pads_to_measure(grasps: pd.DataFrame, gripper, config) -> PadFace | None:
    """The pad face widths are measured over (:func:`pad_face`), or None when every width is given."""
    if "outcome" in grasps.columns or np.isfinite(grasps["width"].to_numpy(dtype=np.float64)).all():
        return None
    return pad_face(gripper, config.gripper)


def _object_grasps(
    oid: str, rows: pd.DataFrame, sources: dict, config, scale, max_width: float, depth, pads=None
):
    """One object's grasps as the worker's GivenGrasps (label rows replayed, widths measured over
    the pad face ``pads``, a :class:`PadFace`)."""
    from annotator.dataset import poses_as_matrices
    from annotator.pipeline.tasks import GivenGrasps

    if records_commands(rows) or "outcome" in rows.columns:  # label rows: replay them
        T, width, quat = replay_grasps(rows, config, max_width)
        return GivenGrasps(T, width, quat)
    T = poses_as_matrices(rows)
    width = rows["width"].to_numpy(dtype=np.float64).copy()
    todo = ~np.isfinite(width)
    mesh = _mesh(oid, sources, config, scale) if todo.any() and oid in sources else None
    if depth is not None:
        if todo.any() and mesh is None:  # an unknown object: the run names it; no chord to find
            width[todo] = 0.0
        T, width = tcp_from_base(T, width, depth, mesh, pads=pads)
        return GivenGrasps(T, width)
    if mesh is not None:
        width[todo] = expected_width(mesh, T[todo], max_width, pads)
    width = np.clip(np.nan_to_num(width, nan=0.0), 0.0, max_width)
    return GivenGrasps(T, width)


def _mesh(oid: str, sources: dict, config, scale):
    """The object's mesh as the poses see it; not weighed nor decomposed (the workers do that)."""
    from annotator.objects import ObjectError, read_object_mesh
    from annotator.tools.common import ToolError

    try:
        return read_object_mesh(sources[oid], config.objects, scale=scale)
    except ObjectError as exc:
        raise ToolError(f"{oid}: {exc}") from None


def _with_rest(given, rows: pd.DataFrame):
    """``given`` with the resting orientation of each row (upright where the table gives none)."""
    from annotator.pipeline.tasks import GivenGrasps

    if all(c in rows.columns for c in REST_COLUMNS):
        rest = rows[list(REST_COLUMNS)].to_numpy(dtype=np.float64)
    else:
        rest = np.tile([0.0, 0.0, 0.0, 1.0], (len(rows), 1))
    return GivenGrasps(given.T_obj_tcp, given.width, given.quat, np.ascontiguousarray(rest))


def commanded_table(
    grasps: pd.DataFrame,
    objects_dir: Path,
    config,
    scale: float | None,
    max_width: float,
    *,
    gripper=None,
    frame: str = "tcp",
) -> pd.DataFrame:
    """The grasps of :func:`read_grasps` as the commanded grasps a run simulates, one row each in
    the table's order: ``object_id``, ``grasp_id`` (as read), ``cmd_x .. cmd_qw`` and ``cmd_width``
    (the very floats a worker commands: base poses turned into TCP poses, missing widths measured),
    ``object_scale`` (``scale``, NaN: the objects' own) and ``rest_q*`` when given. Replaying these
    rows (:func:`annotator.tools.given.replay_grasps`) simulates exactly what ``evaluate`` does.
    """
    from annotator.geometry import Transform, matrix_to_quat

    sources = _sources(objects_dir)
    depth = None
    if frame == "base":
        from annotator.tools.export import TcpDepth

        depth = TcpDepth(gripper, config.gripper)
    pads = _pads_to_measure(grasps, gripper, config)
    parts = []
    for oid, rows in grasps.groupby("object_id", sort=True):
        given = _object_grasps(str(oid), rows, sources, config, scale, max_width, depth, pads)
        T = np.asarray(given.T_obj_tcp)
        if given.quat is not None:  # label rows: their commanded rotations bit for bit
            quat = np.asarray(given.quat, dtype=np.float64).reshape(-1, 4)
        else:  # as simulate() builds each pose: Transform(pos, quat) normalises the quaternion
            raw = matrix_to_quat(T[:, :3, :3]).reshape(-1, 4)
            quat = np.array([Transform(T[k, :3, 3], raw[k]).quat for k in range(len(T))]).reshape(-1, 4)
        part = pd.DataFrame(
            {"object_id": rows["object_id"].to_numpy(dtype=object), "grasp_id": rows["grasp_id"].to_numpy()}
        )
        part[list(CMD_COLUMNS[:3])] = T[:, :3, 3]
        part[list(CMD_COLUMNS[3:7])] = quat
        part["cmd_width"] = np.asarray(given.width, dtype=np.float64)
        part["object_scale"] = np.nan if scale is None else float(scale)
        if all(c in rows.columns for c in REST_COLUMNS):
            part[list(REST_COLUMNS)] = rows[list(REST_COLUMNS)].to_numpy(dtype=np.float64)
        parts.append(part)
    return pd.concat(parts, ignore_index=True)


# ------------------------------------------------------------------------------ real outcomes

# The grasp table's column of real outcomes evaluate compares every stage with, when it has one.
REAL_COLUMN = "real_success"


def real_outcomes(path: str | Path, column: str, grasps: pd.DataFrame) -> pd.DataFrame:
    """The real outcome of each grasp of ``grasps`` (as :func:`read_grasps` read ``path``, same
    row order): ``object_id``, ``grasp_id``, ``real_success`` (bool) from the table's ``column``
    (1/0, true/false, yes/no). :class:`annotator.tools.common.ToolError` naming the first row
    that is none of those."""
    from annotator.tools.common import ToolError, truth_column

    df = _read_table(Path(path))
    if column not in df.columns:
        raise ToolError(f"{path}: no column {column!r} of real outcomes (--real)")
    return pd.DataFrame(
        {
            "object_id": grasps["object_id"].to_numpy(),
            "grasp_id": grasps["grasp_id"].to_numpy(),
            "real_success": truth_column(df[column], path, column),
        }
    )


@dataclass(frozen=True)
class StageAgreement:
    """Simulated "held through ``gate``" against the real outcomes: the :class:`annotator.tools.
    calibrate.Agreement` of the calls (balanced accuracy, precision, recall with intervals)."""

    gate: str
    held: int
    agreement: Agreement


def stage_agreement(rows: pd.DataFrame, real: pd.DataFrame, samples: int = 2000) -> list[StageAgreement]:
    """Each stage of the protocol (``close``, ``lift``, ``motion``, ``shake``) read as the label
    (:func:`annotator.dataset.held_through` on the rows' ``stage``) against ``real`` (from
    :func:`real_outcomes`), on the grasps both have."""
    from annotator.agreement import agreement
    from annotator.dataset import held_through
    from annotator.outcome import GATES

    both = real.merge(rows, on=["object_id", "grasp_id"], how="inner")
    truth = both["real_success"].to_numpy(dtype=bool)
    out = []
    for gate in GATES:
        held = held_through(both, gate).to_numpy(dtype=bool)
        out.append(StageAgreement(gate, int(held.sum()), agreement(truth, held, samples)))
    return out


def stage_agreement_text(stages: list[StageAgreement], column: str, gate: str, real_rate: float) -> str:
    """The comparison as a few lines: the real rate, then each stage (the run's gate marked)."""
    from annotator.agreement import agreement_text

    if not stages:
        return ""
    n = stages[0].agreement.n
    lines = [f"against the real outcomes ({column}: {n} grasps, {real_rate:.1%} held), trial 0 held through:"]
    for s in stages:
        mark = "  <- [protocol] gate" if s.gate == gate else ""
        text = agreement_text(s.agreement, ("balanced", "precision", "recall"))
        lines.append(f"  {s.gate:>6}: {s.held:>5} held; {text}{mark}")
    return "\n".join(lines)
