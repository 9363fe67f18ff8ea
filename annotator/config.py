"""Every physical and numerical constant of the annotator, each with its reason or source.

The sections are frozen dataclasses gathered in :class:`AnnotatorConfig`; a TOML file given with
``--config`` overrides fields by section (``[protocol] lift_height = 0.1``).
"""

from __future__ import annotations

import dataclasses
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib


class ConfigError(ValueError):
    """A configuration value of the wrong type or outside its range (a usage error: exit 2)."""


def _field(
    default: Any,
    *,
    gt: float | None = None,
    ge: float | None = None,
    lt: float | None = None,
    le: float | None = None,
    choices: tuple[str, ...] | None = None,
) -> Any:
    """A configuration field with its allowed range (checked when a section is built)."""
    return field(default=default, metadata={"gt": gt, "ge": ge, "lt": lt, "le": le, "choices": choices})


def _range_text(meta: dict[str, Any]) -> str:
    lo = (
        f"> {meta['gt']:g}"
        if meta.get("gt") is not None
        else (f">= {meta['ge']:g}" if meta.get("ge") is not None else "")
    )
    hi = (
        f"< {meta['lt']:g}"
        if meta.get("lt") is not None
        else (f"<= {meta['le']:g}" if meta.get("le") is not None else "")
    )
    return " and ".join(t for t in (lo, hi) if t)


class _Section:
    """Type and range checks for every field of a frozen configuration section.

    Fields are typed ``float``, ``int``, ``bool`` or ``str``; an int given for a float (TOML
    ``1``) becomes a float so that equal settings compare and hash equal in the manifest.
    """

    def __post_init__(self) -> None:
        section = _SECTION_NAMES.get(type(self).__name__, type(self).__name__)
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            value = getattr(self, f.name)
            where = f"[{section}] {f.name}"
            kind = f.type if isinstance(f.type, str) else f.type.__name__
            if kind == "float":
                if isinstance(value, bool) or not isinstance(value, int | float):
                    raise ConfigError(f"{where}: expected a number, got {value!r}")
                value = float(value)
                if not math.isfinite(value):
                    raise ConfigError(f"{where}: expected a finite number, got {value!r}")
                object.__setattr__(self, f.name, value)
            elif kind == "int":
                if isinstance(value, bool) or not isinstance(value, int):
                    raise ConfigError(f"{where}: expected an integer, got {value!r}")
            elif kind == "bool":
                if not isinstance(value, bool):
                    raise ConfigError(f"{where}: expected true or false, got {value!r}")
            elif kind == "str":
                if not isinstance(value, str):
                    raise ConfigError(f"{where}: expected a string, got {value!r}")
            meta = f.metadata
            if meta.get("choices") is not None and value not in meta["choices"]:
                raise ConfigError(f"{where}: must be one of {list(meta['choices'])}, got {value!r}")
            if kind in ("float", "int"):
                bad = (
                    (meta.get("gt") is not None and not value > meta["gt"])
                    or (meta.get("ge") is not None and not value >= meta["ge"])
                    or (meta.get("lt") is not None and not value < meta["lt"])
                    or (meta.get("le") is not None and not value <= meta["le"])
                )
                if bad:
                    raise ConfigError(f"{where}: must be {_range_text(meta)}, got {value!r}")


