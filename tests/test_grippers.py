"""Every shipped gripper really grips: pads on the FK table, coupling under squeeze, holds a box
through the shake, widths are chords, nothing wider than the stroke succeeds, labels on a concave
object do not depend on the workers. Real PyBullet throughout, parametrized over the grippers."""

from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path

import joblib
import numpy as np
import pandas as pd
import pybullet as pb
import pytest
import trimesh
from conftest import make_box

from annotator.cell.mount import mounted_urdf
from annotator.config import AnnotatorConfig, GripperConfig, PhysicsConfig
from annotator.geometry import Transform
from annotator.grippers import DescriptionError, gripper_dir, load_gripper, shipped_grippers
from annotator.objects import ObjectSource, discover_objects
from annotator.pipeline.tasks import GivenGrasps, Span, SpanTask
from annotator.pipeline.worker import _State, label_span
from annotator.sampler import _first_hits, object_rng, sample_candidates
from annotator.sim import ur3
from annotator.sim.body import Body
from annotator.sim.gripper import ParallelGripper
from annotator.sim.hand import FloatingGripper, ShakeMotion, max_width
from annotator.sim.world import World

# Every shipped gripper: a new one is tested as these are (and needs its generator in GENERATORS).
GRIPPERS = tuple(sorted(shipped_grippers()))
DOWN = np.array([1.0, 0.0, 0.0, 0.0])  # TCP +z pointing down (-z world): a top grasp
CONFIG = AnnotatorConfig()
SAMPLES = Path(__file__).resolve().parents[1] / "objects"
# The generator of each shipped model and the function that returns its URDF text.
GENERATORS = {
    "rg2": ("make_rg2.py", "floating_urdf"),
    "panda": ("make_panda.py", "urdf"),
    "robotiq_2f85": ("make_robotiq_2f85.py", "urdf"),
}
# Follower error bound under a squeeze and the shake: rad for a linkage, m for sliding fingers
# (1 deg on a ~55 mm link moves a pad ~1 mm; the Panda's fingers stray 0.65 mm under 70 N and
# 1.1 mm in the shake). The whole Robotiq linkage (its five gears solved with the arm worlds' 150
# iterations) strays up to 1.9 deg at 40 N: docs/grippers.md.
FOLLOWER_BOUND = {
    ("revolute", "kinematic"): np.radians(1.0),
    ("revolute", "simulated"): np.radians(1.0),
    ("prismatic", "kinematic"): 0.0015,
    ("prismatic", "simulated"): 0.0015,
}
FOLLOWER_BOUND_WHOLE_ROBOTIQ = np.radians(2.5)


def world_for(passive: str) -> World:
    """The annotation worlds' iterations for kinematic passive links, the arm's otherwise."""
    physics = PhysicsConfig()
    return World(physics if passive == "kinematic" else physics.whole_linkage())


def grasp_box(hand: FloatingGripper, box: int, size: float) -> None:
    """Place the open gripper around ``box`` from above and close it with its grip force, gravity off."""
    T_world_tcp = Transform(
        np.asarray(pb.getBasePositionAndOrientation(box, physicsClientId=hand.client)[0]), DOWN
    )
    hand.teleport(hand.T_world_base_for_tcp(T_world_tcp, size), min(size + 0.02, hand.gripper.max_width))
    hand.world.set_gravity(False)
    hand.close(max_steps=480)


def box_pos(world: World, box: int) -> np.ndarray:
    return np.asarray(pb.getBasePositionAndOrientation(box, physicsClientId=world.client)[0])


# --- the descriptions ------------------------------------------------------------------------------


def test_the_three_grippers_are_shipped_and_rg2_is_the_default():
    assert {"rg2", "panda", "robotiq_2f85"} <= set(GRIPPERS)
    assert set(GRIPPERS) == set(GENERATORS)  # every shipped model is generated
    assert load_gripper(None).name == "rg2"


