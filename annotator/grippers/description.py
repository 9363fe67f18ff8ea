"""A gripper as data: a folder with its URDF and ``gripper.toml``, read and checked into a record.

The TOML holds what the URDF cannot say (``docs/grippers.md`` documents every key)::

    format = 1
    name = "rg2"                      # [a-z0-9_] ; the name rows and manifests record
    title = "OnRobot RG2"
    urdf = "rg2.urdf"                 # beside gripper.toml
    export_type = "onrobot_rg2"       # gripper/type written by exports (default: the name)

    [base]   link = "rg2_base_link"; frame = "origin on the flange, +z approach, +x closing"
    [tcp]    link = "tcp"             # a frame at the pad-centre midpoint (closed)
    [mount]  xyz = [0, 0, 0]; rpy = [0, 0, 0]      # the base link on the UR3's tool0 (m, rad)
    [stroke] min = 0.0; max = 0.110                 # pad-face separation the FK must reach (m)
    [drive]  joint = "..."; close_speed = 1.0; coupling = "gear"   # rad/s or m/s; gear|position
    [force]  default = 40.0; min = 3.0; max = 40.0  # N, each pad's squeeze on the object
             simulated_max = 70.0   # optional: the most the model was measured to hold
    [pads]   links = ["finger 1 pad", "finger 2 pad"]; lateral_friction = 1.0
             spinning_friction = 0.002; rolling_friction = 0.0; size = [t, w, l] (optional)
    [collision] kinematic_links = [...]             # followers only posed for collision checks

Every table may also hold a ``source`` string (where its numbers come from). An unknown key, a
link or joint the URDF does not have, a follower that does not ``<mimic>`` the drive, a movable
joint nothing moves, a pad the drive does not move: each is a :class:`DescriptionError` of one
line naming the file and the key. The kinematic checks (the stroke the FK reaches, which side
each finger is on) need PyBullet: :func:`annotator.grippers.load_gripper` runs them.
"""

from __future__ import annotations

import hashlib
import math
import re
import sys
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from annotator.config import ConfigError, RobustConfig
from annotator.geometry import Transform, matrix_to_quat
from annotator.grippers.meshes import MAX_MESH_BYTES, MAX_MESH_FACES, MeshError, mesh_facts
from annotator.grippers.urdf import MAX_URDF_BYTES, Mimic, UrdfModel, read_urdf_bytes, rpy_matrix

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

FORMAT = 1
TOML_NAME = "gripper.toml"
NAME_PATTERN = re.compile(r"[a-z0-9_]+")
COUPLINGS = ("gear", "position")
DIGEST_PREFIX = b"rg2-annotator gripper v1\0"

# The keys of each table (None: the top level) and the kind of value each takes.
SCHEMA: dict[str | None, dict[str, str]] = {
    None: {"format": "int", "name": "str", "title": "str", "urdf": "str", "export_type": "str"},
    "base": {"link": "str", "frame": "str"},
    "tcp": {"link": "str"},
    "mount": {"xyz": "vec3", "rpy": "vec3"},
    "stroke": {"min": "float", "max": "float"},
    "drive": {"joint": "str", "close_speed": "float", "coupling": "str"},
    "force": {"default": "float", "min": "float", "max": "float", "simulated_max": "float"},
    "pads": {
        "links": "str2",
        "size": "vec3",
        "lateral_friction": "float",
        "spinning_friction": "float",
        "rolling_friction": "float",
    },
    "collision": {"kinematic_links": "strs"},
    # the gripper's own execution uncertainty over the project's (RobustConfig.over)
    # (its ranges; not the run's protocol for the perturbed trials: `shake`, `approach_from_contact`,
    # `stall_by_travel`, `fingers_from_contact`)
    "robust": {f.name: "float" for f in fields(RobustConfig) if f.type == "float"},
}
OPTIONAL = {
    (None, "export_type"),
    (None, "title"),
    ("force", "simulated_max"),
    ("pads", "size"),
    ("collision", "kinematic_links"),
}
OPTIONAL_TABLES = {"collision", "mount", "robust"}