@dataclass(frozen=True)
class PhysicsConfig(_Section):
    """World-level simulation settings."""

    # 1/240 s is PyBullet's default step and VGN's; contact-rich grasping is stable there with
    # enough solver iterations (bullet3 #1936).
    time_step: float = _field(1.0 / 240.0, gt=0.0, le=0.1)
    # Solver iterations of the annotation worlds: the floating RG2 with its passive links kinematic
    # (GripperConfig.passive_links), 3 gear constraints instead of 5. bench/fidelity.py, seed 0,
    # 1,100 candidates, against the model before issue 12 (150 iterations, whole linkage):
    #   iterations   success agrees   vs thorough (386 simulated)   widths vs thorough > 0.2 mm
    #   before 150        --              96.6 %                       68 of 357 (max 2.2 mm)
    #   100             99.1 %            96.1 %                       64 of 355 (max 3.8 mm)
    #   110             99.4 %            96.4 %                       50 of 356
    #   120             99.6 %            96.6 %                       48 of 357 (max 1.4 mm)
    #   130             99.3 %            97.2 %                       43 of 358
    # Widths against the model before: 24 of 369 beyond 0.2 mm, but the model before is itself 68
    # beyond the reference, 120 is 48. At 50 iterations the 50 g box of tests/test_rg2.py slipped
    # 27 mm in the shake with the followers 1.4 deg off; at 120 they stay within 1 deg
    # (tests/test_rg2.py). A step at 120 costs 0.81 of the whole linkage's at 150 (bench/peers.py).
    solver_iterations: int = _field(120, ge=1, le=100_000)
    # Worlds that simulate the whole RG2 linkage (the arm in the cell and in replay, the seed scene):
    # PyBullet's default 50 let its five gear constraints buckle by 4-5 deg under a 40 N squeeze
    # (bullet3 #2035); 150 keep them within 1 deg (tests/test_rg2.py).
    linkage_solver_iterations: int = _field(150, ge=1, le=100_000)
    # Inner iterations for the non-contact rows (gear constraints, motors, limits) in each solver
    # iteration (PyBullet's numNonContactInnerIterations; its default is 1).
    non_contact_iterations: int = _field(1, ge=1, le=1_000)
    gravity: float = -9.81  # m/s^2, standard gravity
    # Share of a contact's penetration corrected per step. With Bullet's default (0.2) a pad
    # squeezing 40 N on the edge of an 8 mm plate sank 6 mm into it over a slow close, so thin
    # objects got widths far below their thickness; 0.8 keeps it under 1 mm (bench/fidelity.py,
    # tests/test_protocol.py::test_thin_plate_width_is_its_thickness).
    contact_erp: float = _field(0.8, gt=0.0, le=1.0)
    # Distance (m) within which Bullet keeps a contact point in a manifold and merges a new point
    # into an old one, and makes speculative contacts between convex hulls (gContactBreakingThreshold,
    # PyBullet's default 0.02; one per process, so World.restore_state sets it again). Measured for
    # issue 12 and left at 0.02: 10 mm makes a step 7 % cheaper and keeps the sample objects' labels
    # (bench/fidelity.py seeds 0 and 1: success vs 0.02 99.6 / 99.5 %, widths within 0.13 mm; vs
    # the thorough reference 96.6 / 97.5 % against 96.6 / 96.7 %), but thin plates held face to face
    # at 1/240 s slip out: an 80 g domino (6.35 mm) held 42 of 53 grasps against 53 at 0.02 and
    # 1/960 s, a 5 mm disc 40 of 47 (python bench/light_threshold.py --grams 40 80 with the
    # threshold changed; at 0.02 all held). The sample objects' thin plate is light, so it runs at
    # 1/480 s and fidelity.py did not see it.
    contact_breaking_threshold: float = _field(0.02, gt=0.0, le=1.0)
    # Objects lighter than this are simulated with ceil(sqrt(light_object_mass / mass)) physics
    # steps per time_step (annotator.objects.contact_substeps). Squeezed between the heavy
    # (armature-loaded) fingers, a light object's contacts are too stiff for its mass at 1/240 s:
    # a 4 g, 6.35 mm plate held 2 of 49 face-to-face grasps with the pads 3.9 mm deep; at 1/760 s
    # 49 of 49, 0.15 mm. Neither contact stiffness/damping (k 3e4..1e6 N/m), CCD (swept sphere
    # 2 mm), 300 solver iterations, the Dantzig or PGS solvers, a global CFM nor a friction anchor
    # helped; a 40 g plate holds 48 of 49 at 1/240 s with the pads 0.1 mm deep, hence 40 g.
    # Re-derived for the annotation gripper (python bench/light_threshold.py: a domino, a 40 mm
    # cube, a rod and a disc, seeds 0 and 1, 391 simulated candidates per mass, 1/240 s against
    # 1/960 s): success agreement 96.7 % at 32 g with 29 widths beyond 0.2 mm, 98.7 % and 10 at
    # 40 g, 99.0 % and 2 at 80 g (the control); the domino at 32 g lost 7 of 103 grasps. 40 g stays.
    # Over 15 shapes (--shapes all: plates, boxes, cubes of 30-60 mm, cylinders, a sphere, a bar,
    # the sample mug and banana; ~1,250 simulated candidates per mass) widths move on wide grasps
    # too: beyond 0.2 mm 161 at 32 g (a 60 x 40 x 20 mm box 10, a 40 mm can 11, a 60 mm cube 8),
    # 82 at 40 g, 17 at 80 g; success agrees 97.4 / 98.9 / 99.0 %. No rule by shape or grasp width
    # lets a 32 g object through at 1/240 s, and 40 g is the lowest boundary the data support.
    # A step of time_step * sqrt(m / 40 g) instead of the next whole fraction (1/246 s for 38 g, not
    # 1/480) matches the boundary's own quality over the 15 shapes (success agrees 98.4-99.0 % at
    # 16-36 g, 79-106 widths beyond 0.2 mm; 40 g at 1/240 s: 98.9 %, 82) and takes 18 % of the steps
    # off fidelity.py's trials, but the sample 8 mm plate (38 g) then closes to 7.5-7.8 mm instead
    # of 7.94-8.0 (54 of 357 widths beyond 0.2 mm of the thorough reference, against 30): not kept.
    light_object_mass: float = _field(0.04, gt=0.0)  # kg

    def whole_linkage(self) -> PhysicsConfig:
        """These settings for a world that simulates the RG2's whole linkage (the arm, the GUI)."""
        return dataclasses.replace(self, solver_iterations=self.linkage_solver_iterations)


