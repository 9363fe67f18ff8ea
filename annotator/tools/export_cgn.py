"""Scenes and their grasps in Contact-GraspNet's files (NVlabs/contact_graspnet).

The training data layout (``tools/create_table_top_scenes.py`` writes it, ``contact_graspnet/
data.py: load_scene_contacts`` reads it with ``np.load(path, allow_pickle=False)``)::

    ROOT/meshes/<object>.obj                 the object's mesh as its labels see it (metres, mesh frame)
    ROOT/scene_contacts/NNNNNN.npz           one scene (np.savez), NNNNNN = the scene id:
        obj_paths             (k,) str          mesh paths relative to ROOT
        obj_transforms        (k, 4, 4) float64 each mesh's pose in the scene, for the mesh
                                                *centred on the mean of its vertices* (as the
                                                scene renderer loads it: trimesh.load, scale,
                                                subtract the vertex mean)
        obj_scales            (k,) float64      1: the meshes are written in metres
        grasp_transforms      (N, 4, 4) float64 successful grasps, gripper base frame in the scene
        scene_contact_points  (N, 2, 3) float64 the two pad contacts of each grasp, in the scene
        obj_grasp_idcs        (k,) int64        cumulative end of each object's grasps
      and ours, which Contact-GraspNet does not read: obj_object_ids (k,) str, obj_instance_ids
      (k,), grasp_widths (N,) m, grasp_instance_ids (N,), grasp_ids (N,), gripper (str).
    ROOT/views/NNNNNN_VV.npz                 optional, Contact-GraspNet's inference input per view:
        depth (H, W) float32 m (0 = none), K (3, 3), segmap (H, W) uint8 (instance_id + 1, 0 else),
        camera_pose (4, 4): the camera in the scene frame, OpenGL's axes (below);
        camera_pose_opencv (4, 4): the optical frame (OpenCV's axes) in the scene frame

The scene frame is Contact-GraspNet's: its table is a 1.0 x 1.2 x 0.6 m box centred at the origin,
so the top is at z = 0.3; our workspace's centre on the table top is put at (0, 0, 0.3) with the
table frame's axes. Grasps are Contact-GraspNet's *positives* only (it treats every stored grasp
as one): our successes, as the flange (``rg2_base_link``) pose ``T_scene_tcp T_base_tcp(width)^-1``
(the convention of ``annotator export --format acronym``).

Contacts are where its own are (``mesh_utils.grasp_contact_location``: a ray from each finger
along the closing direction, the first hit on the object's mesh, kept within the opening): on the
target's mesh in the scene, where the pads' closing line meets it. From the TCP ``p`` and closing
axis ``x`` of the label (the end of closing) and its ``width``, a ray from ``p - r x`` along ``+x``
(finger 1) and one from ``p + r x`` along ``-x`` (finger 2), ``r = width / 2 + CONTACT_RAY_MARGIN``;
each contact is the first hit on the mesh, entering it, within ``2 r`` of its origin. A success
whose closing line does not meet its mesh so on both sides (the object held off the line, at
the pads' edges) is left out, as Contact-GraspNet leaves out grasps without two valid contacts;
the export reports how many. Contact-GraspNet's own configuration assumes the Panda's 0.08 m
opening (``DATA.gripper_width``); the RG2 opens to 0.11 m.

Cameras. ``camera_pose`` in ``views/`` is in Contact-GraspNet's convention, OpenGL's (pyrender's):
the camera looks along its -z, +y up in the image; its training turns it into OpenCV's with
``data.py: center_pc_convert_cam`` (negate the y and z columns). ``camera_pose_opencv`` is the same
camera as the optical frame (+z forward, +x right, +y down in the image: the frame of ``depth``
and ``K``, and of our own views).
"""

from __future__ import annotations

import io
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from annotator.scenes.records import SceneRecord
from annotator.tools.export import Writer, fill_bytes, fill_text, write_atomically
from annotator.tools.export_vgn import SceneGrasps

TABLE_TOP_Z = 0.3  # m: the top of Contact-GraspNet's table box (0.6 m tall, centred at the origin)
# m: the contact rays start this far outside the label's pads, so that a pad pressed into the
# object, or a mesh standing out of its collision shape (at most 2.95 mm on the shapes the object
# bench measures: docs/objects.md), still lies ahead of the ray; less than the pads' own thickness.
CONTACT_RAY_MARGIN = 0.005
T_OPENCV_OPENGL = np.diag([1.0, -1.0, -1.0, 1.0])  # a camera's OpenGL frame in its OpenCV frame
SCENE_KEYS = ("obj_paths", "obj_transforms", "obj_scales", "grasp_transforms", "scene_contact_points")
GRIPPER_TYPE = "onrobot_rg2"


