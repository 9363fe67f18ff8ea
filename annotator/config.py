"""Every physical and numerical constant of the annotator, each with its reason or source.

The sections are frozen dataclasses gathered in :class:`AnnotatorConfig`; a TOML file given with
``--config`` overrides fields by section (``[protocol] lift_height = 0.1``).
"""

from __future__ import annotations

import dataclasses
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib


@dataclass(frozen=True)
class PhysicsConfig:
    """World-level simulation settings."""

    # 1/240 s is PyBullet's default step and VGN's; contact-rich grasping is stable there with
    # enough solver iterations (bullet3 #1936).
    time_step: float = 1.0 / 240.0
    # Default 50 iterations lose grip under squeeze (bullet3 #2035); 150 held a 40 N squeeze.
    solver_iterations: int = 150
    gravity: float = -9.81  # m/s^2, standard gravity
    # Share of a contact's penetration corrected per step. With Bullet's default (0.2) a pad
    # squeezing 40 N on the edge of an 8 mm plate sank 6 mm into it over a slow close, so thin
    # objects got widths far below their thickness; 0.8 keeps it under 1 mm (bench/fidelity.py,
    # tests/test_protocol.py::test_thin_plate_width_is_its_thickness).
    contact_erp: float = 0.8


@dataclass(frozen=True)
class GripperConfig:
    """The OnRobot RG2 as simulated (numbers from ../shared/ROBOT_FACTS.md)."""

    # Grip force 3..40 N (OnRobot driver max_force 400 in 0.1 N units); annotate at the maximum
    # a user is likely to set for household objects.
    grip_force: float = 40.0  # N, per finger (squeeze force)
    # Max closing speed: RG2 datasheet ~ 38..127 mm/s finger speed; a 0.5 rad/s link speed gives
    # ~ 27 mm/s per finger at mid-stroke, slow enough that pads do not impact objects hard.
    close_speed: float = 1.0  # rad/s of the driven link
    # Friction of the pads: rubber-like pads on household objects, 1.0 as ACRONYM uses.
    pad_lateral_friction: float = 1.0
    # Spinning friction resists rotation of the object about the contact normal (bullet3 #3150);
    # a few mm of effective radius for a 29.8 x 20.2 mm pad.
    pad_spinning_friction: float = 0.002
    pad_rolling_friction: float = 0.0001
    # How the mimic followers are coupled: "gear" (JOINT_GEAR constraints) or "position"
    # (per-step position control); chosen by the 40 N squeeze measurement in bench/rg2_coupling.py.
    coupling: str = "gear"
    # Gear-constraint coupling of the mimic followers (bullet3 #2791: erp > 0 removes drift).
    coupling_erp: float = 0.8  # 0.2 let followers lag 1.6 deg at 40 N on the floating gripper; 0.8: 0.5 deg
    coupling_max_force: float = 1000.0  # N or N m; far above the 40 N squeeze it must resist
    # The fixed constraint carrying the floating gripper: must hold gripper (0.74 kg) plus a
    # heavy object (~1 kg) at shake accelerations of a few g with margin: 17 kg x 30 m/s^2.
    carrier_max_force: float = 500.0  # N


@dataclass(frozen=True)
class ObjectConfig:
    """How object meshes are loaded and given mass (owned by annotator/objects.py)."""

    # Objects are simulated solid, but real ones are hollow or partly filled: ~ 0.5 g/cm^3 over the
    # enclosed volume is a middle ground (a 40 mm cube 32 g, the 66 x 115 mm can 196 g, a 60 x 40 x
    # 120 mm box 144 g), within the RG2's 2 kg friction payload; a thin-walled mesh (mug, bowl)
    # gets only its wall volume, so it comes out light (the sample mug 65 g).
    density: float = 500.0  # kg/m^3
    # A mesh whose largest bounding-box side exceeds this many metres is almost surely in millimetres.
    max_extent: float = 2.0
    min_extent: float = 0.005  # m; smaller than any graspable household object
    lateral_friction: float = 1.0  # as ACRONYM; paired with the pads' 1.0
    spinning_friction: float = 0.002
    rolling_friction: float = 0.0001
    # Bullet pads convex meshes with a collision margin (bullet3 #2867, ROBOT_FACTS pitfall 5):
    # with the default the pads stopped 0.9 mm short of each face, so every label's width read
    # 1.8 mm wide of the object's chord. Zero margin: within 0.25 mm (tests/test_protocol.py).
    collision_margin: float = 0.0  # m
    # Convex decomposition (CoACD) concavity threshold: 0.05 is the library's default quality.
    decomposition_threshold: float = 0.05