@dataclass(frozen=True)
class GripperConfig(_Section):
    """The OnRobot RG2 as simulated (numbers from ../shared/ROBOT_FACTS.md)."""

    # Grip force 3..40 N (OnRobot driver max_force 400 in 0.1 N units); annotate at the maximum
    # a user is likely to set for household objects.
    grip_force: float = _field(40.0, gt=0.0)  # N, per finger (squeeze force)
    # Max closing speed: RG2 datasheet ~ 38..127 mm/s finger speed; a 0.5 rad/s link speed gives
    # ~ 27 mm/s per finger at mid-stroke, slow enough that pads do not impact objects hard.
    close_speed: float = _field(1.0, gt=0.0)  # rad/s of the driven link
    # Friction of the pads: rubber-like pads on household objects, 1.0 as ACRONYM uses.
    pad_lateral_friction: float = _field(1.0, ge=0.0)
    # Spinning friction resists rotation of the object about the contact normal (bullet3 #3150);
    # a few mm of effective radius for a 29.8 x 20.2 mm pad.
    pad_spinning_friction: float = _field(0.002, ge=0.0)
    # Rolling resistance (m) of the pads; 0, as the objects' (ObjectConfig.rolling_friction; Bullet
    # solves rolling rows whenever either side has it). A pinched object cannot roll on one pad
    # without sliding on the other, which lateral and spinning friction resist; the 0.1 mm it had
    # held nothing measurable but cost two of the six solver rows of every contact point, a quarter
    # of each step in contact (bench/peers.py). bench/fidelity.py, seed 0 (1,100 candidates): no
    # success flips, agreement with the thorough reference 96.6 % of the 386 simulated (unchanged),
    # widths of rows both succeed within 0.12 mm at the 99th percentile (3 of 369 beyond 0.2 mm, at
    # most 0.57 mm: objects that turn in the hand while closing; 200 solver iterations instead of
    # 150 move 33 beyond, up to 3.2 mm).
    pad_rolling_friction: float = _field(0.0, ge=0.0)
    # How the mimic followers are coupled: "gear" (JOINT_GEAR constraints) or "position"
    # (per-step position control); chosen by the 40 N squeeze measurement in bench/rg2_coupling.py.
    coupling: str = _field("gear", choices=("gear", "position"))
    # The annotation gripper's passive links (the parallelogram's inner knuckles, which carry no
    # pad): "simulated" couples them with gear constraints and lets them collide like the rest;
    # "kinematic" only poses them for the kinematic collision checks (annotator.sim.rg2). The arm
    # and the GUI always simulate the whole linkage.
    passive_links: str = _field("kinematic", choices=("simulated", "kinematic"))
    # Gear-constraint coupling of the mimic followers (bullet3 #2791: erp > 0 removes drift).
    coupling_erp: float = _field(
        0.8, gt=0.0, le=1.0
    )  # 0.2 let followers lag 1.6 deg at 40 N on the floating gripper; 0.8: 0.5 deg
    coupling_max_force: float = _field(1000.0, gt=0.0)  # N or N m; far above the 40 N squeeze it must resist
    # The fixed constraint carrying the floating gripper: must hold gripper (0.74 kg) plus a
    # heavy object (~1 kg) at shake accelerations of a few g with margin: 17 kg x 30 m/s^2.
    carrier_max_force: float = _field(500.0, gt=0.0)  # N
    # Finger speed below which the closing motion counts as stopped (rad/s of the driven link):
    # a free-closing link moves at the commanded ~1 rad/s; stalled on an object it creeps < 1e-2.
    stall_speed: float = _field(0.02, gt=0.0)
    # Consecutive stalled steps before the close is declared finished (12 steps = 50 ms at 240 Hz):
    # long enough for the contact forces to build up to the commanded squeeze.
    stall_steps: int = _field(12, ge=1)
    # While the carrier moves (lift, shake) the fingers are stalled on the object and the squeeze
    # torque (force x dw/dphi at the current angle) barely changes: it is re-computed every 6 steps
    # (25 ms, a 40 Hz force loop) rather than every step.
    motor_update_every: int = _field(6, ge=1)
    # A motor command whose torque differs from the last one sent by less than this share is not
    # re-sent (PyBullet keeps motor settings between steps): 0.1 % of 40 N is 0.04 N of squeeze.
    motor_torque_rtol: float = _field(1e-3, ge=0.0, lt=1.0)
    # Driven angles at which the model's FK width table is sampled; widths between are linear
    # interpolations (the table is smooth: w = f(sin phi), 400 samples -> < 0.01 mm error).
    width_table_samples: int = _field(400, ge=2)


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
    min_faces: int = _field(4, ge=4)  # a tetrahedron
    # Faces above which a mesh is simplified (quadric decimation); 200,000 keep a household
    # object's surface within a fraction of a millimetre (0102-memory).
    max_faces: int = _field(200_000, ge=4)
    # Open pieces (with a boundary) holding less than this share of the surface area are loose
    # fragments of a scan and are dropped, as are closed pieces under this share of the volume
    # lying apart from the rest (0103-cleaning).
    fragment_max_share: float = _field(0.01, ge=0.0, lt=0.5)
    lateral_friction: float = _field(1.0, ge=0.0)  # as ACRONYM; paired with the pads' 1.0
    spinning_friction: float = _field(0.002, ge=0.0)
    rolling_friction: float = _field(0.0, ge=0.0)  # see GripperConfig.pad_rolling_friction
    # Bullet's collision margin on convex meshes (bullet3 #2867): 0 keeps widths within 0.25 mm.
    collision_margin: float = _field(0.0, ge=0.0)  # m
    # Convex: volume within this share of the hull's (2 % leaves out a real box's chamfers, not a mug).
    convex_volume_tolerance: float = _field(0.02, ge=0.0, lt=1.0)
    # CoACD concavity thresholds, the first down to the last, x 0.6 each (0.05, 0.03, 0.02), until
    # the collision error is within its limits or the budget is spent (0101-collision-ladder).
    decomposition_threshold: float = _field(0.05, gt=0.0, le=1.0)
    decomposition_min_threshold: float = _field(0.02, gt=0.0, le=1.0)
    # Faces of the copy a decomposition cuts (quadric decimation); the error is measured against
    # the full mesh (0101-collision-ladder).
    decomposition_max_faces: int = _field(5_000, ge=4)
    # CPU seconds per object for the whole decomposition ladder (CoACD, V-HACD, hull), 1-3600
    # (0101-collision-ladder); CoACD leaves vhacd_reserve of it for V-HACD until it has parts.
    decomposition_budget: float = _field(60.0, ge=1.0, le=3600.0)  # CPU-s
    vhacd_reserve: float = _field(8.0, ge=0.0)  # CPU-s
    vhacd_resolution: int = _field(400_000, ge=10_000, le=64_000_000)  # voxels (pybullet.vhacd's range)
    # Seconds a decomposition process may use no CPU at all (a hang, not work) before it is stopped
    # like one over budget; a loaded machine slows a decomposition down, it does not stop it.
    decomposition_timeout: float = _field(120.0, gt=0.0)  # s
    # Collision error targets: distance between collision shape and mesh surface (mean, max); an
    # object beyond them is reported approximate with its figures.
    collision_mean_limit: float = _field(0.0005, gt=0.0)  # m
    collision_max_limit: float = _field(0.002, gt=0.0)  # m
    collision_error_samples: int = _field(10_000, ge=100)  # surface points per direction, seeded
    # Memory one worker may spend loading an object (MB), checked from its face count before it is
    # read; an object above it fails with its estimate (0102-memory).
    memory_budget: float = _field(4096.0, gt=0.0)  # MB
    # Keep a multi-node .glb or multi-object .obj as one object (default: one object per body).
    merge_parts: bool = False


