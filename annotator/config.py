"""Every physical and numerical constant of the annotator, each with its reason or source.

The sections are frozen dataclasses gathered in :class:`AnnotatorConfig`; a TOML file given with
``--config`` overrides fields by section (``[protocol] lift_height = 0.1``).
"""

from __future__ import annotations

import dataclasses
import math
import operator
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib


class ConfigError(ValueError):
    """A configuration value of the wrong type or outside its range (a usage error: exit 2)."""


@dataclass(frozen=True)
class BoundWhen:
    """A field that a run binds in its manifest only where it changes what the run simulates:
    ``rule(config, trials)`` says where (a run of ``--trials trials``). ``before``: what a folder
    made before the field existed simulated, read for it where the rule holds but the folder's
    manifest lacks it (:meth:`AnnotatorConfig.from_run`). Where the rule does not hold, the field is
    left out, so such a folder resumes."""

    rule: Callable[[AnnotatorConfig, int], bool]
    before: Any


def _perturbed_trials_end_at_lift(config: AnnotatorConfig, trials: int) -> bool:
    """The run has perturbed trials and they end after the lift (``[robust] shake`` false)."""
    return trials != 1 and not config.robust.shake


def _perturbed_approach_simulated(config: AnnotatorConfig, trials: int) -> bool:
    """Perturbed trials that end after the lift, with a simulated approach."""
    return _perturbed_trials_end_at_lift(config, trials) and config.protocol.approach == "simulated"


def _field(
    default: Any,
    *,
    gt: float | None = None,
    ge: float | None = None,
    lt: float | None = None,
    le: float | None = None,
    choices: tuple[str, ...] | None = None,
    implicit: bool = False,
    bound: str | None = None,
    bound_when: BoundWhen | None = None,
) -> Any:
    """A configuration field with its allowed range (checked when a section is built). ``implicit``:
    a number every run had before it became a field: a run binds it only where it differs from
    that default (:meth:`AnnotatorConfig.to_dict`), so folders made before still resume.
    ``bound``: the name a run binds the field under, where that is not its own (the ladder's fields
    keep the names they had in ``[objects]``). ``bound_when``: a run binds the field only where its
    rule holds (:class:`BoundWhen`)."""
    metadata: dict[str, Any] = {
        "gt": gt,
        "ge": ge,
        "lt": lt,
        "le": le,
        "choices": choices,
        "implicit": implicit,
    }
    if bound is not None:
        metadata["bound"] = bound
    if bound_when is not None:
        metadata["bound_when"] = bound_when
    return field(default=default, metadata=metadata)


# Field types a section may have: what a value must be (for the message), the test, the conversion.
# An int given for a float (TOML ``1``) becomes a float, so equal settings compare and hash equal.
_TYPES: dict[str, tuple[str, Any, Any]] = {
    "float": ("a number", lambda v: isinstance(v, int | float) and not isinstance(v, bool), float),
    "int": ("an integer", lambda v: isinstance(v, int) and not isinstance(v, bool), int),
    "bool": ("true or false", lambda v: isinstance(v, bool), bool),
    "str": ("a string", lambda v: isinstance(v, str), str),
    "tuple[float, ...]": (
        "a list of numbers",
        lambda v: (
            isinstance(v, list | tuple)
            and all(isinstance(x, int | float) and not isinstance(x, bool) for x in v)
        ),
        lambda v: tuple(float(x) for x in v),
    ),
}
_BOUNDS = (
    ("gt", operator.gt, ">"),
    ("ge", operator.ge, ">="),
    ("lt", operator.lt, "<"),
    ("le", operator.le, "<="),
)


def _range_text(meta: Mapping[str, Any]) -> str:
    return " and ".join(f"{sign} {meta[k]:g}" for k, _, sign in _BOUNDS if meta.get(k) is not None)


def _checked(where: str, kind: str, meta: Mapping[str, Any], value: Any) -> Any:
    """``value`` as a field of type ``kind`` with ``meta``'s range and choices, or ConfigError."""
    want, test, convert = _TYPES[kind]
    if not test(value):
        raise ConfigError(f"{where}: expected {want}, got {value!r}")
    value = convert(value)
    if kind == "float" and not math.isfinite(value):
        raise ConfigError(f"{where}: expected a finite number, got {value!r}")
    if kind.startswith("tuple") and not all(math.isfinite(x) for x in value):
        raise ConfigError(f"{where}: expected finite numbers, got {list(value)!r}")
    if meta.get("choices") is not None and value not in meta["choices"]:
        raise ConfigError(f"{where}: must be one of {list(meta['choices'])}, got {value!r}")
    if any(meta.get(k) is not None and not op(value, meta[k]) for k, op, _ in _BOUNDS):
        raise ConfigError(f"{where}: must be {_range_text(meta)}, got {value!r}")
    return value


class _Section:
    """Type and range checks for every field of a frozen configuration section.

    Fields are typed ``float``, ``int``, ``bool`` or ``str`` (:data:`_TYPES`), each with its
    allowed range or choices in its metadata (:func:`_field`).
    """

    def __post_init__(self) -> None:
        section = _SECTION_NAMES.get(type(self).__name__, type(self).__name__)
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            kind = f.type if isinstance(f.type, str) else f.type.__name__
            value = getattr(self, f.name)
            if isinstance(value, _Section):  # a section within (checked when it was built)
                continue
            if kind.endswith(" | None"):  # optional: None leaves the value to the gripper description
                if value is None:
                    continue
                kind = kind.removesuffix(" | None")
            object.__setattr__(self, f.name, _checked(f"[{section}] {f.name}", kind, f.metadata, value))


@dataclass(frozen=True)
class PhysicsConfig(_Section):
    """World-level simulation settings (docs/protocol.md, "Physics")."""

    # s; PyBullet's default step and VGN's; contacts are stable there with enough iterations (bullet3 #1936).
    time_step: float = _field(1.0 / 240.0, gt=0.0, le=0.1)
    # Annotation worlds (the RG2's passive links kinematic): 120 keep the followers within 1 deg.
    # see docs/decisions/0002-annotation-gripper-and-solver-iterations.md
    solver_iterations: int = _field(120, ge=1, le=100_000)
    # Worlds with the whole RG2 linkage (arm, replay, scene): at 50 its gears buckled 4-5 deg (bullet3 #2035).
    # see docs/decisions/0002-annotation-gripper-and-solver-iterations.md
    linkage_solver_iterations: int = _field(150, ge=1, le=100_000)
    # PyBullet's numNonContactInnerIterations (default 1): gear constraints, motors, limits per iteration.
    non_contact_iterations: int = _field(1, ge=1, le=1_000)
    gravity: float = -9.81  # m/s^2, standard gravity
    # Share of a contact's penetration corrected per step; Bullet's 0.2 let a pad sink 6 mm into a plate.
    # see docs/decisions/0001-contact-erp.md
    contact_erp: float = _field(0.8, gt=0.0, le=1.0)
    # m, gContactBreakingThreshold (PyBullet's 0.02); kept per process, so each world sets it again.
    # see docs/decisions/0007-contact-breaking-threshold.md
    contact_breaking_threshold: float = _field(0.02, gt=0.0, le=1.0)
    # kg; lighter objects take ceil(sqrt(light_object_mass / m)) steps per time_step (contact_substeps).
    # see docs/decisions/0003-light-objects.md
    light_object_mass: float = _field(0.04, gt=0.0)  # kg
    # kg; a floating light object this heavy is lifted and shaken at time_step (lighter or resting: finer).
    # see docs/decisions/0025-light-objects-held-at-the-time-step.md
    light_hold_mass: float = _field(0.028, gt=0.0)  # >= light_object_mass: never
    # Contact ERP of that lift and shake: 0.8 squeezed light objects out of the pads at time_step.
    # see docs/decisions/0025-light-objects-held-at-the-time-step.md
    light_hold_contact_erp: float = _field(0.5, gt=0.0, le=1.0)

    def substeps(self, mass: float) -> int:
        """Steps per ``time_step`` that resolve the contacts of an object of ``mass`` (kg):
        ceil(sqrt(light_object_mass / mass)), at least 1 (docs/decisions/0003-light-objects.md)."""
        if not mass > 0 or mass >= self.light_object_mass:
            return 1
        return int(math.ceil(math.sqrt(self.light_object_mass / mass) - 1e-9))

    def held(self, base: PhysicsConfig, mass: float) -> PhysicsConfig | None:
        """The settings an object of ``mass`` (kg) is lifted and shaken with once the fingers have
        closed on it, when these are its own finer step in a run of ``base`` (``physics_for``) and
        it weighs at least ``base.light_hold_mass``: ``base``'s time step with
        ``light_hold_contact_erp``. None: these settings throughout (a heavy object; one under
        ``light_hold_mass``; a world stepping at any other step, such as a bench's fixed step)."""
        n = base.substeps(mass)
        if n == 1 or not mass >= base.light_hold_mass or self.time_step != base.time_step / n:
            return None
        return dataclasses.replace(self, time_step=base.time_step, contact_erp=base.light_hold_contact_erp)

    def whole_linkage(self) -> PhysicsConfig:
        """These settings for a world that simulates the RG2's whole linkage (the arm, the GUI)."""
        return dataclasses.replace(self, solver_iterations=self.linkage_solver_iterations)