# Ranges no parallel gripper leaves (checked so a typo or an `inf` is refused, never simulated):
# the largest strokes of industrial parallel grippers are a few hundred mm, their forces a few kN,
# their closing speeds well under 10 m/s (or rad/s of a finger joint); a mount is a flange
# adapter of a few cm, 1 m leaves room for any; a pad a few cm across.
MAX_STROKE = 1.0  # m
MAX_FORCE = 10_000.0  # N
MAX_CLOSE_SPEED = 10.0  # rad/s or m/s
MAX_MOUNT_OFFSET = 1.0  # m, each of x, y, z
MAX_MOUNT_ANGLE = 2 * math.pi  # rad, each of roll, pitch, yaw
MAX_PAD_SIZE = 0.5  # m, each of thickness, width, length
MAX_TOML_BYTES = 1024 * 1024
# a pad's collision mesh and its stated [pads] size agree within this ratio on every sorted
# extent (a pad turned 45 degrees about one axis still fits: sqrt(2) < 1.5; millimetres stated as
# metres do not)
PAD_SIZE_RATIO = 1.5


class DescriptionError(ValueError):
    """A gripper description that cannot be used (a usage error: one line, exit 2)."""


@dataclass(frozen=True, eq=False)
class GripperDescription:
    """A checked gripper description. Compare and key by :attr:`digest` (content), not by path.

    Lengths m, angles rad, forces N. ``mimic``: the URDF's followers of ``drive_joint`` in
    document order; ``fingers``: the links of finger 1 (at -x of the base) and finger 2 (at +x),
    each pad's chain below the base plus the passive links on its side; ``sources``: each
    table's ``source`` text.
    """

    name: str
    title: str
    folder: Path
    urdf: Path
    digest: str
    export_type: str
    base_link: str
    base_frame: str
    tcp_link: str
    mount_xyz: tuple[float, float, float]
    mount_rpy: tuple[float, float, float]
    stroke_min: float
    stroke_max: float
    drive_joint: str
    drive_kind: str  # "revolute" or "prismatic"
    close_speed: float  # rad/s or m/s of the driven joint
    coupling: str
    grip_force: float  # the default squeeze
    grip_force_min: float
    grip_force_max: float
    grip_force_simulated_max: float  # above it the coupled model was not measured to hold (a warning)
    pad_links: tuple[str, str]
    pad_size: tuple[float, float, float] | None  # (thickness, width, length); None: the URDF's box
    pad_lateral_friction: float
    pad_spinning_friction: float
    pad_rolling_friction: float
    kinematic_links: tuple[str, ...]
    mimic: tuple[Mimic, ...]
    links: tuple[str, ...]
    colliding_links: frozenset[str]
    fingers: tuple[tuple[str, ...], tuple[str, ...]]
    sources: dict[str, str] = field(default_factory=dict)
    # the bytes the digest covers, read once: ((path relative to the folder, bytes), ...) sorted;
    # a run ships them to its workers, which never read the folder (GripperFiles)
    files: tuple[tuple[str, bytes], ...] = field(default=(), repr=False)
    # ((field, value), ...) of the optional [robust] table: this gripper's execution uncertainty
    # (RobustConfig's fields and units) over the project's defaults
    robust: tuple[tuple[str, float], ...] = ()

    @property
    def key(self) -> tuple[str, str]:
        """What identifies the gripper simulated: (name, digest)."""
        return (self.name, self.digest)

    @property
    def T_flange_base(self) -> Transform:
        """The base link on the arm's flange (the UR3's ``tool0``)."""
        return Transform(self.mount_xyz, matrix_to_quat(rpy_matrix(self.mount_rpy)))

    @property
    def mimic_table(self) -> dict[str, Mimic]:
        return {m.follower: m for m in self.mimic}

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, GripperDescription):
            return NotImplemented
        return (self.digest, self.urdf) == (other.digest, other.urdf)

    def __hash__(self) -> int:
        return hash((self.digest, self.urdf))

    def __repr__(self) -> str:
        return f"GripperDescription({self.name!r}, {self.folder}, digest={self.digest[:12]})"