@dataclass(frozen=True)
class SamplerConfig(_Section):
    """Antipodal candidate sampling (owned by annotator/sampler.py)."""

    # Coulomb friction coefficient used for the friction-cone test; below the simulated 1.0 so
    # that sampled candidates keep a margin.
    friction_coefficient: float = _field(0.5, ge=0.0)
    # Share of candidates sampled without the antipodal test (informative negatives).
    random_fraction: float = _field(0.2, ge=0.0, le=1.0)
    # Rotations tried about the closing axis for each antipodal pair: 8 gives approach
    # directions 45 deg apart, an even cover of the circle of approaches (a chosen value,
    # not a measured optimum).
    n_rotations: int = _field(8, ge=1)
    # Clearance subtracted from the gripper's maximum opening before a pair is accepted: the
    # open pads must pass the surface on the approach, 5 mm per side (RG2 stroke 0..110 mm).
    width_margin: float = _field(0.010, ge=0.0)  # m
    # Chords shorter than this are numerical self-hits at creases or duplicate faces, not
    # graspable walls (the thinnest real household wall, a plastic lid, is ~ 1 mm).
    min_width: float = _field(0.0005, ge=0.0)  # m
    # Ray origins are moved this far along the ray so the source face itself is not hit; far
    # above float64 noise at metre scale, far below any feature the pads can feel.
    ray_offset: float = _field(1e-6, gt=0.0)  # m
    # Surface points drawn per wanted antipodal candidate in one round. Measured on primitives
    # (box, sphere, cylinder, torus, thin-walled tube) 90-100 % pass; 3x leaves room for shapes
    # where most points have no opposite wall within the stroke before a second round is needed.
    oversample: int = _field(3, ge=1)
    # Rounds of drawing (each doubling the draw) before scarce pairs are topped up with the
    # less selective kind; bounds the time spent on objects that have few or no pairs.
    max_rounds: int = _field(3, ge=1)