def scene_file(scene_id: int) -> str:
    return f"{int(scene_id):06d}.npz"


def T_cgn_table(record: SceneRecord) -> np.ndarray:
    """(4, 4): the table frame in Contact-GraspNet's scene frame (workspace centre -> (0, 0, 0.3))."""
    T = np.eye(4)
    T[:3, 3] = [-record.workspace.center[0], -record.workspace.center[1], TABLE_TOP_Z]
    return T


def mesh_file(object_id: str) -> str:
    """Where an object's mesh goes, relative to the export root."""
    from annotator.tools.export import object_stem

    return f"meshes/{object_stem(object_id)}.obj"


def write_meshes(
    root: Path, meshes: Mapping[str, trimesh.Trimesh], write: Writer = write_atomically
) -> dict[str, np.ndarray]:
    """Write each mesh (object id -> mesh in metres, mesh frame) to :func:`mesh_file`; return each
    file's vertex mean as Contact-GraspNet computes it (``trimesh.load`` of the written file).
    ``write``: how a file is written (an export's folder's writer)."""
    means = {}
    for object_id, mesh in sorted(meshes.items()):
        path = root / mesh_file(object_id)
        text = trimesh.exchange.obj.export_obj(mesh, include_normals=False, include_texture=False, digits=10)
        write(path, fill_text(text))
        means[object_id] = np.mean(np.asarray(trimesh.load(path, force="mesh").vertices), axis=0)
    return means