@dataclass(frozen=True)
class GripperConfig(_Section):
    """How the gripper is simulated. Its own numbers (stroke, grip force, closing speed, pad friction,
    coupling) live in its description (annotator/grippers, docs/grippers.md); a field here that is
    set (not None) overrides the description's value for a run (docs/decisions/0200-gripper-as-data.md).
    """

    # N per pad, within the gripper's [force] range; None: the description's default (RG2 40 N).
    grip_force: float | None = _field(None, gt=0.0)
    # rad/s or m/s of the driven joint; None: the description's [drive] close_speed (RG2 1.0 rad/s).
    close_speed: float | None = _field(None, gt=0.0)
    # Pad friction coefficients; None: the description's [pads] values (RG2 1.0 and 0.002).
    pad_lateral_friction: float | None = _field(None, ge=0.0)
    pad_spinning_friction: float | None = _field(None, ge=0.0)
    # m; None: the description's (0 for the shipped grippers: docs/decisions/0201-pad-rolling-friction.md).
    pad_rolling_friction: float | None = _field(None, ge=0.0)
    # "gear" (JOINT_GEAR constraints) or "position" (per-step control); None: the description's
    # [drive] coupling, measured per gripper (docs/decisions/0202-mimic-coupling.md).
    coupling: str | None = _field(None, choices=("gear", "position"))
    # Passive links only posed for the kinematic checks, or coupled and colliding ("simulated": the
    # arm and the GUI always); docs/decisions/0203-kinematic-passive-links.md.
    passive_links: str = _field("kinematic", choices=("simulated", "kinematic"))
    # The gripper's convex shapes (its box pads) with polyhedral features, as [objects] sat_features.
    # see docs/decisions/0029-contact-and-objects-measured.md
    sat_features: bool = False
    # Gear-constraint error reduction (bullet3 #2791: erp > 0 removes drift); 0202.
    coupling_erp: float = _field(0.8, gt=0.0, le=1.0)
    coupling_max_force: float = _field(1000.0, gt=0.0)  # N or N m; far above any squeeze it resists
    # N, the fixed constraint carrying the floating gripper: ~3 kg (the Panda model and a heavy
    # object) at a few g of shake, with margin.
    carrier_max_force: float = _field(500.0, gt=0.0)
    # The close has stalled after stall_steps steps with the drive slower than this share of its
    # closing speed (RG2: 0.02 rad/s, 50 ms); docs/decisions/0204-close-and-squeeze-loop.md.
    stall_fraction: float = _field(0.02, gt=0.0, lt=1.0)
    stall_steps: int = _field(12, ge=1)
    # While lifted and shaken the squeeze is re-sent every 6 steps (25 ms), and skipped within
    # this share of the last torque sent (0204).
    motor_update_every: int = _field(6, ge=1)
    motor_torque_rtol: float = _field(1e-3, ge=0.0, lt=1.0)
    # Drive positions at which the FK width table is sampled (linear in between: < 0.01 mm error).
    width_table_samples: int = _field(400, ge=2)


@dataclass(frozen=True)
class DecompositionConfig(_Section):
    """The collision ladder (annotator/objects/collision_ladder.py, docs/objects.md "Collision
    shapes"): whether a mesh is its own hull, and how a concave one is cut into convex parts by
    CoACD, then V-HACD, then its hull, within a CPU budget and collision error limits. In a config
    file, ``[objects.decomposition]``. A run binds these fields under ``[objects]`` with the names
    they had before they were a section (each field's ``bound`` name: ``budget`` as
    ``decomposition_budget``), so every folder and cache entry made before keeps its key; a config
    file may use either. Reasons and measurements: docs/decisions/0101-collision-ladder.md.
    """

    # Convex: volume within this share of the hull's (2 % leaves out a real box's chamfers, not a mug).
    convex_volume_tolerance: float = _field(0.02, ge=0.0, lt=1.0)
    # CoACD concavity thresholds, the first down to the last, x 0.6 each to one significant digit
    # (0.05, 0.03, 0.02, 0.01), until the collision error is within its limits or the budget is
    # spent (0101-collision-ladder).
    threshold: float = _field(0.05, gt=0.0, le=1.0, bound="decomposition_threshold")
    min_threshold: float = _field(0.01, gt=0.0, le=1.0, bound="decomposition_min_threshold")
    # CoACD's tree-search iterations per cut (its own default 150): the search bounded so a scan's
    # refinement fits the budget (0101-collision-ladder).
    coacd_search_iterations: int = _field(60, ge=1, le=10_000)
    # A threshold whose bounded search misses the error limits by at most this share of them is cut
    # again with CoACD's own search before a finer one (0101-collision-ladder).
    coacd_retry_margin: float = _field(0.05, ge=0.0, le=1.0)
    # CoACD cuts the mesh as it is; one that has finished no threshold after this share of the
    # budget (CPU-s of its own) is stopped, and CoACD cuts it again after remeshing it with its own
    # manifold preprocessing at coacd_remesh_resolution, searching coacd_remesh_search_iterations
    # per cut: pybullet_data's hollow lego brick, which CoACD did not cut as it is in 300 CPU-s,
    # remeshed in 24 CPU-s to 1.81 mm; the YCB meshes' first cuts took at most 15 (0101-collision-ladder).
    coacd_first_cut_share: float = _field(0.3, gt=0.0, le=1.0)
    coacd_remesh_resolution: int = _field(20, ge=10, le=200)
    coacd_remesh_search_iterations: int = _field(20, ge=1, le=10_000)
    # The search a near miss of the bounded one is cut again with: CoACD 1.0's own tree-search
    # iterations per cut (coacd.run_coacd's mcts_iterations default); 0101-collision-ladder.
    coacd_refine_iterations: int = _field(150, ge=1, le=10_000, implicit=True)
    # Faces of the copy a decomposition cuts (quadric decimation); the error is measured against
    # the full mesh. A mesh with more faces is cut as the smallest copy of max_faces, doubled up to
    # copy_max_faces, that strays at most copy_tolerance from it (0101-collision-ladder).
    max_faces: int = _field(5_000, ge=4, bound="decomposition_max_faces")
    copy_max_faces: int = _field(20_000, ge=4, bound="decomposition_copy_max_faces")
    copy_tolerance: float = _field(0.001, gt=0.0, bound="decomposition_copy_tolerance")  # m
    # Surface points per side (seeded) measuring how far a simplified copy strays from the mesh: the
    # copy chosen, and so the collision shape, follows from this measure (0101-collision-ladder).
    copy_samples: int = _field(4_000, ge=100, le=1_000_000, implicit=True, bound="decomposition_copy_samples")
    # CPU seconds (see budget_basis) per object for its whole load: reading, repair and the ladder
    # (CoACD, V-HACD, hull), 1-3600; CoACD leaves vhacd_reserve of it for V-HACD until it has parts.
    # see docs/decisions/0101-collision-ladder.md
    # CPU-s (reference, by default)
    budget: float = _field(60.0, ge=1.0, le=3600.0, bound="decomposition_budget")
    vhacd_reserve: float = _field(8.0, ge=0.0)  # CPU-s (reference, by default)
    # "reference": budget and reserve in CPU-s of the machine they were set on, scaled by a reference
    # cut timed here, so a slower day keeps the shapes; "cpu": this machine's (0101-collision-ladder).
    budget_basis: str = _field("reference", choices=("reference", "cpu"))
    vhacd_resolution: int = _field(400_000, ge=10_000, le=64_000_000)  # voxels (pybullet.vhacd's range)
    # Seconds a decomposition process may use no CPU at all (a hang, not work) before it is stopped
    # like one over budget; a loaded machine slows a decomposition down, it does not stop it.
    timeout: float = _field(120.0, gt=0.0, bound="decomposition_timeout")  # s
    # Collision error targets: distance between collision shape and mesh surface (mean, max); an
    # object beyond them is reported approximate with its figures.
    collision_mean_limit: float = _field(0.0005, gt=0.0)  # m
    collision_max_limit: float = _field(0.002, gt=0.0)  # m
    collision_error_samples: int = _field(10_000, ge=100)  # surface points per direction, seeded