# --- reading ----------------------------------------------------------------------------------


def read_description(folder: Path | str) -> GripperDescription:
    """Read and statically check the description in ``folder`` (or the ``gripper.toml`` given)."""
    path = Path(folder)
    toml_path = path if path.suffix == ".toml" else path / TOML_NAME
    folder = toml_path.parent
    if not toml_path.is_file():
        raise DescriptionError(f"{folder}: no {TOML_NAME} (a gripper folder holds its URDF and {TOML_NAME})")
    raw = _read(toml_path, toml_path, MAX_TOML_BYTES)
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise DescriptionError(f"{toml_path}: not TOML ({exc})") from exc
    values, sources = _check_schema(toml_path, data)
    return _build(toml_path, raw, values, sources)


def _read(where: Path, path: Path, budget: int) -> bytes:
    """The bytes of ``path``, its size checked against ``budget`` before it is read."""
    try:
        size = path.stat().st_size
        if size > budget:
            raise _bad(where, f"{path.name} is {size:,} bytes, over the {budget:,} a gripper's file may have")
        return path.read_bytes()
    except OSError as exc:
        raise _bad(where, f"cannot read {path.name}: {exc.strerror or exc}") from None


def _inside(where: Path, folder: Path, name: str, what: str) -> tuple[Path, str]:
    """``name`` (relative to ``folder``) as a path and its posix path relative to the gripper's
    folder; DescriptionError when it is absolute, a URL, or resolves outside the folder (``..``,
    a symbolic link): a run reads exactly the folder's files and ships them to its workers."""
    root = where.parent.resolve()
    if "://" in name:
        raise _bad(
            where, f"{what} {name}: give files as paths relative to the URDF (package:// is not resolved)"
        )
    if Path(name).is_absolute():
        raise _bad(where, f"{what} {name}: an absolute path; keep the gripper's files inside its folder")
    path = folder / name
    try:
        relative = path.resolve().relative_to(root).as_posix()
    except ValueError:
        raise _bad(
            where,
            f"{what} {name} lies outside the gripper's folder {root} (.. or a link): keep its files there",
        ) from None
    return path, relative


def _bad(where: Path, text: str) -> DescriptionError:
    return DescriptionError(f"{where}: {text}")


def _check_schema(
    path: Path, data: dict[str, Any]
) -> tuple[dict[tuple[str | None, str], Any], dict[str, str]]:
    """Every key known and of its kind: ``{(table, key): value}`` and the tables' sources."""
    values: dict[tuple[str | None, str], Any] = {}
    sources: dict[str, str] = {}
    for key, value in data.items():
        if isinstance(value, dict):
            if key not in SCHEMA or key is None:
                raise _bad(path, f"unknown table [{key}]; known: {sorted(k for k in SCHEMA if k)}")
            for sub, v in value.items():
                if sub == "source":
                    if not isinstance(v, str):
                        raise _bad(path, f"[{key}] source must be a string")
                    sources[key] = v
                    continue
                values[(key, sub)] = _typed(path, key, sub, v)
        else:
            values[(None, key)] = _typed(path, None, key, value)
    for table, keys in SCHEMA.items():
        for key in keys:
            if (table, key) not in values and (table, key) not in OPTIONAL and table not in OPTIONAL_TABLES:
                where = f"[{table}] {key}" if table else key
                raise _bad(path, f"missing {where}")
    return values, sources


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _as_int(value: Any) -> int | None:
    return value if isinstance(value, int) and not isinstance(value, bool) else None


def _as_float(value: Any) -> float | None:
    return float(value) if _is_number(value) else None


def _as_str(value: Any) -> str | None:
    return value if isinstance(value, str) else None


def _as_vec3(value: Any) -> tuple[float, ...] | None:
    ok = isinstance(value, list) and len(value) == 3 and all(_is_number(v) for v in value)
    return tuple(float(v) for v in value) if ok else None