def surface_contacts(
    mesh: trimesh.Trimesh, T_tcp: np.ndarray, width: np.ndarray, margin: float = CONTACT_RAY_MARGIN
) -> tuple[np.ndarray, np.ndarray]:
    """Where the pads' closing lines meet ``mesh`` (module docstring): ``T_tcp`` (n, 4, 4) TCP
    poses and ``width`` (n,) m, in the frame of ``mesh``. Returns the contacts (n, 2, 3) (finger 1,
    finger 2; NaN where none) and (n,) bool: both found."""
    T_tcp = np.asarray(T_tcp, dtype=np.float64).reshape(-1, 4, 4)
    n = len(T_tcp)
    contacts = np.full((n, 2, 3), np.nan)
    if n == 0:
        return contacts, np.zeros(0, dtype=bool)
    x, p = T_tcp[:, :3, 0], T_tcp[:, :3, 3]
    reach = np.asarray(width, dtype=np.float64) / 2 + margin
    origins = np.concatenate([p - reach[:, None] * x, p + reach[:, None] * x])
    directions = np.concatenate([x, -x])
    along, face = first_hits(np.asarray(mesh.triangles), origins, directions)
    hit = np.isfinite(along)
    entering = np.zeros(len(along), dtype=bool)
    entering[hit] = np.einsum("ij,ij->i", mesh.face_normals[face[hit]], directions[hit]) < 0
    good = entering & (along <= 2 * np.concatenate([reach, reach]))
    ray = np.flatnonzero(good)
    contacts[ray % n, ray // n] = origins[ray] + along[ray, None] * directions[ray]
    return contacts, ~np.isnan(contacts).any(axis=(1, 2))


def first_hits(
    triangles: np.ndarray, origins: np.ndarray, directions: np.ndarray, batch: int = 200_000
) -> tuple[np.ndarray, np.ndarray]:
    """The first triangle each ray meets (Moller-Trumbore, both faces): ``triangles`` (F, 3, 3),
    rays ``origins`` + t ``directions`` (R, 3) (unit directions: t in m). Returns t (R,) (inf
    where none is met) and the triangle's index (R,) (meaningless where t is inf). Rays are taken
    in groups of about ``batch`` ray-triangle pairs."""
    triangles = np.asarray(triangles, dtype=np.float64)
    v0 = triangles[:, 0]
    e1, e2 = triangles[:, 1] - v0, triangles[:, 2] - v0
    t_first = np.full(len(origins), np.inf)
    face = np.zeros(len(origins), dtype=np.int64)
    step = max(1, batch // max(1, len(triangles)))
    for start in range(0, len(origins), step):
        o = np.asarray(origins[start : start + step], dtype=np.float64)[:, None]  # (r, 1, 3)
        d = np.asarray(directions[start : start + step], dtype=np.float64)[:, None]
        pvec = np.cross(d, e2)  # (r, F, 3)
        det = np.einsum("fk,rfk->rf", e1, pvec)
        usable = np.abs(det) > 1e-12
        inv = np.where(usable, 1.0 / np.where(usable, det, 1.0), 0.0)
        tvec = o - v0
        u = np.einsum("rfk,rfk->rf", tvec, pvec) * inv
        qvec = np.cross(tvec, e1)
        v = np.einsum("rfk,rfk->rf", np.broadcast_to(d, qvec.shape), qvec) * inv
        t = np.einsum("fk,rfk->rf", e2, qvec) * inv
        ok = usable & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0)
        t = np.where(ok, t, np.inf)
        first = np.argmin(t, axis=1)
        t_first[start : start + step] = t[np.arange(len(first)), first]
        face[start : start + step] = first
    return t_first, face


def scene_arrays(
    record: SceneRecord,
    grasps: SceneGrasps,
    vertex_means: Mapping[str, np.ndarray],
    T_base_tcp: Callable[[np.ndarray], np.ndarray],
    meshes: Mapping[str, trimesh.Trimesh],
) -> dict[str, np.ndarray]:
    """The npz arrays of one scene (module docstring): its successes with both contacts on their
    mesh. ``T_base_tcp(width (n,))`` gives the gripper's (n, 4, 4) flange-to-TCP transforms
    (``annotator.tools.export.TcpDepth.T_base_tcp``); ``meshes``: object id -> mesh (mesh frame)."""
    T_scene_table = T_cgn_table(record)
    kept = record.kept
    obj_T = []
    for inst in kept:
        centred = np.eye(4)
        centred[:3, 3] = vertex_means[inst.object_id]
        obj_T.append(T_scene_table @ inst.T_table_obj.as_matrix() @ centred)
    success = np.array(grasps.success, dtype=bool)  # a copy: grasps without contacts leave it
    instance = np.asarray(grasps.instance_id, dtype=np.int64)
    T_all = T_scene_table @ np.asarray(grasps.T_table_tcp, dtype=np.float64).reshape(-1, 4, 4)
    width_all = np.asarray(grasps.width, dtype=np.float64)
    contacts_all = np.full((len(success), 2, 3), np.nan)
    for inst in kept:
        mine = np.flatnonzero(success & (instance == inst.instance_id))
        if len(mine):
            T_scene_obj = T_scene_table @ inst.T_table_obj.as_matrix()
            posed = meshes[inst.object_id].copy().apply_transform(T_scene_obj)
            contacts_all[mine], _ = surface_contacts(posed, T_all[mine], width_all[mine])
    success &= ~np.isnan(contacts_all).any(axis=(1, 2))
    order = np.lexsort((np.asarray(grasps.grasp_id)[success], instance[success]))  # by object, then id
    T_tcp = T_all[success][order]
    width = width_all[success][order]
    T_base = T_tcp @ np.linalg.inv(T_base_tcp(width)) if len(width) else np.zeros((0, 4, 4))
    contacts = contacts_all[success][order].reshape(-1, 2, 3)
    g_instance = instance[success][order]
    ends = np.array([int(np.sum(g_instance <= inst.instance_id)) for inst in kept], dtype=np.int64)
    return {
        "obj_paths": np.array([mesh_file(inst.object_id) for inst in kept], dtype=str),
        "obj_transforms": np.array(obj_T, dtype=np.float64).reshape(-1, 4, 4),
        "obj_scales": np.ones(len(kept), dtype=np.float64),
        "grasp_transforms": T_base.astype(np.float64),
        "scene_contact_points": contacts.astype(np.float64),
        "obj_grasp_idcs": ends,
        "obj_object_ids": np.array([inst.object_id for inst in kept], dtype=str),
        "obj_instance_ids": np.array([inst.instance_id for inst in kept], dtype=np.int64),
        "grasp_widths": width,
        "grasp_instance_ids": g_instance,
        "grasp_ids": np.asarray(grasps.grasp_id, dtype=np.int64)[success][order],
        "gripper": np.array(GRIPPER_TYPE),
    }


def view_arrays(record: SceneRecord, view) -> dict[str, np.ndarray]:
    """Contact-GraspNet's inference input for one :class:`annotator.scenes.views.SceneView`."""
    seg = np.asarray(view.segmentation)
    segmap = np.where((seg > 0) & (seg < 254), seg, 0).astype(np.uint8)
    T_scene_camera = T_cgn_table(record) @ view.T_table_camera.as_matrix()  # OpenCV's axes
    return {
        "depth": np.asarray(view.depth, dtype=np.float32),
        "K": view.depth_K.K,
        "segmap": segmap,
        "camera_pose": T_scene_camera @ T_OPENCV_OPENGL,
        "camera_pose_opencv": T_scene_camera,
    }


def _npz_bytes(arrays: dict[str, np.ndarray], compressed: bool = False) -> bytes:
    buffer = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buffer, **arrays)
    return buffer.getvalue()