@dataclass(frozen=True)
class ObjectConfig(_Section):
    """How object meshes are loaded, weighed and given collision shapes (annotator/objects/,
    docs/objects.md). A sidecar ``objects.toml`` overrides mass, density, friction, scale and the
    mass model per object. Reasons and measurements: docs/decisions/01xx-*.md.
    """

    # Solid objects: ~ 0.5 g/cm^3 over the enclosed volume (real ones are hollow or partly filled).
    density: float = _field(500.0, gt=0.0)  # kg/m^3
    # Thin-walled objects (the "shell" mass model): household plastics 900-1400 kg/m^3 (PP, PET, ABS).
    shell_density: float = _field(1000.0, gt=0.0)  # kg/m^3
    shell_thickness: float = _field(0.002, gt=0.0)  # m, given to an open sheet: a moulded plastic wall
    # "auto" picks "shell" for a closed mesh with a mean wall (2 x volume / area) at most
    # shell_max_wall that fills at most shell_max_fill of its convex hull (0100-mass-models).
    shell_max_wall: float = _field(0.008, ge=0.0)  # m
    shell_max_fill: float = _field(0.5, ge=0.0, le=1.0)
    max_extent: float = _field(2.0, gt=0.0)  # m; larger is almost surely millimetres
    min_extent: float = _field(0.005, gt=0.0)  # m; smaller than any graspable household object
    min_volume: float = _field(1e-9, gt=0.0)  # m^3 (a 1 mm cube): a hull below is flat or collinear
    # A repair (annotator/objects/repair.py) may change the surface area by this share at most: a
    # filled hole or a removed fin changes it a little, a repair that lost half the object does not.
    mend_area_tolerance: float = _field(0.1, gt=0.0, implicit=True)
    min_faces: int = _field(4, ge=4)  # a tetrahedron
    # Faces above which a mesh is simplified (quadric decimation); 200,000 keep a household
    # object's surface within a fraction of a millimetre (0102-memory).
    max_faces: int = _field(200_000, ge=4)
    # Open pieces (with a boundary) holding less than this share of the surface area are loose
    # fragments of a scan and are dropped, as are closed pieces under this share of the volume
    # lying apart from the rest (0103-cleaning).
    fragment_max_share: float = _field(0.01, ge=0.0, lt=0.5)
    lateral_friction: float = _field(1.0, ge=0.0)  # as ACRONYM; paired with the pads' 1.0
    # m; with a pad's 0.002: the full-slip torsion of a Hertz contact 13.6 mm across (Johnson 1985).
    # see docs/decisions/0029-contact-and-objects-measured.md
    spinning_friction: float = _field(0.002, ge=0.0)
    rolling_friction: float = _field(0.0, ge=0.0)  # see GripperConfig.pad_rolling_friction
    # Bullet's collision margin on convex meshes (bullet3 #2867): 0 keeps widths within 0.25 mm.
    collision_margin: float = _field(0.0, ge=0.0)  # m
    # Convex shapes with their polyhedral features (bullet3's SAT clipping): a whole contact patch per
    # step, not a point; with [gripper] sat_features. docs/decisions/0029-contact-and-objects-measured.md
    sat_features: bool = False
    # The collision ladder: how a concave mesh is cut into convex parts (its own section, TOML
    # [objects.decomposition]).
    decomposition: DecompositionConfig = field(default_factory=DecompositionConfig)
    # Memory one worker may spend loading an object (MB), checked from its face count before it is
    # read; an object above it fails with its estimate (0102-memory).
    memory_budget: float = _field(4096.0, gt=0.0)  # MB
    # Keep a multi-node .glb or multi-object .obj as one object (default: one object per body).
    merge_parts: bool = False

    def with_decomposition(self, **changes: Any) -> ObjectConfig:
        """This section with ``changes`` to its ladder (``budget=30.0``): :class:`DecompositionConfig`'s
        fields, checked as any. ConfigError for a field it does not have."""
        known = {f.name for f in dataclasses.fields(DecompositionConfig)}
        unknown = sorted(set(changes) - known)
        if unknown:
            raise ConfigError(
                f"unknown field(s) {unknown} in [objects.decomposition]; known: {sorted(known)}"
            )
        return dataclasses.replace(self, decomposition=dataclasses.replace(self.decomposition, **changes))


@dataclass(frozen=True)
class SamplerConfig(_Section):
    """Antipodal candidate sampling (annotator/sampler.py; docs/protocol.md, "Candidates")."""

    # Coulomb coefficient of the friction-cone test; below the simulated 1.0 so pairs keep a margin.
    # see docs/decisions/0012-sampler-constants.md
    friction_coefficient: float = _field(0.5, ge=0.0)
    # Share of candidates sampled without the antipodal test (informative negatives).
    random_fraction: float = _field(0.2, ge=0.0, le=1.0)
    # Rotations about the closing axis per pair: approaches 45 deg apart (chosen, not a measured optimum).
    n_rotations: int = _field(8, ge=1)
    # m off the stroke before a pair is accepted: the open pads pass the surface, 5 mm per side.
    width_margin: float = _field(0.010, ge=0.0)  # m
    # m; shorter chords are self-hits at creases or duplicate faces (a plastic lid's wall is ~1 mm).
    min_width: float = _field(0.0005, ge=0.0)  # m
    # m a ray origin moves along the ray so its own face is not hit: far above float64 noise at 1 m.
    ray_offset: float = _field(1e-6, gt=0.0)  # m
    # Surface points drawn per wanted pair per round (90-100 % pass on primitives).
    # see docs/decisions/0012-sampler-constants.md
    oversample: int = _field(3, ge=1)
    # Rounds of drawing (each doubling the draw) before scarce pairs are topped up with less selective rows.
    max_rounds: int = _field(3, ge=1)