def _as_names(value: Any, count: int | None = None) -> tuple[str, ...] | None:
    ok = isinstance(value, list) and all(isinstance(v, str) for v in value)
    return tuple(value) if ok and (count is None or len(value) == count) else None


# kind -> (converter returning None for a value of the wrong kind, what was expected)
KINDS = {
    "int": (_as_int, "an integer"),
    "float": (_as_float, "a finite number"),
    "str": (_as_str, "a string"),
    "vec3": (_as_vec3, "three finite numbers"),
    "str2": (lambda v: _as_names(v, 2), "two link names"),
    "strs": (_as_names, "a list of link names"),
}


def _typed(path: Path, table: str | None, key: str, value: Any) -> Any:
    """``value`` of ``[table] key`` converted to its kind (SCHEMA); DescriptionError otherwise."""
    where = f"[{table}] {key}" if table else key
    kinds = SCHEMA.get(table, {})
    if key not in kinds:
        known = sorted(kinds) + (["source"] if table else [])
        raise _bad(path, f"unknown key {where}; known: {known}")
    convert, expected = KINDS[kinds[key]]
    typed = convert(value)
    if typed is None:
        raise _bad(path, f"{where}: expected {expected}, got {value!r}")
    return typed


def _build(
    path: Path, raw_toml: bytes, v: dict[tuple[str | None, str], Any], sources: dict[str, str]
) -> GripperDescription:
    folder = path.parent
    if v[(None, "format")] != FORMAT:
        raise _bad(
            path, f"format {v[(None, 'format')]} is not supported (this version reads format {FORMAT})"
        )
    name = v[(None, "name")]
    if not NAME_PATTERN.fullmatch(name):
        raise _bad(path, f"name {name!r}: use lower-case letters, digits and '_'")
    urdf_path, urdf_name = _inside(path, folder, v[(None, "urdf")], "urdf")
    if not urdf_path.is_file():
        raise _bad(path, f"urdf: {v[(None, 'urdf')]} does not exist beside {TOML_NAME}")
    raw_urdf = _read(path, urdf_path, MAX_URDF_BYTES)
    try:
        model = read_urdf_bytes(raw_urdf, urdf_path)
    except ValueError as exc:
        raise _bad(path, str(exc)) from exc
    _check_ranges(path, v)
    files = {TOML_NAME: raw_toml, urdf_name: raw_urdf}
    extents = _read_meshes(path, model, files)
    _check_pad_meshes(path, model, v, extents)
    drive = v[("drive", "joint")]
    pads = v[("pads", "links")]
    kinematic = v.get(("collision", "kinematic_links"), ())
    mimic = _check_links(path, model, v, drive, pads, kinematic)
    return GripperDescription(
        name=name,
        title=v.get((None, "title"), name),
        folder=folder,
        urdf=urdf_path,
        digest=_digest(files),
        export_type=v.get((None, "export_type"), name),
        base_link=v[("base", "link")],
        base_frame=v[("base", "frame")],
        tcp_link=v[("tcp", "link")],
        mount_xyz=v.get(("mount", "xyz"), (0.0, 0.0, 0.0)),
        mount_rpy=v.get(("mount", "rpy"), (0.0, 0.0, 0.0)),
        stroke_min=v[("stroke", "min")],
        stroke_max=v[("stroke", "max")],
        drive_joint=drive,
        drive_kind=model.joints[drive].kind,
        close_speed=v[("drive", "close_speed")],
        coupling=v[("drive", "coupling")],
        grip_force=v[("force", "default")],
        grip_force_min=v[("force", "min")],
        grip_force_max=v[("force", "max")],
        grip_force_simulated_max=v.get(("force", "simulated_max"), v[("force", "max")]),
        pad_links=(pads[0], pads[1]),
        pad_size=v.get(("pads", "size")),
        pad_lateral_friction=v[("pads", "lateral_friction")],
        pad_spinning_friction=v[("pads", "spinning_friction")],
        pad_rolling_friction=v[("pads", "rolling_friction")],
        kinematic_links=tuple(kinematic),
        mimic=tuple(mimic),
        links=model.links,
        colliding_links=model.colliding,
        fingers=_fingers(model, pads),
        sources=sources,
        files=tuple(sorted(files.items())),
        robust=_robust(path, v),
    )