@dataclass(frozen=True)
class ProtocolConfig(_Section):
    """The grasp trial: collision check, close, lift, shake (annotator/trial.py)."""

    # Kinematic collision check: any gripper-object distance below this (m) is a collision.
    # 0 means touching counts; the sampler leaves pregrasp_clearance on each side of the pads.
    collision_margin: float = _field(0.0, ge=0.0)
    pregrasp_clearance: float = _field(0.01, ge=0.0)  # m per side: the gripper opens to width + 2 x this
    approach_distance: float = _field(0.10, ge=0.0)  # m, straight-line approach checked behind the grasp pose
    approach_step: float = _field(0.01, gt=0.0)  # m, < the 11.45 mm pad thickness so no thin wall is skipped
    # The close starts with the pads this far (m per side) outside the expected chord instead of
    # at the open width: the skipped travel is through free space (checked kinematically), and
    # 3 mm leaves the closing speed reached before contact (bench/fidelity.py).
    preclose_gap: float = _field(0.003, ge=0.0)
    # GraspDataGen closes for 1 s; the close ends earlier as soon as the fingers stall.
    close_timeout: float = _field(1.0, gt=0.0)  # s
    lift_height: float = _field(0.10, ge=0.0)  # m, the robot issue's 10 cm lift
    lift_duration: float = _field(
        0.2, gt=0.0
    )  # s: 0.5 m/s average, 0.75 m/s peak (UR3 tool speed limit ~1 m/s)
    # The shake: three motions, each translating along and rotating about one gripper axis at
    # once, one 0.2 s sine period each: peak 0.03 m x (2 pi / 0.2 s)^2 = 30 m/s^2 (3 g; GraspDataGen
    # tugs at 1 g) and 0.35 rad x (2 pi / 0.2 s)^2 = 345 rad/s^2. Chosen with bench/fidelity.py
    # against the thorough reference (see AnnotatorConfig.thorough), agreement on the 393
    # simulated candidates of seed 0: six sequential 0.35 s motions at 1 g (the first default)
    # 92.6 % at 654 steps per trial, paired 0.35 s periods 92.4 %, paired 0.25 s 95.9 %, these
    # 0.2 s periods 96.2 % (270 steps; 96.7 % at 244 with preclose_gap).
    shake_amplitude: float = _field(0.03, ge=0.0)  # m, "a shake of a few centimetres"
    shake_angle: float = _field(0.35, ge=0.0)  # rad (20 deg), "tens of degrees"
    shake_duration: float = _field(0.6, gt=0.0)  # s, all motions
    shake_cycles: int = _field(1, ge=1)  # sine periods per motion
    shake_paired: bool = True  # translate along and rotate about each axis at once (3 motions, not 6)
    # Seconds held still after the shake before judging. 0: judged as the last motion ends. A
    # 0.05 s settle (12 steps, 5 % of a trial) changed none of the 386 simulated outcomes of
    # bench/fidelity.py seed 0 (the thorough reference keeps its 0.05 s).
    settle_time: float = _field(0.0, ge=0.0)
    # Held = both pads touch and the object moved less than this in the hand (m); ACRONYM and
    # GraspDataGen judge contact only, the slip bound catches an object hanging by one edge.
    max_slip: float = _field(0.02, gt=0.0)
    lost_distance: float = _field(0.03, gt=0.0)  # m: early exit once the object is this far from its grasp
    check_every: int = _field(6, ge=1)  # steps between loss checks during lift and shake (25 ms)


