"""Every label column of every mode, declared once: name, dtype, unit, frame and meaning.

A *mode* is what wrote a row: ``object`` (``annotate``, the floating gripper), ``cell``
(``annotate --cell``), ``resting`` (``annotator evaluate --resting``), ``scene`` and
``scene_cell`` (``annotate --scenes``, without and with ``--cell``) and ``capture`` (the seed
scene's capture key); ``annotator evaluate`` writes the rows of the mode it simulates in
(``object``, ``resting``). :data:`MODES` gives each mode's columns in the order its rows hold them
(a mode added outside this module declares its own: :func:`declare_mode`); :data:`REQUIRED` are
the columns every label table has and :func:`annotator.dataset.validate_labels` checks.
docs/labels.md shows these tables (:func:`markdown_table`; ``tests/test_label_schema.py`` checks
the page against them).

This module imports neither pybullet nor pandas.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

# dtype names, as pandas spells them
STRING, INT64, FLOAT64, BOOL = "string", "int64", "float64", "bool"


@dataclass(frozen=True)
class Column:
    """One label column: ``dtype`` (pandas' name), ``unit`` ("" for none), ``frame`` ("" where a
    value has none) and a one-line ``meaning``; ``required``: every label table has it."""

    name: str
    dtype: str
    unit: str
    frame: str
    meaning: str
    required: bool = False


@dataclass(frozen=True)
class ColumnGroup:
    """Columns that are one quantity (a position's x, y, z, a quaternion's xyzw, six joints),
    documented in one line of the docs' tables."""

    names: tuple[str, ...]
    dtype: str
    unit: str
    frame: str
    meaning: str
    required: bool = False

    def columns(self) -> tuple[Column, ...]:
        return tuple(
            Column(n, self.dtype, self.unit, self.frame, self.meaning, self.required) for n in self.names
        )

    def label(self) -> str:
        """The group as the docs name it: ``x``, ``y``, ``z`` or ``cmd_qx`` … ``cmd_qw``."""
        if len(self.names) <= 3:
            return ", ".join(f"`{n}`" for n in self.names)
        return f"`{self.names[0]}` … `{self.names[-1]}`"


def _xyz(prefix: str) -> tuple[str, ...]:
    return tuple(f"{prefix}{c}" for c in ("x", "y", "z"))


def _quat(prefix: str) -> tuple[str, ...]:
    return tuple(f"{prefix}{c}" for c in ("qx", "qy", "qz", "qw"))


MESH, WORLD, TABLE = "object mesh frame", "world", "table frame"
QUAT = "unit quaternion xyzw"

# --- the columns of an object label (every mode has them) --------------------------------------------