def _robust(path: Path, v: dict[tuple[str | None, str], Any]) -> tuple[tuple[str, float], ...]:
    """The [robust] table's values, each checked in its RobustConfig range."""
    robust = {key: value for (table, key), value in v.items() if table == "robust"}
    try:
        RobustConfig(**robust)
    except ConfigError as exc:
        raise _bad(path, str(exc)) from None
    return tuple(sorted(robust.items()))


def _check_ranges(path: Path, v: dict[tuple[str | None, str], Any]) -> None:
    """Numbers in their ranges: stroke, force, speed, frictions, pad size; a known coupling."""
    lo, hi = v[("stroke", "min")], v[("stroke", "max")]
    if not 0.0 <= lo < hi:
        raise _bad(path, f"[stroke] needs 0 <= min < max, got min {lo:g}, max {hi:g} (m)")
    f_lo, f_def, f_hi = v[("force", "min")], v[("force", "default")], v[("force", "max")]
    if not 0.0 < f_lo <= f_def <= f_hi:
        raise _bad(path, f"[force] needs 0 < min <= default <= max, got {f_lo:g}, {f_def:g}, {f_hi:g} (N)")
    if hi > MAX_STROKE:
        raise _bad(path, f"[stroke] max {hi:g} m is beyond any parallel gripper's (at most {MAX_STROKE:g} m)")
    if f_hi > MAX_FORCE:
        raise _bad(path, f"[force] max {f_hi:g} N is beyond any parallel gripper's (at most {MAX_FORCE:g} N)")
    simulated = v.get(("force", "simulated_max"), f_hi)
    if not 0.0 < simulated <= MAX_FORCE:
        raise _bad(path, f"[force] simulated_max must be in (0, {MAX_FORCE:g}] N, got {simulated:g}")
    speed = v[("drive", "close_speed")]
    if not 0.0 < speed <= MAX_CLOSE_SPEED:
        raise _bad(
            path, f"[drive] close_speed must be in (0, {MAX_CLOSE_SPEED:g}] (rad/s or m/s), got {speed:g}"
        )
    for key, bound, unit in (("xyz", MAX_MOUNT_OFFSET, "m"), ("rpy", MAX_MOUNT_ANGLE, "rad")):
        values = v.get(("mount", key), (0.0, 0.0, 0.0))
        if not all(abs(x) <= bound for x in values):
            raise _bad(path, f"[mount] {key} {list(values)}: each must be within +-{bound:g} {unit}")
    if v[("drive", "coupling")] not in COUPLINGS:
        raise _bad(
            path, f"[drive] coupling must be one of {list(COUPLINGS)}, got {v[('drive', 'coupling')]!r}"
        )
    for key in ("lateral_friction", "spinning_friction", "rolling_friction"):
        if not v[("pads", key)] >= 0.0:
            raise _bad(path, f"[pads] {key} must be >= 0, got {v[('pads', key)]:g}")
    size = v.get(("pads", "size"))
    if size is not None and not all(0 < s <= MAX_PAD_SIZE for s in size):
        raise _bad(
            path,
            f"[pads] size must be three lengths in (0, {MAX_PAD_SIZE:g}] m (thickness, width, length), "
            f"got {list(size)}",
        )


