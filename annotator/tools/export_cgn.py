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
        camera_pose (4, 4): the optical frame in the scene frame

The scene frame is Contact-GraspNet's: its table is a 1.0 x 1.2 x 0.6 m box centred at the origin,
so the top is at z = 0.3; our workspace's centre on the table top is put at (0, 0, 0.3) with the
table frame's axes. Grasps are Contact-GraspNet's *positives* only (it treats every stored grasp
as one): our successes, as the flange (``rg2_base_link``) pose ``T_scene_tcp T_base_tcp(width)^-1``
(the convention of ``annotator export --format acronym``); the contacts are the pad centres at the
grasp's width, ``tcp -/+ width / 2 x_tcp`` (finger 1, finger 2). Contact-GraspNet's own
configuration assumes the Panda's 0.08 m opening (``DATA.gripper_width``); the RG2 opens to 0.11 m.
"""

from __future__ import annotations

import io
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np
import trimesh

from annotator.scenes.records import SceneRecord
from annotator.tools.export import _write_atomically
from annotator.tools.export_vgn import SceneGrasps

TABLE_TOP_Z = 0.3  # m: the top of Contact-GraspNet's table box (0.6 m tall, centred at the origin)
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
    from annotator.tools.export import _stem

    return f"meshes/{_stem(object_id)}.obj"


def write_meshes(root: Path, meshes: Mapping[str, trimesh.Trimesh]) -> dict[str, np.ndarray]:
    """Write each mesh (object id -> mesh in metres, mesh frame) to :func:`mesh_file`; return each
    file's vertex mean as Contact-GraspNet computes it (``trimesh.load`` of the written file)."""
    means = {}
    for object_id, mesh in sorted(meshes.items()):
        path = root / mesh_file(object_id)
        text = trimesh.exchange.obj.export_obj(mesh, include_normals=False, include_texture=False, digits=10)
        _write_atomically(path, lambda target, text=text: target.write_text(text))
        means[object_id] = np.mean(np.asarray(trimesh.load(path, force="mesh").vertices), axis=0)
    return means


def scene_arrays(
    record: SceneRecord,
    grasps: SceneGrasps,
    vertex_means: Mapping[str, np.ndarray],
    T_base_tcp: Callable[[np.ndarray], np.ndarray],
) -> dict[str, np.ndarray]:
    """The npz arrays of one scene (module docstring). ``T_base_tcp(width (n,))`` gives the
    gripper's (n, 4, 4) flange-to-TCP transforms (``annotator.tools.export.TcpDepth.T_base_tcp``)."""
    T_scene_table = T_cgn_table(record)
    kept = record.kept
    obj_T = []
    for inst in kept:
        centred = np.eye(4)
        centred[:3, 3] = vertex_means[inst.object_id]
        obj_T.append(T_scene_table @ inst.T_table_obj.as_matrix() @ centred)
    success = np.asarray(grasps.success, dtype=bool)
    instance = np.asarray(grasps.instance_id, dtype=np.int64)
    order = np.lexsort((np.asarray(grasps.grasp_id)[success], instance[success]))  # by object, then id
    T_tcp = T_scene_table @ np.asarray(grasps.T_table_tcp, dtype=np.float64).reshape(-1, 4, 4)[success][order]
    width = np.asarray(grasps.width, dtype=np.float64)[success][order]
    T_base = T_tcp @ np.linalg.inv(T_base_tcp(width)) if len(width) else np.zeros((0, 4, 4))
    half = (T_tcp[:, :3, 0] * (width / 2)[:, None]) if len(width) else np.zeros((0, 3))
    contacts = (
        np.stack([T_tcp[:, :3, 3] - half, T_tcp[:, :3, 3] + half], axis=1)
        if len(width)
        else np.zeros((0, 2, 3))
    )
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
    return {
        "depth": np.asarray(view.depth, dtype=np.float32),
        "K": view.depth_K.K,
        "segmap": segmap,
        "camera_pose": T_cgn_table(record) @ view.T_table_camera.as_matrix(),
    }


def _npz_bytes(arrays: dict[str, np.ndarray], compressed: bool = False) -> bytes:
    buffer = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buffer, **arrays)
    return buffer.getvalue()


def write_cgn(
    root: Path | str,
    scenes: list[tuple[SceneRecord, list, SceneGrasps]],
    meshes: Mapping[str, trimesh.Trimesh],
    T_base_tcp: Callable[[np.ndarray], np.ndarray],
) -> list[Path]:
    """Write the meshes, one ``scene_contacts`` file per scene and (for scenes given with views)
    ``views/NNNNNN_VV.npz``. ``scenes``: (record, its views or [], its grasps). Returns the paths."""
    root = Path(root)
    used = {inst.object_id for record, _, _ in scenes for inst in record.kept}
    missing = sorted(used - set(meshes))
    if missing:
        raise KeyError(f"no mesh given for {missing}")
    means = write_meshes(root, {oid: meshes[oid] for oid in used})
    paths = [root / mesh_file(oid) for oid in sorted(used)]
    for record, views, grasps in sorted(scenes, key=lambda s: s[0].scene_id):
        if grasps.scene_id != record.scene_id:
            raise ValueError(f"grasps of scene {grasps.scene_id} given with scene {record.scene_id}")
        path = root / "scene_contacts" / scene_file(record.scene_id)
        data = _npz_bytes(scene_arrays(record, grasps, means, T_base_tcp))
        _write_atomically(path, lambda target, data=data: target.write_bytes(data))
        paths.append(path)
        for view in views:
            vpath = root / "views" / f"{int(record.scene_id):06d}_{view.view_id:02d}.npz"
            vdata = _npz_bytes(view_arrays(record, view), compressed=True)
            _write_atomically(vpath, lambda target, vdata=vdata: target.write_bytes(vdata))
            paths.append(vpath)
    return paths


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