@dataclass(frozen=True)
class SamplerConfig:
    """Antipodal candidate sampling (owned by annotator/sampler.py)."""

    # Coulomb friction coefficient used for the friction-cone test; below the simulated 1.0 so
    # that sampled candidates keep a margin.
    friction_coefficient: float = 0.5
    # Share of candidates sampled without the antipodal test (informative negatives).
    random_fraction: float = 0.2
    # Rotations tried about the closing axis for each antipodal pair: 8 gives approach
    # directions 45 deg apart, an even cover of the circle of approaches (a chosen value,
    # not a measured optimum).
    n_rotations: int = 8
    # Clearance subtracted from the gripper's maximum opening before a pair is accepted: the
    # open pads must pass the surface on the approach, 5 mm per side (RG2 stroke 0..110 mm).
    width_margin: float = 0.010  # m
    # Chords shorter than this are numerical self-hits at creases or duplicate faces, not
    # graspable walls (the thinnest real household wall, a plastic lid, is ~ 1 mm).
    min_width: float = 0.0005  # m
    # Ray origins are moved this far along the ray so the source face itself is not hit; far
    # above float64 noise at metre scale, far below any feature the pads can feel.
    ray_offset: float = 1e-6  # m
    # Surface points drawn per wanted antipodal candidate in one round. Measured on primitives
    # (box, sphere, cylinder, torus, thin-walled tube) 90-100 % pass; 3x leaves room for shapes
    # where most points have no opposite wall within the stroke before a second round is needed.
    oversample: int = 3
    # Rounds of drawing (each doubling the draw) before scarce pairs are topped up with the
    # less selective kind; bounds the time spent on objects that have few or no pairs.
    max_rounds: int = 3


@dataclass(frozen=True)
class ProtocolConfig:
    """The grasp trial: collision check, close, lift, shake (annotator/trial.py)."""

    # Kinematic collision check: any gripper-object distance below this (m) is a collision.
    # 0 means touching counts; the sampler leaves pregrasp_clearance on each side of the pads.
    collision_margin: float = 0.0
    pregrasp_clearance: float = 0.01  # m per side: the gripper opens to width + 2 x this
    approach_distance: float = 0.10  # m, straight-line approach checked behind the grasp pose
    approach_step: float = 0.01  # m, < the 11.45 mm pad thickness so no thin wall is skipped
    # The close starts with the pads this far (m per side) outside the expected chord instead of
    # at the open width: the skipped travel is through free space (checked kinematically), and
    # 3 mm leaves the closing speed reached before contact (bench/fidelity.py).
    preclose_gap: float = 0.003
    # GraspDataGen closes for 1 s; the close ends earlier as soon as the fingers stall.
    close_timeout: float = 1.0  # s
    lift_height: float = 0.10  # m, the robot issue's 10 cm lift
    lift_duration: float = 0.2  # s: 0.5 m/s average, 0.75 m/s peak (UR3 tool speed limit ~1 m/s)
    # The shake: three motions, each translating along and rotating about one gripper axis at
    # once, one 0.2 s sine period each: peak 0.03 m x (2 pi / 0.2 s)^2 = 30 m/s^2 (3 g; GraspDataGen
    # tugs at 1 g) and 0.35 rad x (2 pi / 0.2 s)^2 = 345 rad/s^2. Chosen with bench/fidelity.py
    # against the thorough reference (see AnnotatorConfig.thorough), agreement on the 393
    # simulated candidates of seed 0: six sequential 0.35 s motions at 1 g (the first default)
    # 92.6 % at 654 steps per trial, paired 0.35 s periods 92.4 %, paired 0.25 s 95.9 %, these
    # 0.2 s periods 96.2 % (270 steps; 96.7 % at 244 with preclose_gap).
    shake_amplitude: float = 0.03  # m, "a shake of a few centimetres"
    shake_angle: float = 0.35  # rad (20 deg), "tens of degrees"
    shake_duration: float = 0.6  # s, all motions
    shake_cycles: int = 1  # sine periods per motion
    shake_paired: bool = True  # translate along and rotate about each axis at once (3 motions, not 6)
    settle_time: float = 0.05  # s held still after the shake before judging
    # Held = both pads touch and the object moved less than this in the hand (m); ACRONYM and
    # GraspDataGen judge contact only, the slip bound catches an object hanging by one edge.
    max_slip: float = 0.02
    lost_distance: float = 0.03  # m: early exit once the object is this far from its grasp
    check_every: int = 6  # steps between loss checks during lift and shake (25 ms)


