"""Load one object: read, clean, weigh, give it collision geometry; its digest and its record.

Frames: every pose of an object is of its *mesh frame*: the frame its file is written in, scaled
to metres (for a URDF, the base link frame; for one node of a .glb, the file's frame). The
geometry record says which file(s) and scale that is, so a pose can be tied to its geometry.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, cast

import numpy as np
import trimesh

from annotator.config import ObjectConfig, PhysicsConfig
from annotator.geometry import Transform
from annotator.objects import mass as mass_model
from annotator.objects import memory, reading, repair, urdf
from annotator.objects.decomposition import CollisionGeometry, Progress, collision_geometry
from annotator.objects.discovery import ObjectSource
from annotator.objects.errors import ObjectError
from annotator.objects.fidelity import CollisionError
from annotator.objects.properties import ObjectProperties

log = logging.getLogger(__name__)


@dataclass
class ObjectModel:
    """A loaded, validated object in metres in its mesh frame.

    ``mesh`` : trimesh.Trimesh, the cleaned geometry the poses refer to (a URDF's collision mesh).
    ``center_mass`` : (3,) float, mesh frame. ``inertia`` : (3, 3) float, kg m^2, about the centre
    of mass, axes of the mesh frame. ``parts`` : convex trimesh.Trimesh pieces of the collision
    shape (one, the hull, for a convex object). ``collision_file`` : the multi-part .obj (``o``
    group per part) PyBullet loads as a compound, ``None`` for a single hull.
    ``collision_error`` : distance between collision shape and mesh surface (mean, max, m);
    ``approximate`` : beyond the configured limits. ``collision_method`` : hull, shells, coacd,
    coacd-remeshed or vhacd; ``collision_ladder`` : the decomposition rungs tried and how each went
    (empty for a hull or shells). ``mass_model`` : solid, shell, urdf or given. ``digest`` :
    :func:`source_digest` of the source. ``warnings`` : one line each (without the object id) for
    what a user should know about this object (holes filled, a mesh simplified, an approximate
    collision shape, a URDF inertia replaced); collected here, not logged, so a caller reports each
    once per object.
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
    friction: float = 1.0
    mass_model: str = "solid"
    collision_error: CollisionError | None = None
    collision_method: str = "hull"
    collision_threshold: float = 0.0  # CoACD threshold of the kept parts (0 for a hull)
    collision_ladder: str = ""
    approximate: bool = False
    cleaning: reading.Cleaning = field(default_factory=reading.Cleaning)
    source_files: tuple[str, ...] = ()
    digest: str = ""
    properties: dict[str, Any] = field(default_factory=dict)
    objects_dir: str = ""  # the folder source_files are relative to
    node: int | None = None  # the body of a multi-body file (.glb node, .obj part)
    warnings: list[str] = field(default_factory=list)

    @property
    def T_obj_com(self) -> Transform:
        """Centre-of-mass frame (principal axes) in the mesh frame."""
        _, R = mass_model.principal_axes(self.inertia)
        return Transform.from_rotation(R, self.center_mass)

    def substeps(self, physics: PhysicsConfig) -> int:
        """Physics steps per protocol step this object needs (see :func:`contact_substeps`)."""
        return contact_substeps(self.mass, physics)

    def geometry_record(self) -> dict[str, Any]:
        """One row of ``objects.parquet``: what the poses of this object refer to and what was
        simulated (flat columns: str, float, int, bool)."""
        err = self.collision_error
        return {
            "object_id": self.object_id,
            "objects_dir": self.objects_dir,
            "source_files": json.dumps(list(self.source_files)),
            "source_node": -1 if self.node is None else int(self.node),
            "scale": float(self.scale),
            "pose_frame": "urdf base link" if self.path.suffix.lower() == ".urdf" else "mesh file frame",
            "pose_units": "m",
            "mass": float(self.mass),
            "mass_model": self.mass_model,
            "friction": float(self.friction),
            "volume": float(self.volume),
            "watertight": bool(self.watertight),
            "faces": int(len(self.mesh.faces)),
            "cleaning": self.cleaning.summary(),
            "collision_method": self.collision_method,
            "collision_parts": int(len(self.parts)),
            "collision_threshold": float(self.collision_threshold),
            "collision_ladder": self.collision_ladder,
            "collision_error_mean": float(err.mean) if err else float("nan"),
            "collision_error_max": float(err.max) if err else float("nan"),
            "collision_approximate": bool(self.approximate),
            "properties": json.dumps(self.properties, sort_keys=True),
            "digest": self.digest,
        }


def contact_substeps(mass: float, physics: PhysicsConfig) -> int:
    """Steps per ``time_step`` that resolve a light object's contacts: ceil(sqrt(m_ref / m)), >= 1.

    A light object squeezed between heavy fingers is stiff against a light mass: its contact
    dynamics need a time step ~ sqrt(m) (a 4 g plate at 1/240 s: 2 of 49 face grasps held,
    pads 3.9 mm deep; at 1/760 s 49 of 49, 0.15 mm). See PhysicsConfig.light_object_mass.
    """
    return physics.substeps(mass)


def physics_for(model: ObjectModel, physics: PhysicsConfig) -> PhysicsConfig:
    """The physics settings to simulate ``model`` with: ``time_step`` / its contact substeps.

    Each substep keeps all ``solver_iterations``: with half of them per substep (the work of one
    step per time_step) a 10 g block in the cell slipped in 4 of 8 grasps that hold with all of
    them (tests/test_replay.py's block, 120 iterations: 4 of 10 successes against 8)."""
    n = model.substeps(physics)
    return physics if n == 1 else dataclasses.replace(physics, time_step=physics.time_step / n)


def _source_files(source: ObjectSource) -> list[Path]:
    """The files whose bytes make the object: a URDF and every mesh it references, or the mesh."""
    if not source.is_urdf:
        return [source.path]
    refs = urdf.mesh_refs(source.path, source.folder)
    seen: list[Path] = []
    for ref in refs:
        if ref.path not in seen:
            seen.append(ref.path)
    return [source.path, *seen]


def source_digest(source: ObjectSource | Path, budget_mb: float | None = None) -> str:
    """SHA-256 over everything the object is made of, for the run manifest.

    The file's bytes (for a URDF: the URDF, then every mesh it references in document order, each
    with its path relative to the URDF), the body of a multi-body file, and the sidecar properties that
    apply to it. Each file is checked by size (``budget_mb``, default ``ObjectConfig.memory_budget``)
    and header before it is read, then hashed in chunks (bounded memory). Raises ObjectError when a
    file is over the budget, not of its format, cannot be read or a URDF path is not allowed.
    """
    from annotator.config import ObjectConfig
    from annotator.objects.reading import check_size, sniff

    budget = ObjectConfig().memory_budget if budget_mb is None else budget_mb
    source = _as_source(source)
    h = hashlib.sha256(b"rg2-annotator object v1\0")
    try:
        for path in _source_files(source):
            inside = source.is_urdf and path != source.path
            rel = _relative(path, source.path.parent) if inside else Path(path.name)
            check_size(path, budget)
            if path != source.path or not source.is_urdf:
                sniff(path)  # a mesh: its header matches its suffix
            _hash_file(h, path, rel.as_posix())
    except OSError as exc:
        raise ObjectError(f"cannot read {source.object_id}: {exc.strerror or exc}") from None
    h.update(f"node\0{source.node}\0".encode())
    h.update(json.dumps(source.properties.as_dict(), sort_keys=True).encode())
    return h.hexdigest()


_HASH_CHUNK = 1 << 20


class _Hasher(Protocol):
    """What a hashlib object offers that the source digest uses."""

    def update(self, data: bytes, /) -> None: ...


def _hash_file(h: _Hasher, path: Path, name: str) -> None:
    """Feed ``name``, the size and the bytes of ``path`` to ``h``, read in chunks; ObjectError if
    the file changes size while it is read."""
    size = path.stat().st_size
    h.update(f"{name}\0{size}\0".encode())
    read = 0
    with path.open("rb") as fh:
        while chunk := fh.read(_HASH_CHUNK):
            h.update(chunk)
            read += len(chunk)
    if read != size:
        raise ObjectError(f"{path.name} changed while it was read; run again once it is written")


def _relative(path: Path, folder: Path) -> Path:
    try:
        return Path(path).resolve().relative_to(Path(folder).resolve())
    except ValueError:
        return Path(Path(path).name)


def _as_source(source: ObjectSource | Path | str) -> ObjectSource:
    if isinstance(source, ObjectSource):
        return source
    path = Path(source)
    return ObjectSource(path.stem, path)


def _read_urdf(source: ObjectSource) -> tuple[trimesh.Trimesh, bytes]:
    refs = urdf.mesh_refs(source.path, source.folder)
    collision = [r for r in refs if r.kind == "collision"] or [r for r in refs if r.kind == "visual"]
    if not collision:
        raise ObjectError(f"{source.path.name}: no mesh in its base link (only mesh objects are supported)")
    pieces, blobs = [], []
    for ref in collision:
        piece = reading.read_triangles(ref.path)
        blobs.append(ref.path.read_bytes())
        piece = trimesh.Trimesh(piece.vertices * ref.scale, piece.faces, process=False)
        piece.apply_transform(ref.T_link_geom)
        pieces.append(piece)
    mesh = cast(trimesh.Trimesh, trimesh.util.concatenate(pieces)) if len(pieces) > 1 else pieces[0]
    return mesh, b"".join(blobs)


def _urdf_mass(
    inertial: urdf.UrdfInertial,
    geometric: mass_model.MassProperties,
    mesh: trimesh.Trimesh,
    scale: float,
    warnings: list[str],
) -> mass_model.MassProperties:
    """A URDF's ``<inertial>`` (scaled with the mesh), unless its inertia cannot belong to this
    shape: then its mass with the geometry's distribution. pybullet_data's cube_small.urdf, a 5 cm
    cube, says 1 kg m^2 (a radius of gyration of 3.2 m): placeholders like that are common."""
    inertia = inertial.inertia * scale * scale
    moments = np.linalg.eigvalsh(0.5 * (inertia + inertia.T))
    gyration = float(np.sqrt(max(moments.max(), 0.0) / inertial.mass))
    size = float(np.linalg.norm(mesh.extents))
    plausible = moments.min() >= 0 and moments[0] + moments[1] >= moments[2] * (1 - 1e-6) and gyration <= size
    if plausible:
        return mass_model.MassProperties(
            inertial.mass, geometric.volume, inertial.center_mass * scale, inertia, "urdf"
        )
    warnings.append(
        f"the URDF's inertia cannot belong to this shape (radius of gyration {gyration:.3g} m, object "
        f"{size:.3g} m); using its mass {inertial.mass:.3g} kg with the mesh's inertia"
    )
    return geometric.with_mass(inertial.mass, "urdf")


def _convex(mesh: trimesh.Trimesh, hull: trimesh.Trimesh, config: ObjectConfig) -> bool:
    """A closed mesh whose volume is within ``convex_volume_tolerance`` of its hull's."""
    return float(mesh.volume) >= (1.0 - config.decomposition.convex_volume_tolerance) * float(hull.volume)


def _check_size(mesh: trimesh.Trimesh, name: str, config: ObjectConfig) -> trimesh.Trimesh:
    """Extent within limits and a hull with volume; returns the hull."""
    if len(mesh.faces) < config.min_faces:
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
    if not hull_volume > config.min_volume:
        raise ObjectError(f"{name}: degenerate mesh (zero volume: flat or collinear)")
    return hull


@dataclass
class _Read:
    """What reading and cleaning give: the mesh in the pose frame and what load_object needs next."""

    mesh: trimesh.Trimesh
    hull: trimesh.Trimesh
    watertight: bool
    scale: float
    mesh_sha256: str
    inertial: urdf.UrdfInertial | None
    cleaning: reading.Cleaning
    shells: list[trimesh.Trimesh] = field(default_factory=list)  # separate closed solids, if several
    warnings: list[str] = field(default_factory=list)


def _user_scale(source: ObjectSource, scale: float | None) -> float:
    props = source.properties
    user_scale = props.scale if props.scale is not None else (1.0 if scale is None else float(scale))
    if not np.isfinite(user_scale) or user_scale <= 0:
        raise ObjectError(f"scale must be a positive number, got {scale}")
    return user_scale


def _raw(source: ObjectSource) -> tuple[trimesh.Trimesh, bytes, urdf.UrdfInertial | None]:
    """The file's triangles as written (a URDF's meshes placed in its base link), their bytes and
    a URDF's ``<inertial>``."""
    if source.is_urdf:
        raw, blob = _read_urdf(source)
        return raw, blob, urdf.base_inertial(source.path)
    return reading.read_triangles(source.path, source.node), source.path.read_bytes(), None


def _close(
    mesh: trimesh.Trimesh, config: ObjectConfig, report: reading.Cleaning, warnings: list[str]
) -> tuple[trimesh.Trimesh, bool]:
    """Make the surface closed if it can be: shells that share edges separated, holes filled
    (MeshFix), else MeshFix's repair. Returns the mesh and whether it is closed."""
    if mesh.is_watertight and mesh.is_winding_consistent:
        return mesh, True
    separated = reading.separate_at_shared_edges(mesh, report)
    if separated is not None:
        return separated, True
    filled, report.holes_filled = repair.fill_holes(mesh)
    if report.holes_filled:
        warnings.append(f"mesh was open; filled {report.holes_filled} hole(s)")
        return filled, True
    mended = repair.mend(mesh, config.min_volume, config.mend_area_tolerance)
    if mended is not None:
        report.mended = True
        warnings.append(
            f"mesh was open or not a manifold; repaired by MeshFix ({len(mesh.faces)} -> "
            f"{len(mended.faces)} faces)"
        )
        return mended, True
    warnings.append(
        "mesh is not watertight and MeshFix could not close it; its convex hull is its collision shape"
    )
    return mesh, False


def _solid(
    mesh: trimesh.Trimesh, name: str, config: ObjectConfig, report: reading.Cleaning
) -> tuple[trimesh.Trimesh, list[trimesh.Trimesh]]:
    """A closed mesh outward wound, with volume, its overlapping closed shells joined; and its
    separate closed shells (empty for one)."""
    if mesh.volume < 0:
        mesh.invert()
    if not mesh.volume > config.min_volume:
        raise ObjectError(f"{name}: degenerate mesh (zero enclosed volume)")
    shells = reading.closed_shells(mesh)
    if shells and reading.overlapping(shells):  # parts written as one file: their union
        mesh = reading.join(shells, name)
        report.shells_joined = len(shells)
    return mesh, shells


def _drop_fragments(mesh: trimesh.Trimesh, config: ObjectConfig, report: reading.Cleaning) -> trimesh.Trimesh:
    mesh, dropped = repair.drop_fragments(mesh, config.fragment_max_share)
    report.fragments_dropped, report.fragment_area_share = dropped.pieces, dropped.area_share
    return mesh


def _read(source: ObjectSource, config: ObjectConfig, scale: float | None) -> _Read:
    user_scale = _user_scale(source, scale)
    name = source.object_id
    memory.check(source, config)  # before a vertex is parsed
    raw, blob, inertial = _raw(source)
    if not np.all(np.isfinite(raw.vertices)):
        raise ObjectError(f"{name}: vertices contain NaN or inf")
    raw = trimesh.Trimesh(raw.vertices * user_scale, raw.faces, process=False)

    report, warnings = reading.Cleaning(), []
    mesh = reading.clean(raw, name, report)
    mesh = _drop_fragments(mesh, config, report)
    mesh = reading.simplify(mesh, config.max_faces, report)
    if report.simplified_to:
        warnings.append(
            f"{report.faces_read} faces above the budget of {config.max_faces}; simplified to "
            f"{report.simplified_to}"
        )
    hull = _check_size(mesh, name, config)
    mesh, watertight = _close(mesh, config, report, warnings)
    shells: list[trimesh.Trimesh] = []
    if watertight:
        if report.mended:
            hull = _check_size(mesh, name, config)
        mesh, shells = _solid(mesh, name, config, report)
    if report.summary() != "clean":
        log.info("%s: cleaned: %s", name, report.summary())
    sha = hashlib.sha256(blob).hexdigest()
    return _Read(mesh, hull, watertight, user_scale, sha, inertial, report, shells, warnings)


@dataclass(frozen=True)
class ObjectMesh:
    """An object's mesh as its poses see it (trimesh.Trimesh, metres, pose frame) and the SHA-256
    of the bytes it was read from (the labels' ``mesh_sha256``)."""

    mesh: trimesh.Trimesh
    mesh_sha256: str


def read_object(
    source: ObjectSource | Path, config: ObjectConfig | None = None, scale: float | None = None
) -> ObjectMesh:
    """The object's mesh exactly as its poses see it (scaled, cleaned, in the pose frame) and its
    file's hash, without weighing or decomposing it. Raises ObjectError like :func:`load_object`."""
    read = _read(_as_source(source), config or ObjectConfig(), scale)
    return ObjectMesh(read.mesh, read.mesh_sha256)


def read_object_mesh(
    source: ObjectSource | Path, config: ObjectConfig | None = None, scale: float | None = None
) -> trimesh.Trimesh:
    """The mesh of :func:`read_object`."""
    return read_object(source, config, scale).mesh


def _weigh(read: _Read, props: ObjectProperties, config: ObjectConfig) -> mass_model.MassProperties:
    """Mass properties: a sidecar mass, else a URDF's ``<inertial>``, else the mass model."""
    weighed = mass_model.weigh(
        read.mesh,
        read.hull,
        read.watertight,
        config,
        props.mass_model or "auto",
        props.density,
        props.shell_thickness,
    )
    if props.mass is not None:
        return weighed.with_mass(props.mass, "given")
    if read.inertial is not None:
        return _urdf_mass(read.inertial, weighed, read.mesh, read.scale, read.warnings)
    return weighed


def _collision_method(read: _Read, config: ObjectConfig) -> tuple[str, bool]:
    """(method, convex): hull for convex or open meshes, shells for separate convex solids (a
    V-HACD collision mesh collides as itself), else the decomposition ladder."""
    convex = _convex(read.mesh, read.hull, config) if read.watertight else False
    if convex or not read.watertight:
        return "hull", convex
    if read.shells and all(_convex(shell, shell.convex_hull, config) for shell in read.shells):
        return "shells", convex
    return "coacd", convex


def _geometry_warnings(geometry: CollisionGeometry, config: ObjectConfig) -> list[str]:
    out = []
    ladder = config.decomposition
    if len(geometry.ladder) > 1 or any(r.detail for r in geometry.ladder):
        out.append(f"collision shape by {geometry.method}: {geometry.ladder_summary()}")
    if not geometry.within(ladder):
        out.append(
            f"approximate collision shape: error mean {geometry.error.mean * 1e3:.2f} mm, max "
            f"{geometry.error.max * 1e3:.2f} mm (limits {ladder.collision_mean_limit * 1e3:.2f} / "
            f"{ladder.collision_max_limit * 1e3:.2f} mm)"
        )
    return out


def load_object(
    source: ObjectSource | Path,
    config: ObjectConfig,
    scale: float | None = None,
    cache_dir: Path | None = None,
    progress: Progress | None = None,
    decompose: bool = True,
) -> ObjectModel:
    """Load, clean, validate, weigh and give collision geometry to one object.

    ``scale`` multiplies the file's coordinates (after a URDF's own mesh scale); ``None`` is 1; a
    sidecar ``scale`` overrides it. Steps: check the memory estimate, read (reasons name the
    file's problem), clean (merge seam vertices, drop degenerate and duplicate faces, drop loose
    fragments), simplify above ``config.max_faces``, check size, close the surface (holes filled,
    else MeshFix's repair), join closed shells that touch or overlap into their union
    (manifold3d), weigh (:mod:`annotator.objects.mass`), collision geometry
    (:mod:`annotator.objects.decomposition`: hull for convex or open meshes; the shells themselves
    for convex solids written as one file; the ladder otherwise) with its error against the mesh.
    ``cache_dir``: the decomposition cache (None: ``$RG2_CACHE_DIR`` or ``~/.cache/rg2-annotator``).
    ``progress(object_id, message)``: told when a decomposition starts, changes rung and ends.
    Raises :class:`ObjectError` with a one-line reason for unusable input; a decomposition that
    crashes or runs over its budget is not one (the next rung's shape is used and reported).
    ``decompose=False``: raise :class:`NotDecomposed` rather than decompose a concave object whose
    decomposition the cache does not hold (a process that leaves decompositions to its workers).
    """
    load_started = time.process_time()
    source = _as_source(source)
    props = source.properties
    name = source.object_id
    read = _read(source, config, scale)
    weighed = _weigh(read, props, config)
    method, convex = _collision_method(read, config)
    ladder = config.decomposition
    geometry = collision_geometry(
        read.mesh, method, ladder, cache_dir, name, read.shells, progress, decompose, load_started
    )
    warnings = read.warnings + _geometry_warnings(geometry, config)
    for warning in warnings:
        log.debug("%s: %s", name, warning)
    files = [p.as_posix() if source.root is None else _rel(p, source.folder) for p in _source_files(source)]
    return ObjectModel(
        object_id=name,
        path=source.path,
        mesh=read.mesh,
        scale=read.scale,
        mass=float(weighed.mass),
        volume=float(weighed.volume),
        center_mass=np.asarray(weighed.center_mass, dtype=np.float64),
        inertia=np.asarray(weighed.inertia, dtype=np.float64),
        mesh_sha256=read.mesh_sha256,
        watertight=read.watertight,
        convex=convex,
        parts=geometry.parts,
        collision_file=geometry.obj_file if len(geometry.parts) > 1 else None,
        from_cache=geometry.from_cache,
        decomposition_seconds=0.0 if geometry.from_cache else geometry.seconds,
        config=config,
        friction=config.lateral_friction if props.friction is None else props.friction,
        mass_model=weighed.model,
        collision_error=geometry.error,
        collision_method=geometry.method,
        collision_threshold=geometry.threshold,
        collision_ladder=geometry.ladder_summary(seconds=False),
        approximate=not geometry.within(ladder),
        cleaning=read.cleaning,
        source_files=tuple(files),
        digest=source_digest(source),
        properties=props.as_dict(),
        objects_dir=str(source.folder.resolve()),
        node=source.node,
        warnings=warnings,
    )


def _rel(path: Path, root: Path) -> str:
    try:
        return path.resolve().relative_to(Path(root).resolve()).as_posix()
    except ValueError:
        return path.as_posix()
