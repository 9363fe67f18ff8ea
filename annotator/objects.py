"""Find, load and validate object meshes; give them mass, inertia, convex parts and PyBullet bodies.

Frames: every pose of an object is of its *mesh frame* (the frame its file is written in, in metres
after scaling; for a URDF, the base link frame). PyBullet reports and resets a body's pose at its
centre of mass instead, so use :func:`get_object_pose` / :func:`reset_object_pose`, which convert.
"""

from __future__ import annotations

import hashlib
import logging
import os
import tempfile
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from annotator.config import ObjectConfig
from annotator.geometry import Transform
from annotator.sim import pb as pybullet

log = logging.getLogger(__name__)

MESH_SUFFIXES = (".obj", ".stl", ".ply", ".off", ".glb")
URDF_SUFFIX = ".urdf"
# A mesh is treated as convex (its hull is its collision shape) when its volume is within this
# fraction of its convex hull's volume: 2 % leaves out the chamfers of a real box but not a mug.
CONVEX_VOLUME_TOLERANCE = 0.02
# Below this volume (m^3, a 1 mm cube) a mesh is flat or collinear, whatever its extent.
MIN_VOLUME = 1e-9
MIN_FACES = 4  # a tetrahedron
# PyBullet's createVisualShape(vertices=..., indices=...) rejects very large arrays; bigger meshes
# get their convex hull as the visual (visuals only matter for pictures).
MAX_VISUAL_INDICES = 24_000
DECOMPOSITION_METHOD = "coacd"


class ObjectError(ValueError):
    """One object cannot be used; the message is one line naming the reason."""


class ObjectDiscoveryError(ValueError):
    """The objects folder is missing or holds no objects (a usage error: CLI exit 2)."""


@dataclass(frozen=True)
class ObjectSource:
    """An object found on disk: ``object_id`` is its path relative to the search root, no suffix."""

    object_id: str
    path: Path

    @property
    def is_urdf(self) -> bool:
        return self.path.suffix.lower() == URDF_SUFFIX


@dataclass
class ObjectModel:
    """A loaded, validated object in metres in its mesh frame.

    ``mesh`` : trimesh.Trimesh, the geometry (the collision mesh for a URDF).
    ``center_mass`` : (3,) float, mesh frame. ``inertia`` : (3, 3) float, kg m^2, about the centre
    of mass, axes of the mesh frame. ``parts`` : convex trimesh.Trimesh pieces of the collision
    shape (one, the hull, for a convex object). ``collision_file`` : the cached multi-part .obj
    (``o`` group per part) used for the PyBullet compound, ``None`` for a convex object.
    ``from_cache`` : the decomposition was read from the cache rather than computed.
    """

    object_id: str
    path: Path
    mesh: trimesh.Trimesh
    scale: float
    mass: float
    volume: float
    center_mass: np.ndarray
    inertia: np.ndarray
    mesh_sha256: str
    watertight: bool
    convex: bool
    parts: list[trimesh.Trimesh] = field(default_factory=list)
    collision_file: Path | None = None
    from_cache: bool = False
    decomposition_seconds: float = 0.0
    config: ObjectConfig = field(default_factory=ObjectConfig)

    @property
    def T_obj_com(self) -> Transform:
        """Centre-of-mass frame (principal axes) in the mesh frame."""
        _, R = _principal_axes(self.inertia)
        return Transform.from_rotation(R, self.center_mass)


# --------------------------------------------------------------------------------------------------
# discovery