@dataclass(frozen=True)
class CgnFiles:
    """What :func:`write_cgn` wrote: the ``paths``, the positives written and the successes left
    out for want of two contacts on their mesh (``no_contact``)."""

    paths: list[Path]
    positives: int
    no_contact: int


def write_cgn(
    root: Path | str,
    scenes: list[tuple[SceneRecord, list, SceneGrasps]],
    meshes: Mapping[str, trimesh.Trimesh],
    T_base_tcp: Callable[[np.ndarray], np.ndarray],
    write: Writer = write_atomically,
) -> CgnFiles:
    """Write the meshes, one ``scene_contacts`` file per scene and (for scenes given with views)
    ``views/NNNNNN_VV.npz``. ``scenes``: (record, its views or [], its grasps); ``write``: how a
    file is written (an export's folder's writer)."""
    root = Path(root)
    used = {inst.object_id for record, _, _ in scenes for inst in record.kept}
    missing = sorted(used - set(meshes))
    if missing:
        raise KeyError(f"no mesh given for {missing}")
    means = write_meshes(root, {oid: meshes[oid] for oid in used}, write)
    paths = [root / mesh_file(oid) for oid in sorted(used)]
    positives = no_contact = 0
    for record, views, grasps in sorted(scenes, key=lambda s: s[0].scene_id):
        if grasps.scene_id != record.scene_id:
            raise ValueError(f"grasps of scene {grasps.scene_id} given with scene {record.scene_id}")
        path = root / "scene_contacts" / scene_file(record.scene_id)
        arrays = scene_arrays(record, grasps, means, T_base_tcp, meshes)
        positives += len(arrays["grasp_ids"])
        no_contact += int(np.sum(grasps.success)) - len(arrays["grasp_ids"])
        data = _npz_bytes(arrays)
        write(path, fill_bytes(data))
        paths.append(path)
        for view in views:
            vpath = root / "views" / f"{int(record.scene_id):06d}_{view.view_id:02d}.npz"
            vdata = _npz_bytes(view_arrays(record, view), compressed=True)
            write(vpath, fill_bytes(vdata))
            paths.append(vpath)
    return CgnFiles(paths, positives, no_contact)


# --- reading back, as Contact-GraspNet does ---------------------------------------------------------


def load_scene_contacts(root: Path | str) -> list[dict[str, np.ndarray]]:
    """Every ``scene_contacts/*`` file in name order, read as ``load_scene_contacts`` does: the
    five keys it uses (SCENE_KEYS), ``np.load(..., allow_pickle=False)``."""
    out = []
    for path in sorted((Path(root) / "scene_contacts").glob("*")):
        with np.load(path, allow_pickle=False) as npz:
            out.append({key: npz[key] for key in SCENE_KEYS})
    return out


def contact_labels(info: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """What Contact-GraspNet's ``load_contact_grasps`` derives from a scene: every contact point
    (2N, 3), its direction to the other pad (2N, 3, unit), the pads' distance per contact (2N,)
    and the approach direction per contact (2N, 3) (the grasp transform's z axis)."""
    c = info["scene_contact_points"]
    d01 = c[:, 0, :] - c[:, 1, :]
    dist = np.maximum(np.linalg.norm(d01, axis=1), np.finfo(np.float32).eps)
    directions = np.empty((2 * len(c), 3))
    directions[0::2] = -d01 / dist[:, None]
    directions[1::2] = d01 / dist[:, None]
    approach = info["grasp_transforms"].reshape(-1, 4, 4)[:, :3, 2]
    return {
        "points": c.reshape(-1, 3),
        "directions": directions,
        "finger_distance": np.repeat(dist, 2),
        "approach": np.repeat(approach, 2, axis=0),
    }


def scene_meshes(root: Path | str, info: dict[str, np.ndarray]) -> list[trimesh.Trimesh]:
    """The scene's meshes posed as Contact-GraspNet's renderer poses them: ``trimesh.load``, scale,
    centre on the vertex mean, then ``obj_transforms``."""
    out = []
    for path, T, scale in zip(info["obj_paths"], info["obj_transforms"], info["obj_scales"], strict=True):
        mesh = trimesh.load(Path(root) / str(path), force="mesh")
        mesh.apply_scale(float(scale))
        mesh.vertices -= np.mean(mesh.vertices, axis=0, keepdims=True)
        out.append(mesh.apply_transform(T))
    return out