@dataclass(frozen=True)
class ProtocolConfig(_Section):
    """The grasp trial: collision check, close, lift, shake (annotator/trial.py; docs/protocol.md)."""

    # m; any gripper-object distance below this in the kinematic checks is a collision (0: touching).
    collision_margin: float = _field(0.0, ge=0.0)
    pregrasp_clearance: float = _field(0.01, ge=0.0)  # m per side: the gripper opens to width + 2 x this
    approach_distance: float = _field(0.10, ge=0.0)  # m, straight-line approach checked behind the grasp pose
    approach_step: float = _field(0.01, gt=0.0)  # m, < the 11.45 mm pad thickness so no thin wall is skipped
    # "kinematic": a gripper meeting anything along the approach is a collision; "simulated": it moves
    # there in physics, pushing what it meets (real trials); docs/decisions/0212-simulated-approach.md
    approach: str = _field("kinematic", choices=("kinematic", "simulated"))
    approach_speed: float = _field(0.05, gt=0.0)  # m/s of a simulated approach; 0212
    # s the carrier keeps pulling at the end of a simulated approach, so that an unhindered gripper
    # reaches the grasp pose (its lag closes) before it is held there (0212-simulated-approach)
    approach_hold: float = _field(0.1, ge=0.0, implicit=True)
    approach_force: float = _field(
        50.0, gt=0.0
    )  # N the gripper's carrier pushes with on a simulated approach; 0212
    # m per side outside the expected chord where the close starts (free-space travel skipped).
    # see docs/decisions/0005-close-from-outside-the-chord.md
    preclose_gap: float = _field(0.003, ge=0.0)
    # GraspDataGen closes for 1 s; the close ends earlier as soon as the fingers stall.
    close_timeout: float = _field(1.0, gt=0.0)  # s
    lift_height: float = _field(0.10, ge=0.0)  # m, a 10 cm lift
    # s: peak 0.3 m/s and 2.4 m/s^2, near a UR's movel defaults (0.25 m/s, 1.2 m/s^2), not 1.5 g.
    # see docs/decisions/0028-stages-chosen-on-real-trials.md
    lift_duration: float = _field(0.5, gt=0.0)
    # Benchmark motion after the lift (GRASPA's S5): +a, -a, 0 about the approach, then +b, -b, 0 about
    # the closing axis, in motion_duration; both 0: no motion stage. docs/decisions/0026-stages.md
    motion_approach_angle: float = _field(0.0, ge=0.0, le=math.pi)  # rad
    motion_closing_angle: float = _field(0.0, ge=0.0, le=math.pi / 2)  # rad
    motion_duration: float = _field(1.5, gt=0.0, le=60.0)  # s, all six moves
    # The stage trial 0 must hold through for success: "close", "lift", "motion" or "shake"
    # (every stage still runs); see docs/decisions/0026-stages.md
    gate: str = _field("shake", choices=("close", "lift", "motion", "shake"))
    # The shake: one 0.2 s sine period per paired motion, peak 3 g and 345 rad/s^2.
    # see docs/decisions/0004-short-paired-shake.md
    shake_amplitude: float = _field(0.03, ge=0.0)  # m, "a shake of a few centimetres"
    shake_angle: float = _field(0.35, ge=0.0)  # rad (20 deg), "tens of degrees"
    shake_duration: float = _field(0.6, gt=0.0)  # s, all motions
    shake_cycles: int = _field(1, ge=1)  # sine periods per motion
    shake_paired: bool = True  # translate along and rotate about each axis at once (3 motions, not 6)
    # s held still after the shake before the verdict; 0: judged as the last motion ends.
    # see docs/decisions/0004-short-paired-shake.md
    settle_time: float = _field(0.0, ge=0.0)
    # m; held = both pads touch and the object moved less than this in the hand (catches one-edge hangs).
    max_slip: float = _field(0.02, gt=0.0)
    lost_distance: float = _field(0.03, gt=0.0)  # m: early exit once the object is this far from its grasp
    check_every: int = _field(6, ge=1)  # steps between loss checks during lift and shake (25 ms)


# The largest factor an exploration may scale a range by (RobustConfig.scale_levels): ranges are
# explored up to a few times what they are set to, not orders of magnitude beyond.
SCALE_LEVEL_MAX = 10.0


@dataclass(frozen=True)
class RobustConfig(_Section):
    """Execution uncertainty: the perturbations of the K - 1 extra trials of ``--trials K`` (trial 0
    is unperturbed). Each models one way a real execution of the grasp differs from the simulated
    one; the ranges and their sources: docs/decisions/0018-execution-uncertainty.md.

    Every range has an upper bound: an error of execution, not another task. A TCP off by more
    than 10 cm (the widest stroke of the shipped grippers, the RG2's 11 cm; 1,000 x the arm's
    repeatability) misses whatever the gripper could close on, and 20 deg of rotation is beyond any
    arm's or camera's error; an object placed 5 cm off (10 x Dex-Net's sigma, the size
    of a small object) or turned 30 deg is not the placement that was planned, and tilted 20 deg it
    no longer rests on its support; a friction delta of 1 spans every material from ice to rubber
    (coefficients 0.05 .. 1.2) around any object's.
    """

    # The robot's TCP, Gaussian per axis in the TCP frame: the UR3's (and the Panda's) repeatability
    # +-0.1 mm (their datasheets); no datasheet gives an orientation repeatability: 0.
    position_sigma: float = _field(0.0001, ge=0.0, le=0.1)  # m, across the approach (TCP x and y)
    approach_sigma: float = _field(0.0001, ge=0.0, le=0.1)  # m, along the approach (TCP z)
    rotation_sigma: float = _field(0.0, ge=0.0, le=0.35)  # rad, TCP rotation (Gaussian rotation vector)
    # Where the object is against where it was planned (world frame, turned about its centre of
    # mass): "a few mm", placed by hand on printed footprints (GRASPA); Dex-Net 2.0: sigma 5 mm.
    object_position_sigma: float = _field(0.002, ge=0.0, le=0.05)  # m, per horizontal axis
    object_yaw_sigma: float = _field(0.035, ge=0.0, le=0.52)  # rad (2 deg)
    object_tilt_sigma: float = _field(0.0, ge=0.0, le=0.35)  # rad; 0: a resting object sits on its support
    # Object friction coefficient + uniform(-d, d): sigma 0.115, as Dex-Net 2.0's sigma 0.1.
    friction_delta: float = _field(0.2, ge=0.0, le=1.0)
    # Object mass x uniform(1 - d, 1 + d), inertia with it: a mass from a density guess (chosen;
    # 0 for weighed objects).
    mass_delta: float = _field(0.3, ge=0.0, lt=1.0)
    # Grip force x uniform(1 - d, 1 + d); 0: no public tolerance of the RG2's or the Panda's force.
    grip_force_delta: float = _field(0.0, ge=0.0, lt=1.0)
    # m, the centre of mass moved off the mesh's uniform-density one (Gaussian per axis, object
    # frame); 0: no public measurement found (set it for a drill's battery, a half-full bottle).
    com_offset_sigma: float = _field(0.0, ge=0.0, le=0.1)
    # false: a perturbed trial ends after the lift, judged there as after a shake; true: shaken as trial 0
    # see docs/decisions/0021-perturbed-trials-end-at-the-lift.md
    shake: bool = _field(False, bound_when=BoundWhen(_perturbed_trials_end_at_lift, before=True))
    # true: a perturbed trial also runs the benchmark motion and is judged after it (shake implies it)
    # see docs/decisions/0026-stages.md
    motion: bool = False
    # true: perturbed trials run even when trial 0 collides (the object may lie elsewhere)
    # see docs/decisions/0027-execution-fitted-to-real-trials.md
    perturb_collisions: bool = False
    # Exploration (calibrate --fit-ranges): levels drawn per trial for the pose errors and friction
    # spread; none when empty. see docs/decisions/0027-execution-fitted-to-real-trials.md
    scale_levels: tuple[float, ...] = ()
    # true: a lift-only perturbed trial's simulated approach starts 1 cm before the sweep's first contact
    # see docs/decisions/0022-perturbed-approach-from-contact.md
    approach_from_contact: bool = _field(
        True, bound_when=BoundWhen(_perturbed_approach_simulated, before=False)
    )
    # m of that approach kept before the first contact: a sweep increment at least, the carrier at its
    # speed within 1 mm (docs/decisions/0022-perturbed-approach-from-contact.md)
    approach_lead: float = _field(0.01, ge=0.0, implicit=True)
    # true: a lift-only perturbed trial's close ends once the drive moved <= the stall speed's travel
    # over stall_steps steps (docs/decisions/0023-perturbed-close-stalls-by-travel.md)
    stall_by_travel: bool = _field(True, bound_when=BoundWhen(_perturbed_trials_end_at_lift, before=False))
    # true: after that approach from the contact, the fingers start near what they touch if the object
    # is at rest (docs/decisions/0024-perturbed-fingers-start-near-a-resting-object.md)
    fingers_from_contact: bool = _field(
        True, bound_when=BoundWhen(_perturbed_approach_simulated, before=False)
    )
    # m/s and rad/s under which the object counts as at rest after that approach (the fingers start
    # near it): docs/decisions/0024-perturbed-fingers-start-near-a-resting-object.md
    rest_speed: float = _field(1e-3, gt=0.0, implicit=True)
    rest_spin: float = _field(1e-2, gt=0.0, implicit=True)

    def __post_init__(self) -> None:
        super().__post_init__()
        if any(not 0.0 < level <= SCALE_LEVEL_MAX for level in self.scale_levels):
            raise ConfigError(
                f"[robust] scale_levels: each level must be > 0 and <= {SCALE_LEVEL_MAX:g}, "
                f"got {list(self.scale_levels)}"
            )

    def over(self, gripper: Mapping[str, float]) -> RobustConfig:
        """These ranges over a gripper's own (its description's ``[robust]`` table): a field a
        configuration file set (``--config``, a cell's TOML) wins, then the gripper's value, then
        the project's default. A section built in code counts its fields that differ from the
        default as set. ConfigError (one line) for a gripper value out of range."""
        if not gripper:
            return self
        known = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(gripper) - known)
        if unknown:
            raise ConfigError(f"unknown field(s) {unknown} in a gripper's [robust]; known: {sorted(known)}")
        explicit = getattr(self, "_explicit", None)
        if explicit is None:
            default = RobustConfig()
            explicit = {name for name in known if getattr(self, name) != getattr(default, name)}
        ranges: dict[str, Any] = {k: v for k, v in gripper.items() if k not in explicit}
        return dataclasses.replace(self, **ranges)