def _urdf_mesh_refs(urdf: Path) -> list[tuple[str, Path, np.ndarray, np.ndarray]]:
    """``(kind, path, scale (3,), T_link_geom (4, 4))`` of every mesh a URDF references."""
    try:
        root = ET.parse(urdf).getroot()
    except ET.ParseError as exc:
        raise ObjectError(f"{urdf.name}: not a valid URDF ({exc})") from exc
    refs = []
    for link_index, link in enumerate(root.iter("link")):
        for kind in ("collision", "visual"):
            for elem in link.iter(kind):
                mesh = elem.find("geometry/mesh")
                if mesh is None or not mesh.get("filename"):
                    continue
                name = mesh.get("filename", "")
                for prefix in ("package://", "file://"):
                    name = name.removeprefix(prefix)
                scale = np.array([float(s) for s in mesh.get("scale", "1 1 1").split()], dtype=np.float64)
                origin = elem.find("origin")
                T = np.eye(4)
                if origin is not None:
                    xyz = [float(s) for s in origin.get("xyz", "0 0 0").split()]
                    rpy = [float(s) for s in origin.get("rpy", "0 0 0").split()]
                    T = trimesh.transformations.euler_matrix(*rpy, axes="sxyz")
                    T[:3, 3] = xyz
                tag = kind if link_index == 0 else f"{kind}-link{link_index}"
                refs.append((tag, (urdf.parent / name).resolve(), scale, T))
    return refs


def discover_objects(root: Path) -> list[ObjectSource]:
    """All objects under ``root`` (recursive), sorted by ``object_id``.

    Meshes with suffix in ``MESH_SUFFIXES`` and ``.urdf`` files count; a mesh referenced by a URDF
    under ``root`` belongs to that URDF and is not listed. Raises :class:`ObjectDiscoveryError` when
    ``root`` is not a folder or holds no objects.
    """
    root = Path(root)
    if not root.is_dir():
        raise ObjectDiscoveryError(f"objects folder not found: {root}")
    files = sorted(p for p in root.rglob("*") if p.is_file())
    urdfs = [p for p in files if p.suffix.lower() == URDF_SUFFIX]
    owned: set[Path] = set()
    for urdf in urdfs:
        try:
            owned.update(ref[1] for ref in _urdf_mesh_refs(urdf))
        except ObjectError:
            pass  # a broken URDF is still listed; load_object reports it
    sources = []
    for path in files:
        suffix = path.suffix.lower()
        if suffix == URDF_SUFFIX or (suffix in MESH_SUFFIXES and path.resolve() not in owned):
            object_id = path.relative_to(root).with_suffix("").as_posix()
            sources.append(ObjectSource(object_id, path))
    if not sources:
        raise ObjectDiscoveryError(
            f"no objects in {root} (searched recursively for {' '.join(MESH_SUFFIXES)} {URDF_SUFFIX})"
        )
    ids = [s.object_id for s in sources]
    dupes = sorted({i for i in ids if ids.count(i) > 1})
    if dupes:
        raise ObjectDiscoveryError(f"two files give the same object id(s) {dupes}; rename one")
    return sorted(sources, key=lambda s: s.object_id)


def source_digest(source: ObjectSource) -> str:
    """SHA-256 over everything an object is made from: a mesh file's bytes, or a URDF's bytes and
    those of every mesh it references (in the URDF's order, each with its name).

    The run manifest binds it per object: a mesh changed behind an unchanged URDF changes it.
    Raises :class:`ObjectError` (one line) when a file cannot be read.
    """
    h = hashlib.sha256()
    try:
        if source.is_urdf:
            h.update(b"urdf\0" + source.path.read_bytes())
            seen: set[Path] = set()
            for _, mesh_path, _, _ in _urdf_mesh_refs(source.path):
                if mesh_path in seen:
                    continue
                seen.add(mesh_path)
                h.update(b"\0mesh\0" + mesh_path.name.encode() + b"\0" + mesh_path.read_bytes())
        else:
            h.update(b"mesh\0" + source.path.read_bytes())
    except OSError as exc:
        raise ObjectError(f"cannot read {exc.filename or source.path}: {exc.strerror or exc}") from exc
    return h.hexdigest()


# --------------------------------------------------------------------------------------------------
# loading and validation


def _read_mesh(path: Path) -> trimesh.Trimesh:
    """One triangle mesh from a mesh file, unprocessed, or ObjectError."""
    if not path.is_file():
        raise ObjectError(f"file not found: {path}")
    if path.stat().st_size == 0:
        raise ObjectError(f"empty file: {path.name}")
    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for unreadable input
        raise ObjectError(f"not a readable mesh: {path.name} ({type(exc).__name__}: {exc})") from exc
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise ObjectError(f"not a mesh (no triangles found): {path.name}")
    return loaded


