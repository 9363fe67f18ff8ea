"""The names this package had when the OnRobot RG2 was the only gripper, kept for their callers.

The RG2 is now data (``assets/grippers/rg2/``) simulated by the generic
:class:`annotator.sim.gripper.ParallelGripper`; new code uses that class and
:func:`annotator.grippers.load_gripper`.
"""

from __future__ import annotations

from pathlib import Path

from annotator.config import GripperConfig
from annotator.grippers import default_gripper
from annotator.grippers.urdf import Mimic, read_mimic_table
from annotator.sim.body import Body
from annotator.sim.gripper import FingerEnvelope, ParallelGripper
from annotator.sim.width_table import WidthTable

__all__ = ["RG2", "FingerEnvelope", "Mimic", "WidthTable", "read_mimic_table"]


class RG2(ParallelGripper):
    """The RG2's :class:`ParallelGripper` on a body loaded from ``urdf`` (the floating model or the
    UR3 + RG2), with the old signature ``RG2(body, urdf, config, passive_links=...)``."""

    def __init__(
        self,
        body: Body,
        urdf: Path | str,
        config: GripperConfig | None = None,
        *,
        passive_links: str = "simulated",
    ) -> None:
        super().__init__(body, default_gripper(), config, urdf=urdf, passive_links=passive_links)