@dataclass(frozen=True)
class ConfidenceConfig(_Section):
    """The label's confidence: ``score`` mapped to the probability that the real grasp holds,
    fitted by ``annotator calibrate --trials K`` on real trials (annotator/confidence.py; docs/
    decisions/0019-score-calibration.md). Labels made with it carry ``p_success``; a run binds it
    only when it is set, so folders of runs made without it still resume.
    """

    method: str = _field("none", choices=("none", "isotonic"))  # none: no p_success column
    trials: int = _field(0, ge=0, le=100)  # the --trials K of the scores it was fitted on (a run must match)
    scores: tuple[float, ...] = ()  # knots, increasing in [0, 1]
    p_success: tuple[float, ...] = ()  # P(real success) at each knot, not decreasing; linear between
    n: int = _field(0, ge=0, le=1_000_000_000)  # real trials it was fitted on (0: a mapping written by hand)
    brier: float = _field(0.0, ge=0.0, le=1.0)  # its Brier score on them, cross-validated by object
    # The reliability diagram of the fit (annotator report draws it): per bin of P, its trials' mean
    # P, real success rate and count, cross-validated by object.
    reliability_p: tuple[float, ...] = ()
    reliability_rate: tuple[float, ...] = ()
    reliability_n: tuple[float, ...] = ()
    # The perturbed trials of the scores it was fitted on shook ([robust] shake); a file written
    # before the perturbed trials could end at the lift was fitted on shaken ones.
    perturbed_shake: bool = True
    # The p_success at and above which the calibration calls a grasp a success, chosen by balanced
    # accuracy on the real trials (calibrate --fit-ranges); 0.5 where none was chosen.
    threshold: float = _field(0.5, ge=0.0, le=1.0)
    # The real success rate of the trials it was fitted on (0: not recorded): what always answering
    # it scores, the baseline a mapping applied to other trials must beat.
    base_rate: float = _field(0.0, ge=0.0, le=1.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.method == "none":
            return
        knots, p = self.scores, self.p_success
        if not knots or len(knots) != len(p):
            raise ConfigError("[confidence] scores, p_success: one probability per knot, at least one")
        if any(b <= a for a, b in zip(knots, knots[1:], strict=False)) or not 0 <= knots[0] <= knots[-1] <= 1:
            raise ConfigError(f"[confidence] scores: increasing values in [0, 1], got {list(knots)}")
        if any(b < a for a, b in zip(p, p[1:], strict=False)) or not 0 <= p[0] <= p[-1] <= 1:
            raise ConfigError(f"[confidence] p_success: non-decreasing values in [0, 1], got {list(p)}")
        if self.trials < 1:
            raise ConfigError("[confidence] trials: the --trials K the mapping was fitted on (>= 1)")
        self._check_reliability()

    def _check_reliability(self) -> None:
        """The reliability table: three lists of one length, rates and mean probabilities in
        [0, 1], counts whole and >= 0 that add up to at most ``n``; a table (and a Brier score)
        only with the real trials it was measured on (``n`` >= 1)."""
        lists = {"reliability_p": self.reliability_p, "reliability_rate": self.reliability_rate}
        lists["reliability_n"] = self.reliability_n
        lengths = {len(v) for v in lists.values()}
        if len(lengths) > 1:
            shown = ", ".join(f"{k} {len(v)}" for k, v in lists.items())
            raise ConfigError(
                f"[confidence] reliability_p, reliability_rate, reliability_n: one value per bin ({shown})"
            )
        for name in ("reliability_p", "reliability_rate"):
            bad = [x for x in lists[name] if not 0.0 <= x <= 1.0]
            if bad:
                raise ConfigError(f"[confidence] {name}: a share of trials, in [0, 1], got {bad[0]:g}")
        counts = self.reliability_n
        if any(k < 0 or k != round(k) for k in counts):
            bad_count = next(k for k in counts if k < 0 or k != round(k))
            raise ConfigError(f"[confidence] reliability_n: whole numbers of trials >= 0, got {bad_count:g}")
        if self.n == 0 and (counts or self.brier):
            raise ConfigError(
                "[confidence] n = 0: a reliability table and a Brier score are measured on real trials; "
                "a mapping written by hand has neither"
            )
        if sum(counts) > self.n:
            raise ConfigError(
                f"[confidence] reliability_n: {sum(counts):g} trials in the bins, more than n = {self.n}"
            )


@dataclass(frozen=True)
class CellConfig(_Section):
    """The seed's robot cell (annotator/cell): table, UR3 mount and Kinect v2, in the world frame.

    Positions are metres, angles degrees; the seed scene's numbers and their sources are in
    docs/robots.md ("The seed scene"), the cell's behaviour in docs/cell.md.
    """

    table_urdf: str = _field("table/table.urdf")  # from the installed pybullet_data, as the seed
    table_x: float = _field(0.5)
    table_y: float = _field(0.0)
    table_z: float = _field(-0.65)  # the top surface lands at z = -0.025 (0.6 + half its 0.05 m)
    # The UR3's base_link pose: the seed's robot stands at the origin, unrotated.
    robot_x: float = _field(0.0)
    robot_y: float = _field(0.0)
    robot_z: float = _field(0.0)
    robot_yaw: float = _field(0.0)  # deg about world z
    kinect_x: float = _field(0.4)
    kinect_y: float = _field(0.0)
    kinect_z: float = _field(1.57)
    # Not given by the seed; chosen: straight down (the body's +x, its view, to world -z).
    # see docs/decisions/0014-kinect-views.md
    kinect_pitch: float = _field(90.0, ge=-90.0, le=90.0)  # deg about world y
    kinect_yaw: float = _field(0.0)  # deg about world z, applied after the pitch
    # m, world: where a placed object's centre of mass rests, mid-reach for the UR3.
    # see docs/decisions/0013-placements.md
    placement_x: float = _field(0.35)  # m, world
    placement_y: float = _field(0.0)  # m, world
    placements_per_object: int = _field(3, ge=1)  # the most probable few stable poses
    # Stable poses whose "up" directions chain within this angle are one placement (probabilities add).
    # see docs/decisions/0013-placements.md
    placement_merge_angle: float = _field(20.0, ge=0.0, le=180.0)  # deg
    placement_min_probability: float = _field(0.02, ge=0.0, le=1.0)  # rarer poses are not used
    # Each placement settles under gravity this long; its settled pose is the label's obj_x..obj_qw.
    placement_settle_time: float = _field(0.5, ge=0.0)  # s
    # A pose that moves more than this while settling is skipped for the next one.
    placement_max_drift: float = _field(0.005, gt=0.0)  # m, of any point of the object's bounding box
    # A placed object is lowered onto the table when its collision shape is within this of the top
    # (a placement from the mesh's hull is off by far less).
    touch_search: float = _field(0.05, gt=0.0, implicit=True)  # m
    # "probability": an object's rows shared by stable-pose probability; "even": the same share each.
    # see docs/decisions/0010-cell-candidates.md
    candidates_per_placement: str = _field("probability", choices=("probability", "even"))
    # Approach directions within this angle of straight down.
    # see docs/decisions/0010-cell-candidates.md
    approach_cone: float = _field(65.0, gt=0.0, le=90.0)  # deg from vertical
    # Closing axis turned towards the horizontal by up to this (below the friction cone's 26.6 deg).
    # see docs/decisions/0010-cell-candidates.md
    level_angle: float = _field(15.0, ge=0.0, le=45.0)  # deg
    # The fingers' lowest point (their collision boxes) stays this far above the table top.
    # see docs/decisions/0010-cell-candidates.md
    finger_clearance: float = _field(0.003, ge=0.0)  # m
    # A low grasp may sit back along its approach by up to this; its contacts stay 4.9 mm inside the pad.
    max_standoff: float = _field(0.010, ge=0.0)  # m
    # Reachability: any arm or gripper link this close to the table, or arm link to the object, collides.
    arm_collision_margin: float = _field(0.0, ge=0.0)  # m; 0: touching counts
    # --views K: views 1..K-1 look at the object from this far, this high, over this span of azimuths.
    # see docs/decisions/0014-kinect-views.md
    view_distance: float = _field(1.0, gt=0.0)  # m
    view_elevation: float = _field(45.0, gt=0.0, le=90.0)  # deg
    view_azimuth: float = _field(0.0)  # deg about world z from +x: the table's far side, facing the arm
    view_azimuth_span: float = _field(180.0, ge=0.0, le=360.0)  # deg


@dataclass(frozen=True)
class KinectConfig(_Section):
    """The Kinect v2 as rendered (annotator/cell/kinect.py); the numbers' sources are in docs/robots.md.

    Images are rendered with the pinhole intrinsics these fields imply: fx from the horizontal, fy
    from the vertical field of view, principal point at the image centre (depth: fx = 361.6,
    fy = 367.2 px). Depth and colour are rendered from one optical frame.
    """

    depth_width: int = _field(512, ge=1)  # px [V]
    depth_height: int = _field(424, ge=1)  # px [V]
    depth_hfov: float = _field(70.6, gt=0.0, lt=180.0)  # deg [V]
    depth_vfov: float = _field(60.0, gt=0.0, lt=180.0)  # deg [V]
    color_width: int = _field(1920, ge=1)  # px [V]
    color_height: int = _field(1080, ge=1)  # px [V]
    color_hfov: float = _field(84.1, gt=0.0, lt=180.0)  # deg [V]
    color_vfov: float = _field(53.8, gt=0.0, lt=180.0)  # deg [V]
    # Depth range [V] 0.5..4.5 m: outside it the sensor reports 0 (no measurement), as here.
    min_range: float = _field(0.5, gt=0.0)
    max_range: float = _field(4.5, gt=0.0)
    # m; clip planes of the off-screen renderer, bracketing the sensor's range so that is cut explicitly.
    near_plane: float = _field(0.05, gt=0.0)
    far_plane: float = _field(6.0, gt=0.0)
    # Optional depth noise (a render given a Generator): Gaussian, sigma = noise_sigma_1m x z^2 (z in m).
    # see docs/decisions/0014-kinect-views.md (an order of magnitude, not a calibration)
    noise_sigma_1m: float = _field(0.0015, ge=0.0)  # m at z = 1 m
    noise_quantum: float = _field(0.001, ge=0.0)  # m, the sensor's millimetre output; 0 keeps floats
    # --views: the noise model on depth images; colour at views_color_scale x 1920 x 1080 (the costly part).
    views_depth_noise: bool = False
    views_color_scale: float = _field(1.0, gt=0.0, le=1.0)


@dataclass(frozen=True)
class SceneConfig(_Section):
    """Scenes of several objects settled on the seed's table (annotator/scenes): the workspace, the
    three arrangements, settling, the views, the trials among neighbours and clutter removal. A
    section of AnnotatorConfig that a run's manifest binds only when it labels scenes
    (``annotate --scenes``), so folders of object runs made before it existed still resume
    (docs/decisions/0300-scenes-as-units-of-work.md).

    Sources: VGN (ethz-asl/vgn, branch corl2020, src/vgn/simulation.py and scripts/generate_data.py;
    branch devel for the packed region) and ACRONYM (NVlabs/acronym, acronym_tools/acronym.py).
    """

    # A cube on the table top, centred over the cell's placement point (CellConfig placement_x/y,
    # mid-reach for the UR3): VGN's 0.3 m (6 x the Panda's 50 mm finger depth). Its box in the
    # table-top frame is [-s/2, s/2]^2 x [-s/6, 5 s/6] (VGN's task frame puts the table s/6 = 5 cm
    # above the cube's floor); an object whose centre of mass leaves it is removed (VGN).
    workspace_size: float = _field(0.30, gt=0.0)  # m
    # Settling (VGN's wait_for_objects_to_rest): simulate rest_check_time at a time until every
    # object's |(linear m/s, angular rad/s)| < rest_speed, or the time limit.
    rest_speed: float = _field(0.01, gt=0.0)
    rest_check_time: float = _field(0.25, gt=0.0)  # s (VGN: 60 steps of 1/240 s)
    drop_settle_time: float = _field(1.0, ge=0.0)  # s after each pile drop (VGN)
    settle_time: float = _field(2.0, ge=0.0)  # s once all are in, and after each removal (VGN)
    # VGN stops after a settle that removed nothing, even if something still moves (a can rolling on
    # its side on the 12 cm test workspace kept rolling at 4 cm/s); here settling goes on while
    # something moves, at most this many settle_time rounds, and what still moves is removed.
    settle_rounds: int = _field(5, ge=1)
    # pile: each object dropped in a uniformly random orientation, its centre of mass
    # pile_drop_height above the table (raised over the objects already there) over a point uniform
    # in the central third of the workspace (VGN: U(size/3, 2 size/3)), inside a box of walls
    # pile_box_margin in from the workspace's sides (VGN's box at (0.02, 0.02)); the box is then
    # removed. VGN's box model is not published in its repository; 0.2 m walls hold a drop from 0.2 m.
    pile_drop_height: float = _field(0.20, gt=0.0)  # m
    pile_drop_region: float = _field(1.0 / 3.0, gt=0.0, le=1.0)  # share of the side
    pile_box_margin: float = _field(0.02, ge=0.0)  # m
    pile_box_height: float = _field(0.20, gt=0.0)  # m
    # packed: upright (the stable pose nearest the mesh's own +z, as VGN's packed objects stand),
    # random yaw, the centre of mass uniform in the central packed_region of the side (VGN devel:
    # U(0.2, 0.8) x size), placement_gap above the table; rejected when closer than placement_gap
    # to an object already placed; packed_attempts per object (VGN devel: 10).
    packed_region: float = _field(0.6, gt=0.0, le=1.0)  # share of the side
    packed_attempts: int = _field(10, ge=1)
    # table: ACRONYM's random arrangement: a stable pose drawn by its probability (merged as the
    # cell merges them), random yaw, the centre of mass uniform over the workspace's square less
    # table_edge_clearance from its sides (ACRONYM erodes the support polygon by 0.02 m),
    # table_attempts per object (ACRONYM's max_iter 100), placement_gap apart.
    table_edge_clearance: float = _field(0.02, ge=0.0)  # m
    table_attempts: int = _field(100, ge=1)
    # ACRONYM places 2 mm above the support and rejects distances below 2 mm - 1 mm; VGN lifts
    # packed objects 2 mm. Our overlap test rejects anything closer than this.
    placement_gap: float = _field(0.002, ge=0.0)  # m
    # Views (VGN's generate_data.py): distance r ~ U(view_radius_min, view_radius_max), polar angle
    # from the vertical ~ U(0, view_max_polar), azimuth ~ U(0, 360 deg), looking at the workspace's
    # centre on the table. VGN's r = U(1.6, 2.4) x 0.3 m = 0.48-0.72 m is inside the Kinect v2's
    # 0.5 m minimum range for anything standing on the table; 0.8-1.2 m keeps VGN's ratio (1.5)
    # and a workspace-tall pile (0.25 m along the view) beyond 0.5 m.
    view_radius_min: float = _field(0.8, gt=0.0)  # m
    view_radius_max: float = _field(1.2, gt=0.0)  # m
    view_max_polar: float = _field(45.0, ge=0.0, lt=90.0)  # deg (VGN: pi / 4)
    # Trials among neighbours (annotator/scenes/labels.py): close, lift and shake as the protocol
    # says, or close and lift only (VGN's trial: close, retreat 10 cm, judge).
    shake: bool = True
    # m: closer than this to a neighbour or the table is a collision in the kinematic check (Bullet's
    # convex queries erred by 0.7 mm); docs/decisions/0301-labels-among-neighbours.md.
    neighbour_clearance: float = _field(0.001, ge=0.0)
    # The world's step during a trial: the target's (its light-object substeps, [physics]
    # light_object_mass), or the lightest object's in the scene; docs/decisions/0302-scene-substeps.md.
    substeps: str = _field("target", choices=("target", "lightest"))
    # A neighbour "disturbed" by a trial moved at least this far (m, any corner of its bounding box)
    # between the settled scene and the trial's end: the label's disturbed flag. Resting objects
    # drift below 0.2 mm over a trial's second (tests/test_scene_labels.py); 5 mm is a visible push.
    disturbance_threshold: float = _field(0.005, gt=0.0)  # m
    # Clutter removal (annotator/policies/clutter.py): a round ends after this many failed grasps in
    # a row (VGN: 2); a held object is lifted this far straight up before it counts (VGN: 10 cm).
    clutter_max_failures: int = _field(2, ge=1)
    clutter_lift_height: float = _field(0.10, gt=0.0)  # m; docs/decisions/0303-clutter-removal.md


@dataclass(frozen=True)
class AnnotatorConfig:
    """All sections together; the single configuration object the runner passes to workers."""

    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    gripper: GripperConfig = field(default_factory=GripperConfig)
    objects: ObjectConfig = field(default_factory=ObjectConfig)
    sampler: SamplerConfig = field(default_factory=SamplerConfig)
    protocol: ProtocolConfig = field(default_factory=ProtocolConfig)
    robust: RobustConfig = field(default_factory=RobustConfig)
    # Bound in a run's manifest only when set (a calibration: labels carry p_success).
    confidence: ConfidenceConfig = field(default_factory=ConfidenceConfig)
    cell: CellConfig = field(default_factory=CellConfig)
    kinect: KinectConfig = field(default_factory=KinectConfig)
    # Bound in a run's manifest only by scene runs (to_dict(scenes=True)).
    scenes: SceneConfig = field(default_factory=SceneConfig)

    @classmethod
    def thorough(cls, base: AnnotatorConfig | None = None) -> AnnotatorConfig:
        """The reference protocol that ``bench/fidelity.py`` checks the default against.

        Time step 1/1000 s, 300 solver iterations (twice what the default had when this reference
        was set), the whole RG2 linkage simulated, 0.1 mm rolling resistance on pads and objects
        (as when it was set: the default dropped it later, and a reference that followed the
        default moved from 96.6 % agreement to 96.4 %), and a long shake: six sequential
        motions (translations along x, y, z, then rotations about them), each three 0.35 s sine
        periods at 4.5 cm and 30 deg (1.5 g): 6.3 s, over ten times the default's 0.6 s, at 1.5x its
        amplitudes, judged after a 0.05 s settle. A light object is simulated at its finer step
        throughout (``light_hold_mass = light_object_mass``). Fixed values, so that tuning the
        default cannot move the reference.
        """
        base = base or cls()
        return dataclasses.replace(
            base,
            physics=dataclasses.replace(
                base.physics,
                time_step=1.0 / 1000.0,
                solver_iterations=300,
                non_contact_iterations=1,
                contact_breaking_threshold=0.02,
                light_hold_mass=base.physics.light_object_mass,
            ),
            gripper=dataclasses.replace(base.gripper, passive_links="simulated", pad_rolling_friction=1e-4),
            objects=dataclasses.replace(base.objects, rolling_friction=1e-4),
            protocol=dataclasses.replace(
                base.protocol,
                shake_paired=False,
                shake_duration=6.3,
                shake_cycles=3,
                shake_amplitude=0.045,
                shake_angle=0.525,
                settle_time=0.05,
            ),
        )

    def to_dict(self, *, scenes: bool = False, trials: int | None = None) -> dict[str, dict[str, Any]]:
        """Every section as ``{section: {field: value}}``; ``[scenes]`` only with ``scenes`` (a
        scene run binds it, an object run does not: its labels do not depend on it).

        ``trials``: the dict a run of ``--trials trials`` binds in its manifest: a field with a
        :class:`BoundWhen` is left out where its rule does not hold (``[robust] shake`` at
        ``--trials 1`` or when true: folders made before it existed describe such a run, and
        resume; one whose perturbed trials shook never resumes as one whose end at the lift).
        """
        data = dataclasses.asdict(self)
        data["objects"] |= _bound_fields(data["objects"].pop("decomposition"))
        for section, f in _fields_with("implicit"):  # at the value every run had: not bound
            name = _bound_name(f)
            if data[section].get(name, f.default) == f.default:
                data[section].pop(name, None)
        if not scenes:
            data.pop("scenes")
        if self.confidence.method == "none":
            data.pop("confidence")
        if trials is not None:
            for name, f in _fields_with("bound_when"):
                if not f.metadata["bound_when"].rule(self, trials):
                    data[name].pop(_bound_name(f))
        return data

    @classmethod
    def from_run(cls, data: Any, trials: int) -> AnnotatorConfig:
        """The configuration a run of ``--trials trials`` bound (:meth:`to_dict` with ``trials``): a
        field with a :class:`BoundWhen` that the manifest lacks where its rule holds reads as its
        ``before`` (past one trial, a ``[robust]`` without ``shake`` is one whose perturbed trials
        shook; then one without ``approach_from_contact``, one whose simulated approaches ran in
        full; without ``stall_by_travel``, one whose closes stalled by the drive's speed alone;
        without ``fingers_from_contact``, one whose fingers closed from where the approach left
        them). A ``[physics]`` without ``light_hold_mass`` is one whose light objects were simulated
        at their finer step throughout (``light_hold_mass = light_object_mass``)."""
        data = _before_stages(data)
        physics = data.get("physics") if isinstance(data, dict) else None
        if isinstance(physics, dict) and "light_hold_mass" not in physics:
            before = physics.get("light_object_mass", PhysicsConfig.light_object_mass)
            data = {**data, "physics": {**physics, "light_hold_mass": before}}
        if isinstance(data, dict):
            for section, f in _fields_with("bound_when"):  # in order: a rule may read a field before it
                values, name = data.get(section), _bound_name(f)
                if isinstance(values, dict) and name not in values:
                    rule = f.metadata["bound_when"]
                    if rule.rule(cls.from_dict(data), trials):
                        data = {**data, section: {**values, name: rule.before}}
        return cls.from_dict(data)

    @classmethod
    def from_dict(cls, data: Any) -> AnnotatorConfig:
        """Build from ``{section: {field: value}}``; unknown sections or fields, wrong types and
        values out of range raise :class:`ConfigError` naming the field."""
        if not isinstance(data, dict):
            raise ConfigError(f"expected sections of settings, got {type(data).__name__}")
        sections = {f.name for f in dataclasses.fields(cls)}
        kwargs: dict[str, Any] = {}
        defaults = cls()
        for name, values in data.items():
            if name not in sections:
                raise ConfigError(f"unknown config section [{name}]; known: {sorted(sections)}")
            if not isinstance(values, dict):
                raise ConfigError(f"[{name}] must be a section of settings, got {values!r}")
            current = getattr(defaults, name)
            if name == "objects":
                values = _objects_values(values)
            known = {f.name for f in dataclasses.fields(current)}
            unknown = set(values) - known
            if unknown:
                raise ConfigError(f"unknown field(s) {sorted(unknown)} in [{name}]; known: {sorted(known)}")
            kwargs[name] = dataclasses.replace(current, **values)
            if name == "robust":  # what a file sets wins over a gripper's [robust] (RobustConfig.over)
                object.__setattr__(kwargs[name], "_explicit", frozenset(values))
        return cls(**kwargs)

    @classmethod
    def from_toml(cls, path: str | Path) -> AnnotatorConfig:
        """Read a TOML file of overrides; a file that is not TOML is a :class:`ConfigError`."""
        with open(path, "rb") as fh:
            try:
                data = tomllib.load(fh)
            except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
                raise ConfigError(f"not a TOML file ({exc})") from exc
        return cls.from_dict(data)


def _bound_name(f: dataclasses.Field) -> str:
    """The name a run binds field ``f`` under (its ``bound`` metadata, else its own)."""
    return f.metadata.get("bound") or f.name


def _fields_with(key: str) -> list[tuple[str, dataclasses.Field]]:
    """(the section a run binds it in, field) of every field whose metadata has a true ``key``
    (``implicit``, ``bound_when``: :func:`_field`), in the order they are declared; the ladder's
    (``[objects.decomposition]``) in ``objects``."""
    sections = [(f.name, f.default_factory) for f in dataclasses.fields(AnnotatorConfig)]
    sections.append(("objects", DecompositionConfig))
    return [
        (name, f)
        for name, section in sections
        for f in dataclasses.fields(section)  # type: ignore[arg-type]
        if f.metadata.get(key)
    ]


def _bound_fields(decomposition: dict[str, Any]) -> dict[str, Any]:
    """``[objects.decomposition]``'s values by the names a run binds them under in ``[objects]``."""
    names = {f.name: _bound_name(f) for f in dataclasses.fields(DecompositionConfig)}
    return {names[k]: v for k, v in decomposition.items()}


def _objects_values(values: dict[str, Any]) -> dict[str, Any]:
    """``[objects]``'s values with its ladder gathered into one :class:`DecompositionConfig`: from
    an ``[objects.decomposition]`` table (``decomposition = {...}``) or from the bound names a run's
    manifest (and a config file written before the section) gives them in ``[objects]`` itself.
    ConfigError for a setting given both ways, an unknown field of the table, a wrong type or a
    value out of range."""
    by_bound = {_bound_name(f): f.name for f in dataclasses.fields(DecompositionConfig)}
    flat = {by_bound[k]: v for k, v in values.items() if k in by_bound}
    if not flat and "decomposition" not in values:
        return values
    table = _ladder_table(values.get("decomposition", {}))
    _given_once(flat, table)
    rest = {k: v for k, v in values.items() if k not in by_bound and k != "decomposition"}
    return rest | {"decomposition": DecompositionConfig(**(flat | table))}


def _given_once(flat: dict[str, Any], table: dict[str, Any]) -> None:
    """ConfigError naming a ladder setting given both by its bound name in ``[objects]`` (``flat``,
    by field name) and in the ``[objects.decomposition]`` table."""
    both = sorted(set(flat) & set(table))
    if both:
        bound = {f.name: _bound_name(f) for f in dataclasses.fields(DecompositionConfig)}
        raise ConfigError(
            f"[objects.decomposition] {both[0]} is given twice: as [objects] {bound[both[0]]} and in the "
            "[objects.decomposition] table"
        )


def _ladder_table(table: Any) -> dict[str, Any]:
    """An ``[objects.decomposition]`` table as given, or ConfigError for one that is not a table
    of settings or names a field the section does not have."""
    if not isinstance(table, dict):
        raise ConfigError(f"[objects.decomposition] must be a section of settings, got {table!r}")
    known = {f.name for f in dataclasses.fields(DecompositionConfig)}
    unknown = set(table) - known
    if unknown:
        raise ConfigError(
            f"unknown field(s) {sorted(unknown)} in [objects.decomposition]; known: {sorted(known)}"
        )
    return table


# What a folder made before the stages existed simulated, for each field it lacks: no benchmark
# motion, success through the shake, perturbed trials after the lift only and none after a trial 0
# that collided, every perturbed trial at the ranges themselves.
_BEFORE_STAGES: dict[str, dict[str, Any]] = {
    "protocol": {"motion_approach_angle": 0.0, "motion_closing_angle": 0.0, "gate": "shake"},
    "robust": {"motion": False, "perturb_collisions": False, "scale_levels": ()},
}


def _before_stages(data: Any) -> Any:
    """``data`` (a run's bound configuration) with :data:`_BEFORE_STAGES` for the fields it lacks."""
    if not isinstance(data, dict):
        return data
    out = dict(data)
    for section, values in _BEFORE_STAGES.items():
        if isinstance(out.get(section), dict):
            out[section] = {**values, **out[section]}
    return out


_SECTION_NAMES = {
    "PhysicsConfig": "physics",
    "GripperConfig": "gripper",
    "ObjectConfig": "objects",
    "DecompositionConfig": "objects.decomposition",
    "SamplerConfig": "sampler",
    "ProtocolConfig": "protocol",
    "RobustConfig": "robust",
    "ConfidenceConfig": "confidence",
    "CellConfig": "cell",
    "KinectConfig": "kinect",
    "SceneConfig": "scenes",
}