@dataclass(frozen=True)
class RobustConfig(_Section):
    """Perturbations of the K - 1 extra trials of ``--trials K`` (trial 0 is unperturbed).

    Dex-Net 2.0's robust metric samples the gripper pose with sigma 5 mm and friction with sigma
    0.1; ours models a calibrated UR3 (repeatability +-0.1 mm [UR datasheet]) seen by a depth
    camera, whose object pose error is a few millimetres and degrees.
    """

    position_sigma: float = _field(0.002, ge=0.0)  # m, TCP position noise (Gaussian, per axis)
    rotation_sigma: float = _field(
        0.035, ge=0.0
    )  # rad (2 deg), TCP rotation noise (Gaussian rotation vector)
    friction_delta: float = _field(0.2, ge=0.0)  # object friction coefficient + uniform(-0.2, 0.2)
    mass_delta: float = _field(0.3, ge=0.0, lt=1.0)  # object mass x uniform(0.7, 1.3)


@dataclass(frozen=True)
class CellConfig(_Section):
    """The seed's robot cell (annotator/cell): table, UR3 mount and Kinect v2, in the world frame.

    Positions are metres, angles degrees. The seed script's numbers (../shared/ROBOT_FACTS.md
    "Seed scene"): UR3 at the origin, table/table.urdf at (0.5, 0, -0.65), Kinect at (0.4, 0, 1.57).
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
    # The seed's Kinect orientation is not recorded (ROBOT_FACTS gives the position only); chosen:
    # straight down (pitch 90 deg turns the body's +x, its viewing axis, to world -z), so the
    # 70.6 x 60 deg depth frustum covers the table top in front of the arm from 1.6 m above it.
    kinect_pitch: float = _field(90.0, ge=-90.0, le=90.0)  # deg about world y
    kinect_yaw: float = _field(0.0)  # deg about world z, applied after the pitch
    # Placements (annotator/cell/placement.py): each object rests on the table top in its stable
    # poses (trimesh's compute_stable_poses), its centre of mass over this point in front of the
    # mount: 0.35 m out is mid-reach for the UR3 (the closed-form IK reaches a top-down TCP at the
    # table out to 0.52 m; nearer than ~0.2 m the wrist centre runs into the d4 cylinder).
    placement_x: float = _field(0.35)  # m, world
    placement_y: float = _field(0.0)  # m, world
    placements_per_object: int = _field(3, ge=1)  # the most probable few stable poses
    # Stable poses whose "up" directions in the object frame are linked by a chain of neighbours
    # each within this angle are one placement (a cylinder's hull gives one pose per side facet,
    # 7.5 deg apart on the can: the whole ring is one placement, lying): probabilities add.
    placement_merge_angle: float = _field(20.0, ge=0.0, le=180.0)  # deg
    placement_min_probability: float = _field(0.02, ge=0.0, le=1.0)  # rarer poses are not used
    # annotate --cell: each placement settles under gravity on the table before its trials (the
    # settled pose is the label's obj_x..obj_qw). trimesh's stable poses come from the mesh's hull
    # about the mesh's centre of mass; the simulated body (convex parts) can still tip or roll: of
    # the sample objects, the bowl's third pose moved 31 mm in 1 s, every other pose < 0.1 mm. A
    # pose that moves more than placement_max_drift while settling is skipped for the next one.
    placement_settle_time: float = _field(0.5, ge=0.0)  # s
    placement_max_drift: float = _field(0.005, gt=0.0)  # m, of any point of the object's bounding box
    # annotate --cell candidates (annotator/cell/candidates.py), sampled per placement knowing the
    # table. How the N rows of an object are shared among its placements: "probability" in
    # proportion to their stable-pose probabilities (renormalised over the placements kept), so
    # the labels meet each placement as often as an object dropped on the table lands in it;
    # "even": the same share each.
    candidates_per_placement: str = _field("probability", choices=("probability", "even"))
    # Approach directions within this angle of straight down. With the floating sampler's
    # directions, every cell success approached less than 75 deg from vertical and 168 of the 220
    # floating successes that hit the table came in lower than 60 deg or with the TCP < 15 mm up.
    # Sample objects, --n 100, held (reachable) for a cone of 55 / 65 / 75 deg: 374 (316) / 360
    # (306) / 350 (292), of which reachable more than 45 deg off vertical 16 / 19 / 28: a middle
    # value that keeps side grasps of tall objects (a can, a bottle) at little cost.
    approach_cone: float = _field(65.0, gt=0.0, le=90.0)  # deg from vertical
    # An antipodal pair's closing axis is the first contact's inward normal turned towards the
    # horizontal by a uniform angle up to this (never past level); the usual antipodal test then
    # runs on it. A level axis admits a grasp from straight above; the sample ring's tube (16 faces,
    # none vertical: normals 11.2 deg off horizontal at best) had no pair within 10 deg of level
    # without it. Below the sampler's friction cone (atan 0.5 = 26.6 deg), so the first contact
    # stays inside it with margin.
    level_angle: float = _field(15.0, ge=0.0, le=45.0)  # deg
    # The open and the closed fingers' lowest point (their collision boxes, read from the RG2
    # model) stays this far above the table top; the kinematic check with the table still decides
    # ``collision``. A few mm: the height a taught grasp keeps off a table (the UR3 repeats to
    # 0.1 mm, a table top is flat to ~1 mm).
    finger_clearance: float = _field(0.003, ge=0.0)  # m
    # A grasp on a low object may sit back along its approach (the TCP above the midpoint of the
    # two contacts) by up to this much so the fingertips clear the table: the contacts then lie
    # between the pad centre and its tip, still 4.9 mm inside the 29.8 mm pad at the maximum.
    max_standoff: float = _field(0.010, ge=0.0)  # m
    # Reachability (annotator/cell/reach.py): any arm or gripper link closer than this to the
    # table, or arm link (not gripper) to the object, along the approach is a collision.
    arm_collision_margin: float = _field(0.0, ge=0.0)  # m; 0: touching counts
    # annotate --cell --views K: view 0 is the seed's Kinect; views 1..K-1 look at the object's
    # centre of mass from view_distance away and view_elevation above the horizontal, at azimuths
    # (about world z, from +x) spread evenly over view_azimuth_span centred on view_azimuth
    # (one extra view: at view_azimuth). 0 deg is the table's far side, facing the arm; a camera
    # behind the arm (180 deg) sees mostly the arm, within the sensor's 0.5 m minimum range, so
    # the default span covers the far side and the two ends of the table. 1 m is twice that
    # minimum range; a 10 cm object then spans ~ 36 depth pixels.
    view_distance: float = _field(1.0, gt=0.0)  # m
    view_elevation: float = _field(45.0, gt=0.0, le=90.0)  # deg
    view_azimuth: float = _field(0.0)  # deg
    view_azimuth_span: float = _field(180.0, ge=0.0, le=360.0)  # deg


@dataclass(frozen=True)
class KinectConfig(_Section):
    """The Kinect v2 as rendered (annotator/cell/kinect.py); ../shared/ROBOT_FACTS.md "Kinect v2".

    Images are rendered with the pinhole intrinsics these fields imply: fx from the horizontal,
    fy from the vertical field of view, principal point at the image centre (for depth fx = 361.6,
    fy = 367.2 px; the sample calibration in ROBOT_FACTS has fx = fy = 365.5: within 1 %). Depth and
    colour are rendered from one optical frame (the real colour camera sits ~5 cm beside the depth
    camera; a learner that needs the offset should calibrate it on the real sensor).
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
    # Clip planes of the off-screen renderer (m): inside the near one and beyond the far one
    # nothing is drawn; chosen to bracket the sensor's range so that range is cut explicitly.
    near_plane: float = _field(0.05, gt=0.0)
    far_plane: float = _field(6.0, gt=0.0)
    # Optional depth noise (used only when a render is given a Generator). [C] Gaussian along the
    # ray with sigma = noise_sigma_1m x z^2 (z in m), then rounded to noise_quantum, the sensor's
    # millimetre output. The published Kinect v2 evaluations (Fankhauser et al., ICAR 2015; Corti
    # et al., RAS 2016) report random errors of a few mm at 1 m growing with distance and with the
    # surface's angle: 1.5 mm at 1 m is that order of magnitude, not a calibration of a sensor.
    noise_sigma_1m: float = _field(0.0015, ge=0.0)  # m at z = 1 m
    noise_quantum: float = _field(0.001, ge=0.0)  # m; 0 keeps floats
    # annotate --views: depth images with the noise model above (a Generator keyed on seed, object,
    # placement and view) instead of the exact render; colour rendered at color_scale times
    # 1920 x 1080 (one full-size TinyRenderer colour image costs ~ 0.8 s of a worker).
    views_depth_noise: bool = False
    views_color_scale: float = _field(1.0, gt=0.0, le=1.0)