def _fill_simple_holes(mesh: trimesh.Trimesh) -> trimesh.Trimesh | None:
    """``mesh`` with each simple boundary loop closed by a fan around its centroid, or ``None``.

    ``None`` when the boundary is not a set of simple loops (non-manifold edges, touching holes)
    or the result is still not a consistently wound closed surface.
    """
    once = trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1)
    if len(once) == 0:
        return None
    nxt: dict[int, int] = {}
    for a, b in mesh.edges[once]:  # directed as in their faces
        if int(a) in nxt:
            return None
        nxt[int(a)] = int(b)
    vertices, faces = [mesh.vertices], [mesh.faces]
    n_vertices = len(mesh.vertices)
    while nxt:
        start = next(iter(nxt))
        loop = [start]
        while True:
            following = nxt.pop(loop[-1], None)
            if following is None:
                return None
            if following == start:
                break
            loop.append(following)
        centre = n_vertices
        n_vertices += 1
        vertices.append(mesh.vertices[loop].mean(axis=0, keepdims=True))
        # the fill runs against the boundary's direction so the winding stays consistent
        faces.append(np.array([(b, a, centre) for a, b in zip(loop, loop[1:] + loop[:1], strict=True)]))
    filled = trimesh.Trimesh(np.vstack(vertices), np.vstack(faces), process=False)
    if not (filled.is_watertight and filled.is_winding_consistent):
        return None
    return filled


