"""A gripper description's files carried to where its folder is not: a Dask worker on another host.

A local worker reads the description's folder where the main process found it. A cluster worker
may run on a machine without that folder (a user's own gripper), so a run on a cluster sends
:class:`GripperFiles` instead: the bytes of exactly the files the description's digest covers
(``gripper.toml``, the URDF and every mesh it references, by their paths relative to the
folder). The worker writes them once into its cache (``<cache>/grippers/<digest>/``) and loads the
description from there; the digest of what it loaded must be the one sent, so a worker can never
simulate another gripper than the run bound.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from annotator.grippers.description import TOML_NAME, DescriptionError, GripperDescription
from annotator.grippers.urdf import read_urdf


@dataclass(frozen=True)
class GripperFiles:
    """The files of a gripper description: ``files`` is ``((relative posix path, bytes), ...)``,
    sorted; ``name`` and ``digest`` are the description's."""

    name: str
    digest: str
    files: tuple[tuple[str, bytes], ...]

    @property
    def key(self) -> tuple[str, str]:
        """What identifies the gripper simulated: (name, digest), as :attr:`GripperDescription.key`."""
        return (self.name, self.digest)

    @classmethod
    def of(cls, description: GripperDescription) -> GripperFiles:
        """The files ``description`` was read from. DescriptionError for a file outside its folder
        (it could not be placed beside the others on the worker)."""
        folder = description.folder.resolve()
        urdf = description.urdf.resolve()
        paths = [folder / TOML_NAME, urdf]
        paths += [(urdf.parent / name).resolve() for name in read_urdf(urdf).meshes]
        files = []
        for path in sorted(set(paths)):
            try:
                relative = path.relative_to(folder).as_posix()
            except ValueError:
                raise DescriptionError(
                    f"{folder / TOML_NAME}: {path} lies outside the gripper's folder; a run on a cluster "
                    "sends the folder's files to its workers, so keep the URDF and meshes inside it"
                ) from None
            files.append((relative, path.read_bytes()))
        return cls(description.name, description.digest, tuple(files))

    def unpack(self, root: str | os.PathLike) -> GripperDescription:
        """The description loaded from ``root/grippers/<digest>/`` (written there first if it is not
        yet); DescriptionError if what loads there is not this gripper."""
        from annotator.grippers import load_gripper

        folder = Path(root) / "grippers" / self.digest
        if not (folder / TOML_NAME).is_file():
            self._write(folder)
        description = load_gripper(folder)
        if description.digest != self.digest:
            raise DescriptionError(
                f"{folder}: holds gripper {description.name!r} digest {description.digest[:12]}, "
                f"not the run's {self.name!r} digest {self.digest[:12]}; remove that folder"
            )
        return description

    def _write(self, folder: Path) -> None:
        """Write the files into a fresh folder beside ``folder``, then rename it into place (two
        workers unpacking at once: the first rename wins, the second folder is removed)."""
        folder.parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f".{self.digest[:12]}-", dir=folder.parent))
        try:
            for relative, data in self.files:
                parts = PurePosixPath(relative).parts
                if PurePosixPath(relative).is_absolute() or ".." in parts:
                    raise DescriptionError(f"gripper {self.name!r}: refusing to write {relative!r}")
                target = staging.joinpath(*parts)
                target.parent.mkdir(parents=True, exist_ok=True)
                target.write_bytes(data)
            with contextlib.suppress(OSError):  # another worker's rename came first: keep its folder
                os.rename(staging, folder)
        finally:
            shutil.rmtree(staging, ignore_errors=True)


def resolve_gripper(
    gripper: GripperDescription | GripperFiles | str | None, cache_dir: str | os.PathLike | None = None
) -> GripperDescription:
    """A worker's gripper: a description as it is, a name or folder loaded, :class:`GripperFiles`
    unpacked into ``cache_dir`` (default: the decomposition cache, ``RG2_CACHE_DIR``)."""
    from annotator.grippers import load_gripper

    if isinstance(gripper, GripperFiles):
        if cache_dir is None:
            from annotator.objects import default_cache_dir

            cache_dir = default_cache_dir()
        return gripper.unpack(cache_dir)
    return load_gripper(gripper)


def is_shipped(description: GripperDescription) -> bool:
    """Is ``description`` read from the package's own ``assets/grippers/<name>`` folder?"""
    from annotator.grippers import gripper_dir

    try:
        return description.folder.resolve() == gripper_dir(description.name).resolve()
    except OSError:
        return False


def gripper_record(description: GripperDescription) -> dict[str, str]:
    """What a run binds and a manifest records: ``{"name": ..., "digest": ...}``."""
    return {"name": description.name, "digest": description.digest}