@dataclass(frozen=True)
class AnnotatorConfig:
    """All sections together; the single configuration object the runner passes to workers."""

    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    gripper: GripperConfig = field(default_factory=GripperConfig)
    objects: ObjectConfig = field(default_factory=ObjectConfig)
    sampler: SamplerConfig = field(default_factory=SamplerConfig)
    protocol: ProtocolConfig = field(default_factory=ProtocolConfig)
    robust: RobustConfig = field(default_factory=RobustConfig)
    cell: CellConfig = field(default_factory=CellConfig)
    kinect: KinectConfig = field(default_factory=KinectConfig)

    @classmethod
    def thorough(cls, base: AnnotatorConfig | None = None) -> AnnotatorConfig:
        """The reference protocol that ``bench/fidelity.py`` checks the default against.

        Time step 1/1000 s, 300 solver iterations (twice what the default had when this reference
        was set), the whole RG2 linkage simulated, 0.1 mm rolling resistance on pads and objects
        (as when it was set: issue 12 dropped it from the default, and a reference that followed the
        default moved from 96.6 % agreement to 96.4 %), and a long shake: six sequential
        motions (translations along x, y, z, then rotations about them), each three 0.35 s sine
        periods at 4.5 cm and 30 deg (1.5 g): 6.3 s, over ten times the default's 0.6 s, at 1.5x its
        amplitudes, judged after a 0.05 s settle. Fixed values, so that tuning the default cannot
        move the reference.
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

    def to_dict(self) -> dict[str, dict[str, Any]]:
        return dataclasses.asdict(self)

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
            known = {f.name for f in dataclasses.fields(current)}
            unknown = set(values) - known
            if unknown:
                raise ConfigError(f"unknown field(s) {sorted(unknown)} in [{name}]; known: {sorted(known)}")
            kwargs[name] = dataclasses.replace(current, **values)
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


_SECTION_NAMES = {
    "PhysicsConfig": "physics",
    "GripperConfig": "gripper",
    "ObjectConfig": "objects",
    "SamplerConfig": "sampler",
    "ProtocolConfig": "protocol",
    "RobustConfig": "robust",
    "CellConfig": "cell",
    "KinectConfig": "kinect",
}