OBJECT_GROUPS: tuple[ColumnGroup, ...] = (
    ColumnGroup(
        ("object_id",),
        STRING,
        "",
        "",
        "path of the object's file relative to `--objects`, without suffix (`mug`, `urdf/shampoo/shampoo`); "
        "`file/part` for one body of a multi-body file",
        True,
    ),
    ColumnGroup(
        ("grasp_id",),
        INT64,
        "",
        "",
        "0 … N−1 within the object (within the scene for scene labels); the candidate's index in its "
        "seeded draw",
        True,
    ),
    ColumnGroup(_xyz(""), FLOAT64, "m", MESH, "TCP position at the end of closing", True),
    ColumnGroup(_quat(""), FLOAT64, QUAT, MESH, "TCP orientation at the end of closing; `qw ≥ 0`", True),
    ColumnGroup(
        ("width",),
        FLOAT64,
        "m",
        "",
        "pad-face separation at the end of closing; for `collision` the open width the check used (never "
        "simulated)",
        True,
    ),
    ColumnGroup(
        ("success",),
        BOOL,
        "",
        "",
        'trial 0 held through `[protocol] gate` (the default gate, the shake: `outcome == "success"`)',
        True,
    ),
    ColumnGroup(("outcome",), STRING, "", "", "how the trial ended: see [Outcomes](#outcomes)", True),
    ColumnGroup(
        ("score",),
        FLOAT64,
        "0 … 1",
        "",
        "fraction of the `--trials K` trials that held: trial 0 through the gate, the K − 1 "
        "perturbed ones through the lift unless `[robust] motion` or `shake` (0 or 1 with K = 1)",
        True,
    ),
    ColumnGroup(
        ("object_scale",),
        FLOAT64,
        "",
        "",
        "scale applied to the file (`--scale`, `objects.toml`, or 1)",
        True,
    ),
    ColumnGroup(("mesh_sha256",), STRING, "", "", "SHA-256 of the object's file as read", True),
    ColumnGroup(("seed",), INT64, "", "", "the run's `--seed` (0 for a capture: nothing is drawn)", True),
    ColumnGroup(
        ("sim_steps",),
        INT64,
        "steps",
        "",
        "physics steps simulated for the row, all K trials together (0 for `collision`)",
    ),
    ColumnGroup(
        ("slip",),
        FLOAT64,
        "m",
        "",
        "how far the object moved in the hand from the end of closing to the verdict; NaN unless the row "
        "reached the end of the shake",
    ),
    ColumnGroup(("object_mass",), FLOAT64, "kg", "", "mass the object was simulated with"),
    ColumnGroup(
        ("stage",),
        STRING,
        "",
        "",
        "how far trial 0 held: `none`, `closed`, `lifted`, `moved` (the benchmark motion), `shaken` "
        "([Stages](protocol.md#stages)); label by any stage with `annotator.dataset.held_through`",
    ),
    ColumnGroup(
        ("trial_stages",),
        STRING,
        "",
        "",
        "how far each trial held, one digit per trial, trial 0 first: 0 none, 1 closed, 2 lifted, 3 "
        "moved, 4 shaken; a perturbed trial stops at its last stage",
    ),
    ColumnGroup(
        _xyz("cmd_"),
        FLOAT64,
        "m",
        MESH,
        "the commanded TCP position: where the gripper was placed before closing",
    ),
    ColumnGroup(
        _quat("cmd_"),
        FLOAT64,
        QUAT,
        MESH,
        "the commanded TCP orientation (as simulated: the sign is not made canonical)",
    ),
    ColumnGroup(("cmd_width",), FLOAT64, "m", "", "the expected chord the close started from"),
    ColumnGroup(
        ("collision_error",),
        FLOAT64,
        "m",
        "",
        "largest distance between the simulated collision shape and the mesh surface",
    ),
    ColumnGroup(("collision_error_mean",), FLOAT64, "m", "", "mean of that distance"),
    ColumnGroup(
        ("gripper",),
        STRING,
        "",
        "",
        "the gripper simulated: its description's name (`rg2`, `panda`, `robotiq_2f85`, or a folder's own "
        "`name`); the run's manifest binds its name and digest ([grippers.md](grippers.md#using-a-gripper))",
    ),
)

# --- the robot cell (annotate --cell; the reachability columns also in scenes with --cell) ---------------

PLACEMENT_GROUPS: tuple[ColumnGroup, ...] = (
    ColumnGroup(
        ("placement_id",),
        INT64,
        "",
        "",
        "the placement the candidate was sampled for and rests in; 0 is the most probable stable pose kept",
    ),
    ColumnGroup(
        ("placement_probability",),
        FLOAT64,
        "",
        "",
        "its stable-pose probability (poses merged into it added)",
    ),
)
OBJECT_POSE_GROUPS: tuple[ColumnGroup, ...] = (
    ColumnGroup(
        _xyz("obj_"), FLOAT64, "m", WORLD, "the object's mesh frame in the world after settling on the table"
    ),
    ColumnGroup(
        _quat("obj_"),
        FLOAT64,
        QUAT,
        WORLD,
        "its orientation after settling; a label's TCP in the world is `T_world_obj · T_obj_tcp`",
    ),
)
REACH_GROUPS: tuple[ColumnGroup, ...] = (
    ColumnGroup(
        ("reachable",), BOOL, "", "", "the UR3 can execute the commanded grasp along its 10 cm approach"
    ),
    ColumnGroup(
        tuple(f"q_grasp_{i}" for i in range(6)),
        FLOAT64,
        "rad",
        "",
        "the arm's joints at the grasp (shoulder pan, shoulder lift, elbow, wrist 1, 2, 3); NaN when not "
        "reachable",
    ),
    ColumnGroup(
        ("unreachable_reason",),
        STRING,
        "",
        "",
        '`""` when reachable, else `no IK solution`, `joint limits`, `arm-table collision`, `arm-object '
        "collision`, `arm self-collision`, or `error`",
    ),
)