def _read_meshes(path: Path, model: UrdfModel, files: dict[str, bytes]) -> dict[str, tuple[float, ...]]:
    """Read each mesh file the URDF references once into ``files`` (by its path relative to the
    folder): inside the folder, sizes within :data:`MAX_MESH_BYTES` together (checked before any
    is read), each a mesh PyBullet loads, their faces within :data:`MAX_MESH_FACES` together.
    Returns each mesh's vertex extents (file units) by the name the URDF gives it."""
    found: dict[str, Path] = {}
    for name in model.meshes:
        mesh, relative = _inside(path, model.path.parent, name, f"{model.path.name} references")
        if not mesh.is_file():
            raise _bad(path, f"{model.path.name} references {name}, which does not exist")
        found[name] = mesh
    sizes = {name: mesh.stat().st_size for name, mesh in found.items()}
    if sum(sizes.values()) > MAX_MESH_BYTES:
        name = max(sizes, key=sizes.__getitem__)
        raise _bad(
            path,
            f"the meshes are {sum(sizes.values()):,} bytes ({name}: {sizes[name]:,}), over the gripper's "
            f"budget of {MAX_MESH_BYTES:,}: simplify them (collision meshes need a few thousand faces)",
        )
    extents: dict[str, tuple[float, ...]] = {}
    faces: dict[str, int] = {}
    for name, mesh in found.items():
        _, relative = _inside(path, model.path.parent, name, f"{model.path.name} references")
        data = files.get(relative)
        if data is None:
            data = files[relative] = _read(path, mesh, MAX_MESH_BYTES)
        try:
            facts = mesh_facts(name, data)
        except MeshError as exc:
            raise _bad(path, f"{model.path.name} references {exc}") from None
        extents[name] = facts.extents
        faces[name] = facts.faces
    if sum(faces.values()) > MAX_MESH_FACES:
        name = max(faces, key=faces.__getitem__)
        raise _bad(
            path,
            f"the meshes hold {sum(faces.values()):,} faces ({name}: {faces[name]:,}), over the gripper's "
            f"budget of {MAX_MESH_FACES:,}: simplify them (each face costs PyBullet ~1.7 kB per worker)",
        )
    return extents


def _check_pad_meshes(
    path: Path, model: UrdfModel, v: dict[tuple[str | None, str], Any], extents: dict[str, tuple[float, ...]]
) -> None:
    """A pad whose collision is a mesh has the stated ``[pads] size`` (sorted extents, scaled by
    the URDF's mesh scale, within :data:`PAD_SIZE_RATIO`)."""
    size = v.get(("pads", "size"))
    if size is None:
        return
    for pad in v[("pads", "links")]:
        for name, scale in model.collision_meshes.get(pad, ()):
            measured = sorted(abs(e * s) for e, s in zip(extents[name], scale, strict=True))
            stated = sorted(size)
            pairs = zip(measured, stated, strict=True)
            if not all(m > 0 and 1 / PAD_SIZE_RATIO <= m / s <= PAD_SIZE_RATIO for m, s in pairs):
                raise _bad(
                    path,
                    f"[pads] size {list(size)} m does not match pad {pad!r}'s mesh {name}, "
                    f"{[round(m, 6) for m in measured]} m across (sorted, scaled)",
                )


def _check_links(
    path: Path,
    model: UrdfModel,
    v: dict[tuple[str | None, str], Any],
    drive: str,
    pads: tuple[str, ...],
    kinematic: tuple[str, ...],
) -> list[Mimic]:
    """Links and joints named in the TOML exist and the drive moves everything that moves; returns
    the URDF's followers of the drive (document order)."""
    _check_frames(path, model, v)
    mimic = _check_drive(path, model, drive)
    followers = {m.follower for m in mimic}
    _check_pads(path, model, pads, {drive} | followers, stated_size=v.get(("pads", "size")) is not None)
    _check_kinematic(path, model, pads, followers, kinematic)
    return mimic


def _check_frames(path: Path, model: UrdfModel, v: dict[tuple[str | None, str], Any]) -> None:
    urdf = model.path.name
    for key in (("base", "link"), ("tcp", "link")):
        if v[key] not in model.links:
            raise _bad(path, f"[{key[0]}] link {v[key]!r} is not a link of {urdf}")
    if v[("base", "link")] != model.root:
        base = v[("base", "link")]
        raise _bad(path, f"[base] link {base!r} must be the root link of {urdf} ({model.root!r})")