@pytest.mark.parametrize("name", GRIPPERS)
def test_description_reaches_its_stroke_and_digest_is_stable(name):
    d = load_gripper(name)
    assert d.name == name and d.folder == gripper_dir(name)
    again = load_gripper(gripper_dir(name))  # by folder: the same content, the same digest
    assert again.digest == d.digest and len(d.digest) == 64
    with World() as world:
        hand = FloatingGripper(world, GripperConfig(), d)
        table = hand.gripper.table
        assert table.max_width == pytest.approx(d.stroke_max, abs=0.0015)
        assert table.min_width == pytest.approx(d.stroke_min, abs=0.001)
        assert hand.grip_force == d.grip_force


@pytest.mark.parametrize("name", GRIPPERS)
def test_shipped_urdf_is_what_its_generator_writes(name):
    script, function = GENERATORS[name]
    spec = importlib.util.spec_from_file_location(f"make_{name}", gripper_dir(name) / script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert getattr(module, function)() == load_gripper(name).urdf.read_text()


def test_a_copied_folder_is_the_same_gripper(tmp_path):
    """A user's folder holding the same files has the same digest wherever it lies."""
    shutil.copytree(gripper_dir("panda"), tmp_path / "mine")
    assert load_gripper(tmp_path / "mine").digest == load_gripper("panda").digest
    toml = tmp_path / "mine" / "gripper.toml"
    toml.write_text(toml.read_text().replace("default = 70.0", "default = 60.0"))
    with pytest.raises(DescriptionError, match="name 'panda' is a shipped gripper's and this model is an"):
        load_gripper(tmp_path / "mine")  # another model may not write `gripper = panda` on its rows
    toml.write_text(toml.read_text().replace('name = "panda"', 'name = "my_panda"'))
    assert load_gripper(tmp_path / "mine").digest != load_gripper("panda").digest


# --- kinematics --------------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("passive", ["kinematic", "simulated"])
@pytest.mark.parametrize("name", GRIPPERS)
def test_pads_follow_the_fk_table_at_every_width(name, passive):
    """Driven through the stroke in free air (dynamic), the pads are where the model's FK table puts
    them: separation, pad-centre midpoint in the base frame, pads parallel to the base."""
    with world_for(passive) as world:
        hand = FloatingGripper(world, GripperConfig(passive_links=passive), name)
        hand.teleport(Transform([0.0, 0.0, 0.5], DOWN), 0.05)
        world.set_gravity(False)
        g = hand.gripper
        width_err, tcp_err, tilt = [], [], []
        for width in np.linspace(0.0, g.max_width, 17):
            for _ in range(120):
                g.hold_position(g.table.angle_of(width), g.grip_force)
                world.step()
            T_base_world = hand.base_pose().inverse()
            pads = [T_base_world * hand.body.link_pose(n) for n in hand.description.pad_links]
            width_err.append(abs(g.measured_width() - width))
            midpoint = (pads[0].pos + pads[1].pos) / 2
            tcp_err.append(np.linalg.norm(midpoint - g.T_base_tcp(width).pos))
            tilt.extend(np.degrees(np.arccos(np.clip(p.rotation[0, 0], -1, 1))) for p in pads)
        assert max(width_err) < 5e-4, np.round(np.array(width_err) * 1000, 2)
        assert max(tcp_err) < 5e-4, np.round(np.array(tcp_err) * 1000, 2)
        assert max(tilt) < 1.0, np.round(tilt, 2)


@pytest.mark.parametrize("name", GRIPPERS)
def test_squeeze_force_is_the_grip_force(name):
    """Stalled on a 40 mm, 100 g box, each pad presses with the commanded force (the default and half)."""
    with World() as world:
        hand = FloatingGripper(world, GripperConfig(), name)
        box = make_box(world, 0.04, 0.1)
        default = hand.grip_force
        for force in (default, max(0.5 * default, hand.description.grip_force_min)):
            grasp_box(hand, box, 0.04)
            for _ in range(60):
                hand.gripper.squeeze(force)
                world.step()
            np.testing.assert_allclose(hand.gripper.pad_normal_forces(box), force, rtol=0.1)


@pytest.mark.slow
@pytest.mark.parametrize("passive", ["kinematic", "simulated"])
@pytest.mark.parametrize("name", GRIPPERS)
def test_followers_stay_coupled_and_a_box_is_held_through_lift_and_shake(name, passive):
    """The grip force on a 200 g, 40 mm box, then the protocol's lift and shake: every coupled
    follower near its mimic target throughout, the pads squeezing the grip force, the box held
    (moved in the hand less than a centimetre)."""
    with world_for(passive) as world:
        hand = FloatingGripper(world, GripperConfig(passive_links=passive), name)
        g, force = hand.gripper, hand.grip_force
        box = make_box(world, 0.04, 0.2)
        grasp_box(hand, box, 0.04)
        errors = []
        for _ in range(120):
            g.squeeze()
            world.step()
            errors.append(g.follower_errors().max())
        forces = g.pad_normal_forces(box)
        world.set_gravity(True)
        lifted = Transform(hand.target.pos + [0.0, 0.0, 0.1], hand.target.quat)

        def watch(_: int) -> bool:
            errors.append(g.follower_errors().max())
            return False

        p = CONFIG.protocol
        hand.move(lifted, duration=p.lift_duration, force=force, on_step=watch)
        shake = ShakeMotion(p.shake_amplitude, p.shake_angle, p.shake_duration, paired=True)
        hand.shake(shake, force=force, on_step=watch)
        assert np.all(np.abs(forces - force) < 0.1 * force), forces
        bound = FOLLOWER_BOUND[(hand.description.drive_kind, passive)]
        if name == "robotiq_2f85" and passive == "simulated":
            bound = FOLLOWER_BOUND_WHOLE_ROBOTIQ
        assert max(errors) < bound, max(errors)
        in_hand = (hand.base_pose().inverse() * Transform(box_pos(world, box), [0, 0, 0, 1])).pos
        assert np.linalg.norm(in_hand - g.T_base_tcp(0.04).pos) < 0.01
        assert np.all(g.pad_normal_forces(box) > 0.5 * force)


@pytest.mark.parametrize("name", GRIPPERS)
def test_closing_on_nothing_ends_closed_without_contact(name):
    with World() as world:
        hand = FloatingGripper(world, GripperConfig(), name)
        box = make_box(world, 0.04, 0.05, pos=(0.5, 0.0, 0.1))  # far away
        hand.teleport(Transform([0, 0, 0.5], DOWN), hand.gripper.max_width)
        world.set_gravity(False)
        steps = hand.close(max_steps=480)
        assert steps < 480, "closing never finished"
        assert hand.gripper.measured_width() < 0.002
        assert not any(hand.gripper.pad_contacts(box))


# --- labels through the worker: chords, impossible grasps, determinism -----------------------------


def _source(tmp_path: Path, name: str, mesh: trimesh.Trimesh) -> ObjectSource:
    path = tmp_path / f"{name}.obj"
    mesh.export(path)
    return ObjectSource(name, path)


def _label(source: ObjectSource, mesh, gripper: str, n: int, workers: int = 1) -> tuple[pd.DataFrame, object]:
    """Labels of the object's first ``n`` candidates sampled for ``gripper``'s stroke, in spans of 10."""
    stroke = max_width(CONFIG, gripper)
    c = sample_candidates(mesh, n, object_rng(0, source.object_id), CONFIG.sampler, stroke)
    tasks = []
    for a in range(0, n, 10):
        b = min(n, a + 10)
        given = GivenGrasps(c.T_obj_tcp[a:b], c.width_expected[a:b])
        span = Span(source.object_id, source, None, a, b, given)
        tasks.append(SpanTask(span=span, config=CONFIG, seed=0, n=b - a, gripper=load_gripper(gripper)))
    out = joblib.Parallel(n_jobs=workers)(joblib.delayed(label_span)(t) for t in tasks)
    assert all(r.error is None for r in out), [r.error for r in out]
    return pd.concat([r.rows for r in out], ignore_index=True), c


def _chord(mesh: trimesh.Trimesh, row: pd.Series) -> float | None:
    """The convex object's chord along the TCP's closing axis through the TCP (None: missed)."""
    T = Transform([row.x, row.y, row.z], [row.qx, row.qy, row.qz, row.qw])
    x_axis = T.rotation[:, 0]
    origins = np.array([T.pos - 0.2 * x_axis, T.pos + 0.2 * x_axis])
    t, _ = _first_hits(mesh.triangles, origins, np.array([x_axis, -x_axis]))
    return float(0.4 - t.sum()) if np.all(np.isfinite(t)) else None


@pytest.mark.slow
@pytest.mark.parametrize("name", GRIPPERS)
def test_successes_close_on_the_chord(tmp_path, name):
    """Every success of a 60 x 40 x 120 mm box's labels closed to the box's chord (within 3 mm)."""
    mesh = trimesh.creation.box((0.06, 0.04, 0.12))
    df, _ = _label(_source(tmp_path, "box", mesh), mesh, name, 40)
    wins = df[df["success"]]
    assert len(wins) >= 5, df["outcome"].value_counts().to_dict()
    for _, row in wins.iterrows():
        chord = _chord(mesh, row)
        assert chord is not None and abs(row.width - chord) < 0.003, (row.grasp_id, row.width, chord)


@pytest.mark.slow
@pytest.mark.parametrize("name", GRIPPERS)
def test_no_success_on_a_cube_wider_than_the_stroke(tmp_path, name):
    stroke = load_gripper(name).stroke_max
    mesh = trimesh.creation.box(np.full(3, stroke + 0.03))
    df, _ = _label(_source(tmp_path, "wide", mesh), mesh, name, 30)
    assert len(df) == 30
    assert not df["success"].any(), df["outcome"].value_counts().to_dict()


@pytest.fixture(scope="module")
def mug(tmp_path_factory) -> ObjectSource:
    folder = tmp_path_factory.mktemp("mug")
    shutil.copy(SAMPLES / "mug.obj", folder)
    return discover_objects(folder)[0]


@pytest.mark.slow
@pytest.mark.parametrize("name", GRIPPERS)
def test_mug_labels_do_not_depend_on_workers_or_span_order(mug, name):
    """The concave sample mug (decomposed): the same rows from one worker in order, one worker in
    reverse order after another gripper's spans, and two worker processes."""
    n, gripper = 40, load_gripper(name)
    spans = [Span(mug.object_id, mug, None, a, a + 10) for a in range(0, n, 10)]

    def run(order, workers: int = 1) -> pd.DataFrame:
        tasks = [SpanTask(span=spans[i], config=CONFIG, seed=0, n=n, gripper=gripper) for i in order]
        out = joblib.Parallel(n_jobs=workers)(joblib.delayed(label_span)(t) for t in tasks)
        assert all(r.error is None for r in out), [r.error for r in out]
        return pd.concat([r.rows for r in out]).sort_values("grasp_id", ignore_index=True)

    _State.instance = None
    reference = run(range(len(spans)))
    other = "panda" if name != "panda" else "rg2"  # the worker rebuilds its world for another gripper
    label_span(SpanTask(span=spans[0], config=CONFIG, seed=0, n=n, gripper=load_gripper(other)))
    pd.testing.assert_frame_equal(run(reversed(range(len(spans)))), reference)
    pd.testing.assert_frame_equal(run(range(len(spans)), workers=2), reference)
    assert (reference["outcome"] != "collision").sum() >= 3, reference["outcome"].value_counts().to_dict()


@pytest.mark.parametrize("name", GRIPPERS)
def test_tcp_link_is_midway_between_the_closed_pads(name):
    """The description's TCP link is the pad-centre midpoint of the closed gripper, with the base's
    axes: finger 1 at -x, finger 2 at +x (+x closes from finger 1 to finger 2)."""
    d = load_gripper(name)
    with World() as world:
        body = Body.load(world.client, d.urdf, fixed_base=True)
        gripper = ParallelGripper(body, d, GripperConfig())
        gripper.reset_width(0.0)
        p1, p2 = (body.link_pose(n).pos for n in d.pad_links)
        T_world_tcp = body.link_pose(d.tcp_link)
        np.testing.assert_allclose(T_world_tcp.pos, (p1 + p2) / 2, atol=1e-4)
        np.testing.assert_allclose(T_world_tcp.rotation, body.link_pose(d.base_link).rotation, atol=1e-9)
        T_tcp_world = T_world_tcp.inverse()
        assert T_tcp_world.apply(p1)[0] < 0 < T_tcp_world.apply(p2)[0]


@pytest.mark.parametrize("mounted", [False, True], ids=["floating", "on_ur3"])
@pytest.mark.parametrize("name", GRIPPERS)
def test_model_loads_cleanly_and_survives_random_targets(name, mounted, capfd, tmp_path, monkeypatch):
    """PyBullet prints no warning loading it (alone or on the arm); one second of random drive and
    arm targets stays finite, near the base, the followers coupled."""
    monkeypatch.setenv("RG2_CACHE_DIR", str(tmp_path))
    d = load_gripper(name)
    urdf = mounted_urdf(d) if mounted else d.urdf
    with World(PhysicsConfig().whole_linkage()) as w:
        capfd.readouterr()
        body = Body.load(w.client, urdf, fixed_base=True, flags=pb.URDF_USE_SELF_COLLISION)
        printed = capfd.readouterr()
        assert "warning" not in (printed.out + printed.err).lower(), printed.out + printed.err
        gripper = ParallelGripper(body, d, GripperConfig(), urdf=urdf)
        drive = body.joints[gripper.driven]
        arm = [j for j in body.movable_joints if j.name in ur3.JOINT_NAMES]
        assert bool(arm) == mounted
        rng = np.random.default_rng(0)
        for step in range(240):
            if step % 40 == 0:
                angle = rng.uniform(drive.lower, drive.upper)
                targets = [rng.uniform(max(j.lower, -np.pi), min(j.upper, np.pi)) for j in arm]
            gripper.hold_position(angle, gripper.grip_force)
            if arm:
                body.position_control({j.name: q for j, q in zip(arm, targets, strict=True)})
            w.step()
        base = body.base_pose().pos
        for link in body.links:
            p = body.link_pose(link).pos
            assert np.all(np.isfinite(p)) and np.linalg.norm(p - base) < 2.0, link
        bound = 1.0 if d.drive_kind == "revolute" else 0.001  # deg or m
        error = gripper.follower_errors().max()
        assert (np.degrees(error) if d.drive_kind == "revolute" else error) < bound


# --- the passive links of the four-bar grippers ---------------------------------------------------

LINKAGES = tuple(n for n in GRIPPERS if load_gripper(n).drive_kind == "revolute")  # four-bars


@pytest.mark.parametrize("name", LINKAGES)
def test_annotation_gripper_couples_only_the_pad_chains(name):
    d = load_gripper(name)
    with world_for("kinematic") as world:
        g = FloatingGripper(world, GripperConfig(passive_links="kinematic"), d).gripper
        assert {g.body.joints[j].child_link for j in g.passive} == set(d.kinematic_links)
        assert len(g.coupled) == len(d.mimic) - 2 == 3 and len(g._constraints) == 3
    with world_for("simulated") as world:
        g = FloatingGripper(world, GripperConfig(passive_links="simulated"), d).gripper
        assert g.passive == () and len(g._constraints) == len(d.mimic)


@pytest.mark.parametrize("name", LINKAGES)
def test_kinematic_passive_links_are_checked_but_never_touch_while_stepping(name):
    """A probe inside a passive link's collision box: getClosestPoints (the kinematic checks)
    reports the link in both models; the contacts the world steps with include it only when the
    passive links are simulated."""
    touched = {}
    link_name = load_gripper(name).kinematic_links[0]
    for passive in ("kinematic", "simulated"):
        with world_for(passive) as world:
            hand = FloatingGripper(world, GripperConfig(passive_links=passive), name)
            hand.teleport(Transform([0.0, 0.0, 0.5], DOWN), 0.6 * hand.gripper.max_width)
            link = hand.body.links[link_name]
            # 15 mm along the link from its pivot (both linkages' link frames sit at the pivot, z
            # along the link): inside the collision box, away from its centre and its ends
            probe_pos = hand.body.link_pose(link_name).apply([0.0, 0.0, 0.015])
            probe = make_box(world, 0.003, 0.001, pos=probe_pos)
            closest = pb.getClosestPoints(hand.uid, probe, 0.0, physicsClientId=world.client)
            assert link in {p[3] for p in closest}, passive
            # the contacts the next step would solve (stepping would throw the probe out of the box)
            pb.performCollisionDetection(physicsClientId=world.client)
            touched[passive] = any(
                p[3] == link for p in pb.getContactPoints(hand.uid, probe, physicsClientId=world.client)
            )
    assert touched == {"kinematic": False, "simulated": True}


# --- pictures and exports draw and write the gripper used -------------------------------------------


@pytest.mark.parametrize("name", GRIPPERS)
def test_pictures_draw_the_gripper_used(name):
    """The renderer loads the named gripper, poses its pads at the label's width around the TCP and
    draws it (its body is in the picture)."""
    from annotator.tools.show import GraspRenderer, grasp_cameras

    mesh = trimesh.creation.box((0.03, 0.03, 0.03))
    T_obj_tcp = Transform([0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0])
    with GraspRenderer(mesh, description=name) as renderer:
        assert renderer.description.name == name
        renderer.pose_gripper(T_obj_tcp, 0.03)
        pads = [renderer.body.link_pose(n).pos for n in renderer.description.pad_links]
        gap = abs(float(np.dot(pads[1] - pads[0], T_obj_tcp.rotation[:, 0]))) - renderer.gripper.pad_thickness
        assert gap == pytest.approx(0.03, abs=1e-6)
        np.testing.assert_allclose((pads[0] + pads[1]) / 2, T_obj_tcp.pos, atol=1e-6)
        frame = renderer.render(grasp_cameras(T_obj_tcp, mesh, 120)[0])
        assert (frame.segmentation == renderer.body.uid).sum() > 100


@pytest.mark.parametrize("name", GRIPPERS)
def test_exports_write_the_grippers_type_and_base_frame(name):
    """``T_base_tcp`` of the export is the gripper model's own, and its type and frame are written."""
    from annotator.tools.export import TcpDepth, frame_note

    d = load_gripper(name)
    depth = TcpDepth(name)
    widths = np.array([0.0, 0.5 * d.stroke_max, d.stroke_max])
    with World() as world:
        hand = FloatingGripper(world, GripperConfig(), d)
        expected = np.array([hand.gripper.T_base_tcp(w).as_matrix() for w in widths])
    np.testing.assert_allclose(depth.T_base_tcp(widths), expected)
    assert depth.description.export_type == {"rg2": "onrobot_rg2", "panda": "franka_panda"}.get(name, name)
    assert d.base_link in frame_note(d)
    if name == "panda":  # the fingers slide: the TCP stays 103.65 mm out of the mounting face
        np.testing.assert_allclose(expected[:, 2, 3], 0.10365, atol=1e-9)