def _principal_axes(inertia: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Principal moments (3,) and a proper rotation (3, 3) whose columns are the principal axes."""
    moments, R = np.linalg.eigh(0.5 * (inertia + inertia.T))
    if np.linalg.det(R) < 0:
        R[:, 2] *= -1.0
    return np.maximum(moments, 0.0), R


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def load_object(
    source: ObjectSource | Path,
    config: ObjectConfig,
    scale: float | None = None,
    cache_dir: Path | None = None,
) -> ObjectModel:
    """Load, validate, weigh and decompose one object.

    ``scale`` multiplies the file's coordinates (after a URDF's own mesh scale); ``None`` is 1.
    Mass = volume x ``config.density``. A mesh that is not watertight has no defined inside: its
    simple holes (boundary loops, e.g. a scan's open bottom) are first closed with a fan of
    triangles; if it is still open, its convex hull stands in for volume, mass, centre of mass,
    inertia *and* collision shape (an upper bound on mass and shape; logged as a warning). CoACD
    on open meshes was measured at 1-2 minutes per object with unpredictable parts, so it is not
    attempted.
    Raises :class:`ObjectError` with a one-line reason for unusable input.
    """
    if isinstance(source, Path | str):
        path = Path(source)
        source = ObjectSource(path.stem, path)
    path = source.path
    user_scale = 1.0 if scale is None else float(scale)
    if not np.isfinite(user_scale) or user_scale <= 0:
        raise ObjectError(f"scale must be a positive number, got {scale}")

    if source.is_urdf:
        if not path.is_file() or path.stat().st_size == 0:
            raise ObjectError(f"empty or missing URDF: {path.name}")
        refs = _urdf_mesh_refs(path)
        collision = [r for r in refs if r[0] == "collision"] or [r for r in refs if r[0] == "visual"]
        if not collision:
            raise ObjectError(f"{path.name}: no mesh in its base link (only mesh objects are supported)")
        pieces, blobs = [], []
        for _, mesh_path, mesh_scale, T in collision:
            piece = _read_mesh(mesh_path)
            blobs.append(mesh_path.read_bytes())
            piece.vertices = piece.vertices * mesh_scale
            piece.apply_transform(T)
            pieces.append(piece)
        mesh = trimesh.util.concatenate(pieces) if len(pieces) > 1 else pieces[0]
        # The hash is of the collision mesh file(s): what is simulated.
        mesh_sha = _sha256(b"".join(blobs))
    else:
        mesh = _read_mesh(path)
        mesh_sha = _sha256(path.read_bytes())

    name = source.object_id
    if not np.all(np.isfinite(mesh.vertices)):
        raise ObjectError(f"{name}: vertices contain NaN or inf")
    mesh.vertices = mesh.vertices * user_scale
    mesh.merge_vertices()
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) < MIN_FACES:
        raise ObjectError(f"{name}: degenerate mesh ({len(mesh.faces)} non-degenerate faces)")

    extent = float(np.max(mesh.extents))
    if extent > config.max_extent:
        hint = "looks like millimetres" if extent / 1000.0 <= config.max_extent else "far too large"
        raise ObjectError(f"{name}: {hint} (extent {extent:.3g} m); pass --scale 0.001")
    if extent < config.min_extent:
        raise ObjectError(
            f"{name}: too small (extent {extent * 1000:.3g} mm < {config.min_extent * 1000:.3g} mm); "
            "check units or pass --scale"
        )
    try:
        hull = mesh.convex_hull
        hull_volume = float(hull.volume)
    except Exception as exc:  # qhull fails on flat or collinear input
        raise ObjectError(f"{name}: degenerate mesh (zero volume: flat or collinear)") from exc
    if not hull_volume > MIN_VOLUME:
        raise ObjectError(f"{name}: degenerate mesh (zero volume: flat or collinear)")

    watertight = bool(mesh.is_watertight and mesh.is_winding_consistent)
    if not watertight:
        filled = _fill_simple_holes(mesh)
        if filled is not None:
            log.warning(
                "%s: mesh was open; closed %d hole(s)", name, len(filled.vertices) - len(mesh.vertices)
            )
            mesh, watertight = filled, True
    if watertight:
        if mesh.volume < 0:
            mesh.invert()
        solid = mesh
        if not mesh.volume > MIN_VOLUME:
            raise ObjectError(f"{name}: degenerate mesh (zero enclosed volume)")
    else:
        log.warning("%s: mesh is not watertight; using its convex hull for mass, inertia and collision", name)
        solid = hull
    props = trimesh.triangles.mass_properties(solid.triangles, density=config.density)
    volume = float(solid.volume)
    convex = watertight and volume >= (1.0 - CONVEX_VOLUME_TOLERANCE) * hull_volume

    model = ObjectModel(
        object_id=name,
        path=path,
        mesh=mesh,
        scale=user_scale,
        mass=float(props.mass),
        volume=volume,
        center_mass=np.asarray(props.center_mass, dtype=np.float64),
        inertia=np.asarray(props.inertia, dtype=np.float64),
        mesh_sha256=mesh_sha,
        watertight=watertight,
        convex=convex,
        config=config,
    )
    if convex or not watertight:
        model.parts = [hull]
    else:
        model.parts, model.collision_file, model.from_cache, model.decomposition_seconds = decompose(
            mesh, mesh_sha, config, cache_dir=cache_dir
        )
    return model


# --------------------------------------------------------------------------------------------------
# convex decomposition, cached
#
# Measured on this project's concave objects (objects/, one core, threshold 0.05, fresh cache);
# "extra" is volume the parts fill that the mesh does not (e.g. a mug's cavity), lower is better:
#   object   CoACD 1.0.14                     PyBullet V-HACD (pybullet.vhacd defaults)
#   mug      23 parts 13 s  extra 20 cm^3      21 parts 19 s  extra 40 cm^3
#   bowl     39 parts 15 s  extra 29 cm^3      55 parts 35 s  extra 49 cm^3
#   banana    2 parts  1 s  extra  6 cm^3       2 parts  3 s  extra 13 cm^3
#   ring     12 parts  4 s  extra  3 cm^3      12 parts 22 s  extra  6 cm^3
# CoACD is both faster and about twice as tight (it cuts along concave edges rather than voxelising),
# and it is deterministic given a seed, so it is the method; V-HACD would avoid one dependency but
# partly fills cavities and rims, exactly where a gripper finger goes.


def default_cache_dir() -> Path:
    """``$RG2_CACHE_DIR`` if set, else ``~/.cache/rg2-annotator``."""
    env = os.environ.get("RG2_CACHE_DIR")
    return Path(env) if env else Path.home() / ".cache" / "rg2-annotator"


def _geometry_tag(mesh: trimesh.Trimesh) -> str:
    """Short hash of the final vertices and faces, so a rescaled mesh gets its own cache entry."""
    h = hashlib.sha256(np.ascontiguousarray(np.round(mesh.vertices, 9)).tobytes())
    h.update(np.ascontiguousarray(mesh.faces, dtype=np.int64).tobytes())
    return h.hexdigest()[:12]


def cache_path(mesh: trimesh.Trimesh, mesh_sha256: str, config: ObjectConfig, cache_dir: Path | None) -> Path:
    """Where the decomposition of ``mesh`` is cached: mesh hash + geometry + method parameters."""
    root = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    params = f"{DECOMPOSITION_METHOD}-t{config.decomposition_threshold:g}-seed0"
    return root / f"{mesh_sha256}_{_geometry_tag(mesh)}_{params}.obj"


def _write_parts_obj(parts: list[trimesh.Trimesh], path: Path) -> None:
    """Multi-part .obj, one ``o`` group per convex part (what PyBullet loads as a compound)."""
    lines, offset = [], 1
    for i, part in enumerate(parts):
        lines.append(f"o part_{i}")
        lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in part.vertices]
        lines += [f"f {a + offset} {b + offset} {c + offset}" for a, b, c in part.faces]
        offset += len(part.vertices)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.stem, suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write("\n".join(lines) + "\n")
        os.replace(tmp, path)  # atomic: concurrent workers see the whole file or none
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _read_parts_obj(path: Path) -> list[trimesh.Trimesh]:
    parts: list[trimesh.Trimesh] = []
    verts: list[list[float]] = []
    for line in path.read_text().splitlines():
        if line.startswith("o ") and verts:
            parts.append(trimesh.Trimesh(np.array(verts)).convex_hull)
            verts = []
        elif line.startswith("v "):
            verts.append([float(v) for v in line.split()[1:4]])
    if verts:
        parts.append(trimesh.Trimesh(np.array(verts)).convex_hull)
    return parts


def decompose(
    mesh: trimesh.Trimesh, mesh_sha256: str, config: ObjectConfig, cache_dir: Path | None = None
) -> tuple[list[trimesh.Trimesh], Path, bool, float]:
    """Convex parts of ``mesh`` with CoACD, cached on disk.

    Returns ``(parts, cache_file, from_cache, seconds)``; ``seconds`` is the decomposition time (0
    when served from the cache). Safe with concurrent processes: each writes a temporary file and
    renames it; two workers may both compute the same entry, never corrupt it.
    """
    path = cache_path(mesh, mesh_sha256, config, cache_dir)
    if path.is_file():
        try:
            parts = _read_parts_obj(path)
            if parts:
                return parts, path, True, 0.0
        except Exception:  # an unreadable cache entry is recomputed
            log.warning("unreadable decomposition cache %s; recomputing", path)
    try:
        import coacd
    except ImportError as exc:  # pragma: no cover - a declared dependency
        raise ObjectError("convex decomposition needs the 'coacd' package (pip install coacd)") from exc
    coacd.set_log_level("error")
    start = time.perf_counter()
    result = coacd.run_coacd(
        coacd.Mesh(np.asarray(mesh.vertices), np.asarray(mesh.faces)),
        threshold=config.decomposition_threshold,
        seed=0,
    )
    seconds = time.perf_counter() - start
    parts = [trimesh.Trimesh(v, f).convex_hull for v, f in result]
    parts = [p for p in parts if p.volume > 0]
    if not parts:
        raise ObjectError(f"convex decomposition produced no parts for {mesh_sha256[:12]}")
    _write_parts_obj(parts, path)
    log.info("decomposed %s into %d parts in %.1f s", mesh_sha256[:12], len(parts), seconds)
    return parts, path, False, seconds


# --------------------------------------------------------------------------------------------------
# PyBullet


def create_body(
    client: int, model: ObjectModel, T_world_obj: Transform | None = None, config: ObjectConfig | None = None
) -> int:
    """A dynamic PyBullet body for ``model`` in ``client``; returns its body id.

    Collision: the convex hull, or a compound of the convex parts. Visual: the mesh. Mass and
    inertia from the model with the inertial frame at the centre of mass along the principal
    axes, so the body's link frame is the mesh frame; ``T_world_obj`` places that frame.
    Frictions from ``config``, by default the one the model was loaded with.
    """
    config = config or model.config
    T_world_obj = T_world_obj or Transform.identity()
    if len(model.parts) <= 1:
        hull = model.parts[0] if model.parts else model.mesh.convex_hull
        col = pybullet.createCollisionShape(
            pybullet.GEOM_MESH, vertices=np.asarray(hull.vertices).tolist(), physicsClientId=client
        )
    else:
        path = model.collision_file
        if path is None or not Path(path).is_file():
            path = cache_path(model.mesh, model.mesh_sha256, config, None)
            _write_parts_obj(model.parts, path)
            model.collision_file = path
        col = pybullet.createCollisionShape(pybullet.GEOM_MESH, fileName=str(path), physicsClientId=client)
    if col < 0:
        raise ObjectError(f"{model.object_id}: PyBullet rejected the collision shape")
    visual_mesh = model.mesh if 3 * len(model.mesh.faces) <= MAX_VISUAL_INDICES else model.mesh.convex_hull
    vis = pybullet.createVisualShape(
        pybullet.GEOM_MESH,
        vertices=np.asarray(visual_mesh.vertices).tolist(),
        indices=np.asarray(visual_mesh.faces).reshape(-1).tolist(),
        rgbaColor=[0.8, 0.55, 0.3, 1.0],
        physicsClientId=client,
    )
    moments, R = _principal_axes(model.inertia)
    T_obj_com = Transform.from_rotation(R, model.center_mass)
    pos, quat = T_world_obj.to_pybullet()
    body = pybullet.createMultiBody(
        baseMass=model.mass,
        baseCollisionShapeIndex=col,
        baseVisualShapeIndex=vis,
        basePosition=pos,
        baseOrientation=quat,
        baseInertialFramePosition=T_obj_com.pos.tolist(),
        baseInertialFrameOrientation=T_obj_com.quat.tolist(),
        physicsClientId=client,
    )
    pybullet.changeDynamics(
        body,
        -1,
        localInertiaDiagonal=moments.tolist(),
        lateralFriction=config.lateral_friction,
        spinningFriction=config.spinning_friction,
        rollingFriction=config.rolling_friction,
        collisionMargin=config.collision_margin,
        physicsClientId=client,
    )
    return body


def _T_com_obj(client: int, body: int) -> Transform:
    info = pybullet.getDynamicsInfo(body, -1, physicsClientId=client)
    return Transform(np.asarray(info[3]), np.asarray(info[4])).inverse()


def get_object_pose(client: int, body: int) -> Transform:
    """``T_world_obj`` of the body's mesh frame (PyBullet's base pose is its centre of mass)."""
    T_world_com = Transform.from_pybullet(
        pybullet.getBasePositionAndOrientation(body, physicsClientId=client)
    )
    return T_world_com * _T_com_obj(client, body)


def reset_object_pose(client: int, body: int, T_world_obj: Transform) -> None:
    """Teleport the body so its mesh frame is at ``T_world_obj`` (velocities are left unchanged)."""
    T_world_com = T_world_obj * _T_com_obj(client, body).inverse()
    pos, quat = T_world_com.to_pybullet()
    pybullet.resetBasePositionAndOrientation(body, pos, quat, physicsClientId=client)