# --- resting on the table (annotator evaluate --resting) -----------------------------------------------

RESTING_GROUPS: tuple[ColumnGroup, ...] = (
    ColumnGroup(
        _quat("rest_"),
        FLOAT64,
        QUAT,
        TABLE,
        "the orientation the object was given to rest in (its mesh frame), as given",
    ),
    *OBJECT_POSE_GROUPS,
    ColumnGroup(
        ("settle_drift",),
        FLOAT64,
        "m",
        "",
        "how far it moved while settling: the largest movement of a corner of its mesh's bounding box",
    ),
)

# --- among neighbours (annotate --scenes) ----------------------------------------------------------------

SCENE_GROUPS: tuple[ColumnGroup, ...] = (
    ColumnGroup(("scene_id",), INT64, "", "", "the scene; grasp ids count per scene"),
    ColumnGroup(("instance_id",), INT64, "", "", "the target instance: its row in the scene table"),
    ColumnGroup(_xyz("table_tcp_"), FLOAT64, "m", TABLE, "the label's TCP position in the table frame"),
    ColumnGroup(
        _quat("table_tcp_"), FLOAT64, QUAT, TABLE, "the label's TCP orientation in the table frame; `qw ≥ 0`"
    ),
    ColumnGroup(
        ("collided_with",),
        STRING,
        "",
        "",
        'for a `collision`: `object` (the target itself), `table` or `neighbour`; `""` otherwise',
    ),
    ColumnGroup(("collided_instance",), INT64, "", "", "the neighbour's instance id, -1 otherwise"),
    ColumnGroup(
        ("collision_stage",),
        STRING,
        "",
        "",
        "`approach` (open, at or behind the grasp), `closed` (on the chord) or `pregrasp` (evaluate: the "
        'pose before the approach); `""` otherwise',
    ),
    ColumnGroup(
        ("disturbance",),
        FLOAT64,
        "m",
        "",
        "the largest displacement of a bounding-box corner of any neighbour between the settled scene "
        "and the trial's end",
    ),
    ColumnGroup(("disturbed",), BOOL, "", "", "`disturbance` ≥ `[scenes] disturbance_threshold` (5 mm)"),
    ColumnGroup(
        ("disturbed_instance",), INT64, "", "", "the neighbour that moved most, -1 without neighbours"
    ),
)


# --- with a calibration ([confidence], annotator calibrate) ------------------------------------------

CONFIDENCE_GROUPS: tuple[ColumnGroup, ...] = (
    ColumnGroup(
        ("p_success",),
        FLOAT64,
        "0 … 1",
        "",
        "only in labels made with a calibration (`[confidence]`, written by `annotator calibrate`): the "
        "probability that the real grasp holds, the calibration's mapping of `score` "
        "([tools.md](tools.md#the-labels-confidence-p_success))",
    ),
)


def _names(groups: tuple[ColumnGroup, ...]) -> tuple[str, ...]:
    return tuple(n for g in groups for n in g.names)


OBJECT_COLUMNS = _names(OBJECT_GROUPS)
# Why a given grasp's row is a collision (annotator evaluate, calibrate's replays): the scene rows'
# columns of the same names, after the mode's columns
REASON_COLUMNS: tuple[str, ...] = ("collided_with", "collision_stage")
# With a calibration, after the mode's columns (and before the reasons)
CONFIDENCE_COLUMNS: tuple[str, ...] = ("p_success",)
# a scene row holds the object columns but writes its gripper after the scene's own
_OBJECT_BUT_GRIPPER = tuple(c for c in OBJECT_COLUMNS if c != "gripper")

# Each mode's columns in the order its rows hold them.
MODES: dict[str, tuple[str, ...]] = {
    "object": OBJECT_COLUMNS,
    "cell": OBJECT_COLUMNS + _names(PLACEMENT_GROUPS + OBJECT_POSE_GROUPS + REACH_GROUPS),
    "resting": OBJECT_COLUMNS + _names(RESTING_GROUPS),
    "scene": _OBJECT_BUT_GRIPPER + _names(SCENE_GROUPS) + ("gripper",),
    "scene_cell": _OBJECT_BUT_GRIPPER + _names(SCENE_GROUPS) + ("gripper",) + _names(REACH_GROUPS),
    "capture": OBJECT_COLUMNS,
}

