"""Generate the sample household objects in this folder (metres, deterministic, no randomness).

Run from anywhere: ``python objects/make_objects.py``. Needs trimesh + numpy, and manifold3d (a
dependency of the annotator) for the one boolean union (the mug's handle). Every object stands on
z = 0 with its axis of symmetry (if any) along +z.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

HERE = Path(__file__).resolve().parent
SECTIONS = 48  # facets around revolved shapes: ~ 4 mm chord on a 66 mm can, smooth enough to grasp


def _closed(mesh: trimesh.Trimesh, name: str) -> trimesh.Trimesh:
    """Check a generated mesh is a valid closed solid with outward normals."""
    mesh.merge_vertices()
    mesh.remove_unreferenced_vertices()
    if mesh.volume < 0:
        mesh.invert()
    assert mesh.is_watertight, f"{name} is not watertight"
    assert mesh.is_winding_consistent, f"{name} has inconsistent winding"
    assert mesh.volume > 0, f"{name} has no volume"
    return mesh


def _revolve(profile_rz: list[tuple[float, float]], name: str) -> trimesh.Trimesh:
    """Solid of revolution about +z of a closed (r, z) profile that starts and ends on the axis."""
    mesh = trimesh.creation.revolve(np.asarray(profile_rz, dtype=np.float64), sections=SECTIONS)
    return _closed(mesh, name)


def box() -> trimesh.Trimesh:
    """A cereal-box-like cuboid, 60 x 40 x 120 mm."""
    m = trimesh.creation.box(extents=(0.060, 0.040, 0.120))
    m.apply_translation((0, 0, 0.060))
    return _closed(m, "box")


def can() -> trimesh.Trimesh:
    """A 330 ml drinks can, 66 mm diameter x 115 mm."""
    m = trimesh.creation.cylinder(radius=0.033, height=0.115, sections=SECTIONS)
    m.apply_translation((0, 0, 0.0575))
    return _closed(m, "can")


def bottle() -> trimesh.Trimesh:
    """A 0.5 l bottle, 68 mm body, shoulder, 26 mm neck and a 30 mm cap, 245 mm tall (solid)."""
    shoulder = [
        (0.034 - 0.021 * (1 - np.cos(t)) / 2, 0.160 + 0.040 * t / np.pi) for t in np.linspace(0, np.pi, 9)
    ]
    profile = [(0.0, 0.0), (0.031, 0.0), (0.034, 0.003), *shoulder]
    profile += [(0.013, 0.225), (0.015, 0.225), (0.015, 0.245), (0.0, 0.245)]
    return _revolve(profile, "bottle")


def mug() -> trimesh.Trimesh:
    """A mug: 82 mm outer diameter x 95 mm, 4 mm wall, 6 mm base, torus-segment handle (hollow, concave)."""
    r_out, r_in, height, base = 0.041, 0.037, 0.095, 0.006
    shell = _revolve(
        [(0, 0), (r_out, 0), (r_out, height), (r_in, height), (r_in, base), (0, base)], "mug shell"
    )
    # Handle: a torus (ring radius 28 mm, tube radius 6 mm) in the xz plane, its inner part cut away
    # by a cylinder inside the wall so nothing protrudes into the cup; unioned with the shell.
    handle = trimesh.creation.torus(
        major_radius=0.028, minor_radius=0.006, major_sections=40, minor_sections=12
    )
    handle.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (1, 0, 0)))
    handle.apply_translation((r_out + 0.012, 0, 0.052))
    core = trimesh.creation.cylinder(radius=r_out - 0.002, height=height, sections=SECTIONS)
    core.apply_translation((0, 0, height / 2))
    handle = handle.difference(core, engine="manifold")
    return _closed(shell.union(handle, engine="manifold"), "mug")


def bowl() -> trimesh.Trimesh:
    """A cereal bowl: 130 mm rim diameter, 70 mm foot, 60 mm tall, 4 mm wall (hollow, concave)."""
    zs = np.linspace(0.0, 0.060, 13)
    outer = [(0.035 + 0.030 * np.sin(np.pi / 2 * z / 0.060), z) for z in zs]
    inner = [(r - 0.004, max(z, 0.005)) for r, z in outer[::-1]]
    profile = [(0.0, 0.0), *outer, *inner[:-1], (inner[-1][0], 0.005), (0.0, 0.005)]
    return _revolve(profile, "bowl")


def banana() -> trimesh.Trimesh:
    """A banana-like curved bar: a tapered tube on an 80 degree arc of 120 mm radius (~ 170 mm long)."""
    n_along, n_around, arc_r = 40, 16, 0.120
    t = np.linspace(0.0, 1.0, n_along)
    phi = np.deg2rad(-40.0 + 80.0 * t)
    centre = np.stack([arc_r * np.sin(phi), np.zeros_like(phi), arc_r * (1 - np.cos(phi))], axis=1)
    tangent = np.stack([np.cos(phi), np.zeros_like(phi), np.sin(phi)], axis=1)
    normal = np.cross(tangent, (0.0, 1.0, 0.0))  # in the arc's plane, towards the arc centre
    radius = 0.004 + 0.015 * np.sin(np.pi * t) ** 0.6  # 19 mm thick in the middle, 4 mm stalk ends
    a = np.linspace(0.0, 2 * np.pi, n_around, endpoint=False)
    ring = np.cos(a)[None, :, None] * normal[:, None, :] + np.sin(a)[None, :, None] * np.array(
        [0.0, 1.0, 0.0]
    )
    verts = centre[:, None, :] + radius[:, None, None] * ring
    verts = np.vstack([verts.reshape(-1, 3), centre[0], centre[-1]])
    faces = []
    for i in range(n_along - 1):
        for j in range(n_around):
            a0, a1 = i * n_around + j, i * n_around + (j + 1) % n_around
            b0, b1 = a0 + n_around, a1 + n_around
            faces += [(a0, a1, b1), (a0, b1, b0)]
    start, end = len(verts) - 2, len(verts) - 1
    last = (n_along - 1) * n_around
    for j in range(n_around):
        faces.append((start, (j + 1) % n_around, j))
        faces.append((end, last + j, last + (j + 1) % n_around))
    m = trimesh.Trimesh(verts, np.asarray(faces), process=True)
    m.fix_normals()
    m.apply_translation((0, 0, -m.bounds[0, 2]))
    return _closed(m, "banana")


def ring() -> trimesh.Trimesh:
    """A ring (torus), 88 mm outer diameter, 18 mm thick tube, lying flat."""
    m = trimesh.creation.torus(major_radius=0.035, minor_radius=0.009, major_sections=48, minor_sections=16)
    m.apply_translation((0, 0, 0.009))
    return _closed(m, "ring")


def plate() -> trimesh.Trimesh:
    """A thin rectangular plate (a tile or a chopping board offcut), 120 x 80 x 8 mm."""
    m = trimesh.creation.box(extents=(0.120, 0.080, 0.008))
    m.apply_translation((0, 0, 0.004))
    return _closed(m, "plate")


def big_ball() -> trimesh.Trimesh:
    """A 160 mm ball: wider than the RG2's 110 mm stroke in every direction (only negatives)."""
    m = trimesh.creation.icosphere(subdivisions=3, radius=0.080)
    m.apply_translation((0, 0, 0.080))
    return _closed(m, "big_ball")


