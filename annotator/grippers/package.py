"""A gripper description's files carried to its workers: a run's gripper is frozen.

The main process reads a description's files once (:attr:`GripperDescription.files`, the bytes
its digest covers: ``gripper.toml``, the URDF and every mesh it references, by their paths
relative to the folder). Its workers, local or on a cluster, get those bytes, never the folder's
path: a user editing the folder mid-run, or a cluster worker on a machine without it, changes
nothing. The worker writes them once into its cache (``<cache>/grippers/<digest>/``) and loads the
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
from annotator.grippers.loading import is_shipped, load_gripper


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
        """The files ``description`` was read from, as read then (never read again): every one
        inside its folder (the description refuses a path outside it)."""
        return cls(description.name, description.digest, description.files)

    def unpack(self, root: str | os.PathLike) -> GripperDescription:
        """The description loaded from ``root/grippers/<digest>/`` (written there first if it is not
        yet); DescriptionError if what loads there is not this gripper."""
        folder = Path(root) / "grippers" / self.digest
        if not (folder / TOML_NAME).is_file():
            self._write(folder)
        try:
            description = load_gripper(folder)
        except DescriptionError as exc:
            raise DescriptionError(
                f"{folder}: not the run's {self.name!r} digest {self.digest[:12]} ({exc}); remove that folder"
            ) from None
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
    gripper: GripperDescription | GripperFiles | str | None, cache_dir: str | os.PathLike
) -> GripperDescription:
    """A worker's gripper, frozen: the files a run's main process read (a description's own bytes
    or :class:`GripperFiles`) unpacked into ``cache_dir/grippers/<digest>/`` and loaded from
    there, so a worker never reads the user's folder (edited mid-run, its labels would mix two
    grippers under one digest). A shipped gripper and a name or folder are loaded as they are."""
    if isinstance(gripper, GripperDescription) and not is_shipped(gripper):
        if gripper.files:
            gripper = GripperFiles.of(gripper)
        else:
            return gripper
    if isinstance(gripper, GripperFiles):
        return gripper.unpack(cache_dir)
    return load_gripper(gripper)


def gripper_record(description: GripperDescription) -> dict[str, str]:
    """What a run binds and a manifest records: ``{"name": ..., "digest": ...}``."""
    return {"name": description.name, "digest": description.digest}