# The groups each section of docs/labels.md documents, by its marker's name.
DOC_SECTIONS: dict[str, tuple[ColumnGroup, ...]] = {
    "object": OBJECT_GROUPS,
    "cell": PLACEMENT_GROUPS + OBJECT_POSE_GROUPS + REACH_GROUPS,
    "resting": RESTING_GROUPS,
    "scene": SCENE_GROUPS,
    "confidence": CONFIDENCE_GROUPS,
}

GROUPS: tuple[ColumnGroup, ...] = (
    OBJECT_GROUPS + PLACEMENT_GROUPS + REACH_GROUPS + RESTING_GROUPS + SCENE_GROUPS + CONFIDENCE_GROUPS
)


def _by_name() -> dict[str, Column]:
    out: dict[str, Column] = {}
    for group in GROUPS:
        for column in group.columns():
            if column.name in out and out[column.name] != column:
                raise AssertionError(f"label column {column.name} declared twice, differently")
            out[column.name] = column
    return out


COLUMNS: dict[str, Column] = _by_name()
# The columns every label table has, in order, with their dtypes (what load_labels checks).
REQUIRED: dict[str, str] = {c.name: c.dtype for c in COLUMNS.values() if c.required}


def declare_mode(mode: str, groups: tuple[ColumnGroup, ...], base: str = "object") -> tuple[str, ...]:
    """Declare the rows of a mode added outside this module (docs/architecture.md, "Adding a
    mode"): ``base``'s columns, then those of ``groups``. Declaring the same again is a no-op; a
    mode or a column declared otherwise before is a ValueError. Returns the mode's columns."""
    names = MODES[base] + _names(groups)
    for group in groups:
        for column in group.columns():
            if COLUMNS.get(column.name, column) != column:
                raise ValueError(f"label column {column.name} is declared already, differently")
    if MODES.get(mode, names) != names:
        raise ValueError(f"label mode {mode!r} is declared already, with other columns")
    for group in groups:
        COLUMNS.update((c.name, c) for c in group.columns())
    MODES[mode] = names
    return names


def columns_of(mode: str) -> tuple[Column, ...]:
    """The columns of ``mode``'s rows, in order; KeyError naming the modes for an unknown one."""
    try:
        return tuple(COLUMNS[name] for name in MODES[mode])
    except KeyError:
        raise KeyError(f"unknown label mode {mode!r}; modes: {', '.join(MODES)}") from None


def markdown_table(section: str) -> str:
    """The docs' table of a section of :data:`DOC_SECTIONS`: column, type, unit and frame, meaning."""
    lines = ["| column | type | unit, frame | meaning |", "|---|---|---|---|"]
    for g in DOC_SECTIONS[section]:
        where = ", ".join(p for p in (g.unit, g.frame) if p)
        lines.append(f"| {g.label()} | {g.dtype} |{f' {where}' if where else ''} | {g.meaning} |")
    return "\n".join(lines)


_BLOCK = re.compile(r"(<!-- label-columns: (\w+)[^\n]*-->\n)(.*?)(<!-- /label-columns -->)", re.S)


def doc_sections(text: str) -> dict[str, str]:
    """The column tables of a page (docs/labels.md), by section: what stands between each
    ``<!-- label-columns: SECTION ... -->`` marker and ``<!-- /label-columns -->``."""
    return {m.group(2): m.group(3).rstrip("\n") for m in _BLOCK.finditer(text)}


def render_docs(text: str) -> str:
    """``text`` with each marked table replaced by :func:`markdown_table` of its section."""
    return _BLOCK.sub(lambda m: m.group(1) + markdown_table(m.group(2)) + "\n" + m.group(4), text)


if __name__ == "__main__":  # python -m annotator.schema docs/labels.md: rewrite its tables
    import sys
    from pathlib import Path

    for name in sys.argv[1:]:
        page = Path(name)
        page.write_text(render_docs(page.read_text()))
