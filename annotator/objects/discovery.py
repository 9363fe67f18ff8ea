"""Find the objects under a folder without reading their geometry.

An object is a mesh file (``MESH_SUFFIXES``), an object ``.urdf`` (the meshes it references are
part of it, not objects of their own), or one body of a multi-body file (id ``file/part``): a mesh
node of a ``.glb``, an ``o`` object (or a ``g`` group that is a body) of an ``.obj``
(:mod:`~annotator.objects.wavefront`), unless ``merge_parts`` keeps the file whole. Cost: a
directory walk, each URDF's XML, each ``.glb``'s JSON chunk and a regex scan of each ``.obj`` for
its statements; no vertex is parsed, so folders of thousands of files list fast.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from annotator.config import ObjectConfig
from annotator.objects import gltf, urdf, wavefront
from annotator.objects.errors import ObjectDiscoveryError, ObjectError
from annotator.objects.properties import ObjectProperties, Sidecar

MESH_SUFFIXES = (".obj", ".stl", ".ply", ".off", ".glb")
URDF_SUFFIX = ".urdf"


@dataclass(frozen=True)
class ObjectSource:
    """An object found on disk.

    ``object_id``: its path relative to the search root without suffix (``file/part`` for one
    body of a multi-body .glb or .obj). ``root``: the objects folder (URDF meshes must lie inside
    it; ``None``: the file's own folder). ``node``: the body's index (the .glb index of its first
    mesh node, :func:`annotator.objects.gltf.mesh_nodes`, or the .obj part index of
    :func:`annotator.objects.wavefront.parts`; ``None``: the whole file).
    ``properties``: what the sidecar ``objects.toml`` sets for it.
    """

    object_id: str
    path: Path
    root: Path | None = None
    node: int | None = None
    properties: ObjectProperties = field(default_factory=ObjectProperties)

    @property
    def is_urdf(self) -> bool:
        return self.path.suffix.lower() == URDF_SUFFIX

    @property
    def folder(self) -> Path:
        """The folder every file of this object must lie in."""
        return Path(self.root) if self.root is not None else self.path.parent


def discover_objects(root: Path, config: ObjectConfig | None = None) -> list[ObjectSource]:
    """All objects under ``root`` (recursive), sorted by ``object_id``.

    Raises :class:`ObjectDiscoveryError` when ``root`` is not a folder, holds no objects, two
    files give one id, or its ``objects.toml`` is broken. A file that cannot be parsed (a broken
    URDF or .glb) is still listed as one object; loading it reports the reason.
    """
    config = config or ObjectConfig()
    root = Path(root)
    if not root.is_dir():
        raise ObjectDiscoveryError(f"objects folder not found: {root}")
    sidecar = Sidecar.load(root)
    files = sorted(p for p in root.rglob("*") if p.is_file())
    owned = _urdf_meshes(files, root)
    sources = [
        source
        for path in files
        if _is_object(path, owned)
        for source in _sources_of(path, root, sidecar, config)
    ]
    if not sources:
        raise ObjectDiscoveryError(
            f"no objects in {root} (searched recursively for {' '.join(MESH_SUFFIXES)} {URDF_SUFFIX})"
        )
    counts = Counter(s.object_id for s in sources)
    dupes = sorted(i for i, n in counts.items() if n > 1)
    if dupes:
        raise ObjectDiscoveryError(f"two files give the same object id(s) {dupes}; rename one")
    return sorted(sources, key=lambda s: s.object_id)


def _urdf_meshes(files: list[Path], root: Path) -> set[Path]:
    """The meshes the URDFs among ``files`` reference (parts of those objects, not objects)."""
    owned: set[Path] = set()
    for path in files:
        if path.suffix.lower() == URDF_SUFFIX:
            try:
                owned.update(ref.path for ref in urdf.mesh_refs(path, root))
            except ObjectError:
                pass  # a broken URDF is still listed; load_object reports it
    return owned


def _is_object(path: Path, owned: set[Path]) -> bool:
    suffix = path.suffix.lower()
    return suffix == URDF_SUFFIX or (suffix in MESH_SUFFIXES and path.resolve() not in owned)


def _sources_of(path: Path, root: Path, sidecar: Sidecar, config: ObjectConfig) -> list[ObjectSource]:
    """The objects one file gives: itself, or one per body of a multi-body file."""
    file_id = path.relative_to(root).with_suffix("").as_posix()
    props = sidecar.for_object(file_id)
    merge = props.merge_parts if props.merge_parts is not None else config.merge_parts
    parts = [] if merge else _parts(path, config.memory_budget)
    if len(parts) < 2:
        return [ObjectSource(file_id, path, root, None, props)]
    return [
        ObjectSource(f"{file_id}/{name}", path, root, index, sidecar.for_object(file_id, f"{file_id}/{name}"))
        for index, name in parts
    ]


def _parts(path: Path, budget_mb: float) -> list[tuple[int, str]]:
    """(index, name) of each body of a multi-body file (.glb mesh nodes, .obj objects or groups);
    empty for a single body or a file that cannot be parsed (it is listed whole; loading names
    the problem). A file over the memory budget (``budget_mb``) or whose header is not its
    format's is not scanned: listed whole, it is refused with its figure before it is hashed."""
    from annotator.objects.reading import check_size, sniff

    suffix = path.suffix.lower()
    try:
        check_size(path, budget_mb)
        sniff(path)
    except ObjectError:
        return []
    try:
        if suffix == ".glb":
            return [(node.index, node.name) for node in gltf.mesh_nodes(path)]
        if suffix == ".obj":
            return [(part.index, part.name) for part in wavefront.parts(path)]
    except (ObjectError, OSError, ValueError):
        pass
    return []