SHAMPOO_URDF = """<?xml version="1.0"?>
<!-- A shampoo bottle the way pybullet_data ships objects: meshes authored in centimetres beside
     the URDF, a finer visual and a coarser collision mesh, and a mesh scale to metres. -->
<robot name="shampoo">
  <link name="base_link">
    <inertial>
      <origin rpy="0 0 0" xyz="0 0 0.09"/>
      <mass value="0.3"/>
      <inertia ixx="0.0009" ixy="0" ixz="0" iyy="0.0008" iyz="0" izz="0.0001"/>
    </inertial>
    <visual>
      <origin rpy="0 0 0" xyz="0 0 0"/>
      <geometry>
        <mesh filename="shampoo.obj" scale="0.01 0.01 0.01"/>
      </geometry>
    </visual>
    <collision>
      <origin rpy="0 0 0" xyz="0 0 0"/>
      <geometry>
        <mesh filename="shampoo_collision.obj" scale="0.01 0.01 0.01"/>
      </geometry>
    </collision>
  </link>
</robot>
"""


def shampoo_cm(sections: int) -> trimesh.Trimesh:
    """A shampoo bottle in CENTIMETRES: 6 x 3.6 cm elliptic capsule, 18 cm tall."""
    m = trimesh.creation.capsule(height=12.0, radius=3.0, count=(sections, sections))
    m.apply_scale((1.0, 0.6, 1.0))
    m.apply_translation((0, 0, 9.0))
    return _closed(m, "shampoo")


def _write(mesh: trimesh.Trimesh, rel: str) -> None:
    path = HERE / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".obj":
        data = trimesh.exchange.obj.export_obj(mesh, include_normals=False, include_texture=False)
        path.write_text(data)
    else:
        mesh.export(path)
    ext = mesh.extents * (10.0 if "urdf/" in rel else 1000.0)  # the URDF's meshes are in cm
    print(f"{rel:32s} {len(mesh.faces):5d} faces  {ext[0]:.0f} x {ext[1]:.0f} x {ext[2]:.0f} mm")


def main() -> None:
    _write(box(), "box.obj")
    _write(can(), "can.stl")
    _write(bottle(), "bottle.ply")
    _write(mug(), "mug.obj")
    _write(bowl(), "bowl.obj")
    _write(banana(), "banana.obj")
    _write(ring(), "ring.off")
    _write(plate(), "plate.obj")
    _write(big_ball(), "big_ball.obj")
    _write(shampoo_cm(16), "urdf/shampoo/shampoo.obj")
    _write(shampoo_cm(8), "urdf/shampoo/shampoo_collision.obj")
    (HERE / "urdf/shampoo/shampoo.urdf").write_text(SHAMPOO_URDF)


if __name__ == "__main__":
    main()