def _check_drive(path: Path, model: UrdfModel, drive: str) -> list[Mimic]:
    """The drive is a movable joint, every ``<mimic>`` follows it, every movable joint is one of them."""
    urdf = model.path.name
    joint = model.joints.get(drive)
    if joint is None or not joint.movable:
        raise _bad(path, f"[drive] joint {drive!r} is not a revolute or prismatic joint of {urdf}")
    if joint.mimic is not None:
        follows = joint.mimic.driven
        raise _bad(path, f"[drive] joint {drive!r} itself mimics {follows!r}: name the joint it follows")
    mimic = list(model.mimic_table().values())
    if not mimic:
        raise _bad(path, f"no <mimic> tag in {urdf}: nothing couples the fingers to the drive {drive!r}")
    for m in mimic:
        if m.driven != drive:
            raise _bad(path, f"{urdf}: joint {m.follower!r} mimics {m.driven!r}, not the drive {drive!r}")
    followers = {m.follower for m in mimic}
    for j in model.joints.values():
        if j.movable and j.name != drive and j.name not in followers:
            raise _bad(
                path, f"{urdf}: movable joint {j.name!r} neither is the drive nor mimics it: nothing moves it"
            )
    return mimic


def _check_pads(
    path: Path, model: UrdfModel, pads: tuple[str, ...], moved: set[str], stated_size: bool
) -> None:
    """Two distinct pad links, each moved by the drive, each a box unless its size is stated."""
    urdf = model.path.name
    if pads[0] == pads[1]:
        raise _bad(path, f"[pads] links names {pads[0]!r} twice: give finger 1's pad, then finger 2's")
    for pad in pads:
        if pad not in model.links:
            raise _bad(path, f"[pads] link {pad!r} is not a link of {urdf}")
        if not moved & set(model.joints_to(pad)):
            raise _bad(path, f"[pads] link {pad!r} is not moved by the drive or its followers")
        if not stated_size and pad not in model.boxes:
            raise _bad(path, f"[pads] link {pad!r} has no collision box: state [pads] size")


def _check_kinematic(
    path: Path, model: UrdfModel, pads: tuple[str, ...], followers: set[str], kinematic: tuple[str, ...]
) -> None:
    """Kinematic links are passive: children of followers, carrying no pad."""
    on_pad_chains = {link for pad in pads for link in model.chain(pad)}
    urdf = model.path.name
    for link in kinematic:
        parent = model.parent_joint(link) if link in model.links else None
        if parent is None or parent.name not in followers:
            raise _bad(
                path,
                f"[collision] kinematic link {link!r} is not the child of a <mimic> follower in {urdf}",
            )
        if link in on_pad_chains:
            raise _bad(
                path,
                f"[collision] kinematic link {link!r} carries a pad: only passive links can be kinematic",
            )


def _fingers(model: UrdfModel, pads: tuple[str, ...]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Each finger's links: the pad's chain below the root, then every other link below the root
    on that finger's side (the sign of x of its frame in the root frame with the joints at 0)."""
    root = model.root
    chains = [[link for link in reversed(model.chain(pad)) if link != root] for pad in pads]
    side = []
    for chain in chains:
        x = model.T_root_link(chain[-1])[0, 3]
        side.append(-1.0 if x < 0 else 1.0)
    placed = {link for chain in chains for link in chain}
    for link in model.links:
        if link == root or link in placed or model.parent_joint(link) is None:
            continue
        x = float(model.T_root_link(link)[0, 3])
        if abs(x) < 1e-9 or not set(model.joints_to(link)) & {
            j.name for j in model.joints.values() if j.movable
        }:
            continue  # on the axis or fixed to the base: part of the base
        for k in (0, 1):
            if (x < 0) == (side[k] < 0):
                chains[k].append(link)
                placed.add(link)
                break
    return tuple(chains[0]), tuple(chains[1])


def _digest(files: dict[str, bytes]) -> str:
    """SHA-256 of the TOML, the URDF and every mesh it references, by their paths relative to the
    folder (sorted), each with its length: the bytes read once, those a run ships to its workers."""
    h = hashlib.sha256(DIGEST_PREFIX)
    for relative in sorted(files):
        data = files[relative]
        h.update(relative.encode() + b"\0" + str(len(data)).encode() + b"\0")
        h.update(data)
    return h.hexdigest()