@dataclass(frozen=True)
class RobustConfig:
    """Perturbations of the K - 1 extra trials of ``--trials K`` (trial 0 is unperturbed).

    Dex-Net 2.0's robust metric samples the gripper pose with sigma 5 mm and friction with sigma
    0.1; ours models a calibrated UR3 (repeatability +-0.1 mm [UR datasheet]) seen by a depth
    camera, whose object pose error is a few millimetres and degrees.
    """

    position_sigma: float = 0.002  # m, TCP position noise (Gaussian, per axis)
    rotation_sigma: float = 0.035  # rad (2 deg), TCP rotation noise (Gaussian rotation vector)
    friction_delta: float = 0.2  # object friction coefficient + uniform(-0.2, 0.2)
    mass_delta: float = 0.3  # object mass x uniform(0.7, 1.3)


@dataclass(frozen=True)
class AnnotatorConfig:
    """All sections together; the single configuration object the runner passes to workers."""

    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    gripper: GripperConfig = field(default_factory=GripperConfig)
    objects: ObjectConfig = field(default_factory=ObjectConfig)
    sampler: SamplerConfig = field(default_factory=SamplerConfig)
    protocol: ProtocolConfig = field(default_factory=ProtocolConfig)
    robust: RobustConfig = field(default_factory=RobustConfig)

    @classmethod
    def thorough(cls, base: AnnotatorConfig | None = None) -> AnnotatorConfig:
        """The reference protocol that ``bench/fidelity.py`` checks the default against.

        Time step 1/1000 s, twice the solver iterations, and a long shake: six sequential
        motions (translations along x, y, z, then rotations about them), each three 0.35 s sine
        periods at 4.5 cm and 30 deg (1.5 g): 6.3 s, over ten times the default's 0.6 s, at 1.5x its
        amplitudes. Fixed values, so that tuning the default cannot move the reference.
        """
        base = base or cls()
        return dataclasses.replace(
            base,
            physics=dataclasses.replace(
                base.physics, time_step=1.0 / 1000.0, solver_iterations=2 * base.physics.solver_iterations
            ),
            protocol=dataclasses.replace(
                base.protocol,
                shake_paired=False,
                shake_duration=6.3,
                shake_cycles=3,
                shake_amplitude=0.045,
                shake_angle=0.525,
            ),
        )

    def to_dict(self) -> dict[str, dict[str, Any]]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, dict[str, Any]]) -> AnnotatorConfig:
        """Build from ``{section: {field: value}}``; unknown sections or fields are errors."""
        sections = {f.name: f.type for f in dataclasses.fields(cls)}
        kwargs: dict[str, Any] = {}
        defaults = cls()
        for name, values in data.items():
            if name not in sections:
                raise ValueError(f"unknown config section [{name}]; known: {sorted(sections)}")
            current = getattr(defaults, name)
            known = {f.name for f in dataclasses.fields(current)}
            unknown = set(values) - known
            if unknown:
                raise ValueError(f"unknown field(s) {sorted(unknown)} in [{name}]")
            kwargs[name] = dataclasses.replace(current, **values)
        return cls(**kwargs)

    @classmethod
    def from_toml(cls, path: str | Path) -> AnnotatorConfig:
        with open(path, "rb") as fh:
            return cls.from_dict(tomllib.load(fh))
