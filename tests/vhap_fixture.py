"""Capture folders written the way VHAP writes them, by code of our own (not our writer).

Follows the public code of VHAP's ``vhap/export_as_nerf_dataset.py`` (frame fields,
``transforms*.json``, ``flame_param/*.npz``, the camera relocation by the mean FLAME
translation, ``split_json`` with camera 8 or the last one held out and an empty val split for
one camera) and ``vhap/combine_nerf_datasets.py`` (``../SEQUENCE/...`` paths, accumulated
timestep indices, dropped ``timestep_id``/``timestep_index_original``, the last sequence as
the test split). Cameras: OpenGL camera-to-world and ``cy = H - cy_opencv`` (VHAP's
``convert_camera_convention('opencv->opengl')``).

The head is :func:`synthetic_flame_topology`: a **synthetic** model of FLAME's size (5023
vertices, 300 + 100 components, FLAME's joints) whose lip-ring vertices sit where VHAP's
teeth construction expects a mouth. It is not FLAME and holds no FLAME data. Images and
masks are drawn by the small rasterizer here, independent of the project's renderers.
"""

from __future__ import annotations

import json
import math
import pathlib
import shutil

import numpy as np
from PIL import Image

from mogaface.core.flame.teeth import LIP_RING_LOWER, LIP_RING_UPPER

N_VERTICES, N_SHAPE, N_EXPR = 5023, 300, 100


# -- a synthetic model of FLAME's size ----------------------------------------------------------
def synthetic_flame_topology(seed: int = 0) -> dict:
    """A FLAME-format model dict (SYNTHETIC: an ellipsoid head, random bases), 5023 vertices."""
    rng = np.random.default_rng(seed)
    lips = set(LIP_RING_UPPER) | set(LIP_RING_LOWER)
    free = [v for v in range(N_VERTICES) if v not in lips]
    rows, cols = 70, 71
    grid = np.array(free[: rows * cols]).reshape(rows, cols)
    theta = np.linspace(0.15, math.pi - 0.15, rows)[:, None]  # from the top down
    phi = np.linspace(0, 2 * math.pi, cols, endpoint=False)[None, :]
    v = np.zeros((N_VERTICES, 3))
    v[grid, 0] = 0.075 * np.sin(theta) * np.sin(phi)
    v[grid, 1] = 0.10 * np.cos(theta)
    v[grid, 2] = 0.09 * np.sin(theta) * np.cos(phi)
    spare = free[rows * cols:]
    v[spare] = rng.normal(scale=0.01, size=(len(spare), 3))  # unreferenced, inside the head
    xs = np.linspace(0.025, -0.025, 15)
    v[list(LIP_RING_UPPER)] = np.stack([xs, np.full(15, -0.040), 0.085 - 8 * xs**2], 1)
    v[list(LIP_RING_LOWER)] = np.stack([xs, np.full(15, -0.052), 0.084 - 8 * xs**2], 1)
    faces = []
    for r in range(rows - 1):
        for c in range(cols):
            a, b = grid[r, c], grid[r, (c + 1) % cols]
            d, e = grid[r + 1, c], grid[r + 1, (c + 1) % cols]
            faces += [[a, d, b], [b, d, e]]
    weights = np.zeros((N_VERTICES, 5))
    weights[:, 1] = 1.0
    jaw = (v[:, 1] < -0.045) & (v[:, 2] > 0.02)
    weights[jaw] = [0, 0, 1, 0, 0]
    regressor = np.zeros((5, N_VERTICES))
    regressor[:, grid.ravel()] = 1.0 / grid.size
    return {
        "v_template": v,
        "f": np.array(faces, np.int64),
        "shapedirs": rng.normal(scale=2e-4, size=(N_VERTICES, 3, N_SHAPE + N_EXPR)),
        "posedirs": np.zeros((N_VERTICES, 3, 36)),
        "J_regressor": regressor,
        "weights": weights,
        "kintree_table": np.array([[4294967295, 0, 1, 1, 1], [0, 1, 2, 3, 4]], np.int64),
        "n_shape": np.int64(N_SHAPE),
        "note": np.array("SYNTHETIC test model of FLAME's size; not FLAME"),
    }


# -- cameras ------------------------------------------------------------------------------------
def look_at_w2c(eye, target=(0.0, 0.0, 0.0)) -> np.ndarray:
    """OpenCV world-to-camera looking from ``eye`` at ``target`` (world y up)."""
    eye = np.asarray(eye, float)
    z = np.asarray(target, float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    w2c = np.eye(4)
    w2c[:3, :3] = np.stack([x, y, z])
    w2c[:3, 3] = -w2c[:3, :3] @ eye
    return w2c


def rig(n_cameras: int, size: int, cx_shift: float = 1.3, cy_shift: float = 3.0) -> list[dict]:
    """OpenCV cameras around the front: ``id``, ``K`` (principal point off-centre), ``w2c``."""
    out = []
    for i in range(n_cameras):
        angle = 0.0 if n_cameras == 1 else np.radians(-40 + 80 * i / (n_cameras - 1))
        eye = 0.6 * np.array([np.sin(angle), 0.05, np.cos(angle)])
        K = np.array([[1.8 * size, 0, size / 2 + cx_shift], [0, 1.8 * size, size / 2 + cy_shift], [0, 0, 1.0]])
        out.append({"id": str(220700191 + 1013 * i), "K": K, "w2c": look_at_w2c(eye)})
    return out


def opencv_to_vhap(camera: dict, size: int):
    """VHAP's ``opencv->opengl`` conversion: GL camera-to-world and ``cy`` from the bottom."""
    c2w = np.linalg.inv(camera["w2c"])
    c2w[:3, [1, 2]] *= -1
    K = camera["K"].copy()
    K[1, 2] = size - K[1, 2]
    return c2w, K


# -- a rasterizer of our own for images and masks -----------------------------------------------
def project(vertices: np.ndarray, camera: dict) -> tuple[np.ndarray, np.ndarray]:
    cam = vertices @ camera["w2c"][:3, :3].T + camera["w2c"][:3, 3]
    uv = cam[:, :2] / cam[:, 2:] * np.diag(camera["K"])[:2] + camera["K"][:2, 2]
    return uv, cam[:, 2]


def rasterize(vertices, faces, camera, size) -> tuple[np.ndarray, np.ndarray]:
    """``(mask (H,W) bool, face id (H,W), -1 outside)``: pixel centres inside each triangle's box,
    nearest triangle wins."""
    uv, depth = project(vertices, camera)
    tri_uv = uv[faces]  # (F,3,2)
    lo = np.ceil(tri_uv.min(1) - 0.5).astype(int)
    hi = np.floor(tri_uv.max(1) - 0.5).astype(int)
    span = np.clip(hi - lo + 1, 0, size).max(0)
    a, b, c = tri_uv[:, 0], tri_uv[:, 1], tri_uv[:, 2]
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    hits_face, hits_pixel, hits_z = [], [], []
    for dy in range(span[1]):
        for dx in range(span[0]):
            x, y = lo[:, 0] + dx, lo[:, 1] + dy
            ok = (x <= hi[:, 0]) & (y <= hi[:, 1]) & (x >= 0) & (y >= 0) & (x < size) & (y < size)
            ok &= np.abs(area) > 1e-12
            p = np.stack([x + 0.5, y + 0.5], 1)

            def edge(s, t):
                return (t[:, 0] - s[:, 0]) * (p[:, 1] - s[:, 1]) - (t[:, 1] - s[:, 1]) * (p[:, 0] - s[:, 0])

            with np.errstate(divide="ignore", invalid="ignore"):
                w = np.stack([edge(b, c), edge(c, a), edge(a, b)], 1) / area[:, None]
            ok &= (w >= 0).all(1)
            f = np.flatnonzero(ok)
            hits_face.append(f)
            hits_pixel.append(y[f] * size + x[f])
            hits_z.append((w[f] * depth[faces[f]]).sum(1))
    face, pixel, z = (np.concatenate(h) for h in (hits_face, hits_pixel, hits_z))
    order = np.lexsort((z, pixel))  # by pixel, nearest first
    first = np.ones(len(order), bool)
    first[1:] = pixel[order][1:] != pixel[order][:-1]
    face_id = np.full(size * size, -1)
    face_id[pixel[order][first]] = face[order][first]
    return (face_id >= 0).reshape(size, size), face_id.reshape(size, size)


def draw(vertices, faces, camera, size) -> tuple[np.ndarray, np.ndarray]:
    """A white-background uint8 image shaded by face orientation, and its uint8 mask."""
    mask, face_id = rasterize(vertices, faces, camera, size)
    tri = vertices[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True) + 1e-12
    colour = (0.5 + 0.45 * normal) * np.array([0.9, 0.7, 0.6])
    rgb = np.ones((size, size, 3))
    rgb[mask] = colour[face_id[mask]]
    return (rgb * 255).round().astype(np.uint8), (mask * 255).astype(np.uint8)


# -- VHAP's exporter ----------------------------------------------------------------------------
def tracking(model, n_timesteps: int, seed: int, translation, *, teeth=True, dynamic=False) -> dict:
    """A ``tracked_flame_params`` dict as VHAP's tracker saves it: ``(T, n)`` arrays, shape ``(300,)``."""
    rng = np.random.default_rng(seed)
    n_v = N_VERTICES + (120 if teeth else 0)
    out = {
        "shape": rng.normal(scale=0.5, size=N_SHAPE).astype(np.float32),
        "expr": rng.normal(scale=0.5, size=(n_timesteps, N_EXPR)).astype(np.float32),
        "rotation": rng.normal(scale=0.03, size=(n_timesteps, 3)).astype(np.float32),
        "neck_pose": rng.normal(scale=0.02, size=(n_timesteps, 3)).astype(np.float32),
        "jaw_pose": np.abs(rng.normal(scale=0.1, size=(n_timesteps, 3))).astype(np.float32) * [1, 0, 0],
        "eyes_pose": rng.normal(scale=0.05, size=(n_timesteps, 6)).astype(np.float32),
        "translation": (np.asarray(translation) + rng.normal(scale=0.004, size=(n_timesteps, 3))).astype(np.float32),
        "static_offset": rng.normal(scale=0.001, size=(1, n_v, 3)).astype(np.float32),
    }
    if dynamic:
        out["dynamic_offset"] = rng.normal(scale=0.002, size=(n_timesteps, n_v, 3)).astype(np.float32)
    return out


def export_sequence(folder, flame, tracked: dict, cameras: list[dict], size: int) -> pathlib.Path:
    """Write one sequence folder as ``export_as_nerf_dataset.py`` does (param mode, masks, split).

    ``flame``: a FlameModel for the tracked vertex count, used to pose the mesh for the pixels.
    """
    import torch

    folder = pathlib.Path(folder)
    folder.mkdir(parents=True)
    n_t = len(tracked["expr"])
    with torch.no_grad():
        verts = flame(**{k: torch.as_tensor(v if k != "shape" else v[None].repeat(n_t, 0))
                         for k, v in tracked.items() if k != "static_offset"},
                      static_offset=torch.as_tensor(tracked["static_offset"])).numpy().astype(np.float64)
    faces = flame.faces.numpy()
    mean_t = tracked["translation"].astype(np.float64).mean(0)  # relocate_flame_meshes
    M = np.eye(4)
    M[:3, 3] = -mean_t
    frames = []
    for t in range(n_t):
        for c, cam in enumerate(cameras):
            rgb, alpha = draw(verts[t], faces, cam, size)
            c2w, K = opencv_to_vhap(cam, size)
            fl_x, fl_y, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
            frame = {
                "timestep_index": t, "timestep_index_original": t, "timestep_id": f"frame_{t:05d}",
                "camera_index": c, "camera_id": cam["id"],
                "cx": cx, "cy": cy, "fl_x": fl_x, "fl_y": fl_y, "h": size, "w": size,
                "camera_angle_x": math.atan(size / (fl_x * 2)) * 2,
                "camera_angle_y": math.atan(size / (fl_y * 2)) * 2,
                "transform_matrix": (M @ c2w).tolist(),
                "file_path": f"images/{t:05d}_{c:02d}.png",
                "fg_mask_path": f"fg_masks/{t:05d}_{c:02d}.png",
                "flame_param_path": f"flame_param/{t:05d}.npz",
            }
            for key, data in (("file_path", rgb), ("fg_mask_path", alpha)):
                (folder / frame[key]).parent.mkdir(exist_ok=True)
                Image.fromarray(data).save(folder / frame[key])
            frames.append(frame)
    last = frames[-1]
    db = {"frames": frames, **{k: last[k] for k in ("cx", "cy", "fl_x", "fl_y", "h", "w", "camera_angle_x",
                                                     "camera_angle_y")},
          "timestep_indices": list(range(n_t)), "camera_indices": list(range(len(cameras)))}
    (folder / "flame_param").mkdir()
    for t in range(n_t):
        params = {k: tracked[k][[t]] for k in ("translation", "rotation", "neck_pose", "jaw_pose", "eyes_pose", "expr")}
        params["translation"] = (params["translation"] - mean_t).astype(np.float32)
        params["shape"] = tracked["shape"]
        params["static_offset"] = tracked["static_offset"]
        if "dynamic_offset" in tracked:
            params["dynamic_offset"] = tracked["dynamic_offset"][[t]]
        np.savez(folder / f"flame_param/{t:05d}.npz", **params)
    canonical = {"translation": np.zeros((1, 3)), "rotation": np.zeros((1, 3)), "neck_pose": np.zeros((1, 3)),
                 "jaw_pose": np.array([[0.3, 0, 0]]), "eyes_pose": np.zeros((1, 6)), "shape": tracked["shape"],
                 "expr": np.zeros((1, N_EXPR)), "static_offset": tracked["static_offset"]}
    np.savez(folder / "canonical_flame_param.npz", **canonical)
    for name in ("transforms.json", "transforms_backup.json", "transforms_backup_flame.json"):
        (folder / name).write_text(json.dumps(db, indent=4))
    _split_json(folder, db)
    return folder


def _split_json(folder: pathlib.Path, db: dict, train_ratio: float = 0.7) -> None:
    """VHAP's ``split_json``: first 70 % of timesteps train/val, the rest test; val = camera 8 or the last."""
    base = {k: v for k, v in db.items() if k not in ("frames", "timestep_indices", "camera_indices")}
    train, val, test = ({**base, "frames": []} for _ in range(3))
    ts = sorted(db["timestep_indices"])
    n_train = int(np.ceil(len(ts) * train_ratio))
    train["timestep_indices"] = val["timestep_indices"] = ts[:n_train]
    test["timestep_indices"] = ts[n_train:]
    cams = db["camera_indices"]
    if len(cams) > 1:
        held = 8 if 8 in cams else cams[-1]
        train["camera_indices"], val["camera_indices"] = [i for i in cams if i != held], [held]
    else:
        train["camera_indices"], val["camera_indices"] = cams, []
    test["camera_indices"] = cams
    for f in db["frames"]:
        if f["timestep_index"] in ts[:n_train]:
            (train if f["camera_index"] in train["camera_indices"] else val)["frames"].append(f)
        else:
            test["frames"].append(f)
    for name, doc in (("train", train), ("val", val), ("test", test)):
        (folder / f"transforms_{name}.json").write_text(json.dumps(doc, indent=4))


# -- VHAP's combine_nerf_datasets.py (division mode 'last') -------------------------------------
def combine(sequences: list[pathlib.Path], target: pathlib.Path) -> pathlib.Path:
    """A union folder beside the sequences; the last sequence is the test split."""
    target.mkdir()
    count = 0

    def merged(folders):
        nonlocal count
        db = None
        for folder in folders:
            part = json.loads((folder / "transforms.json").read_text())
            part["timestep_indices"] = [t + count for t in part["timestep_indices"]]
            count += len(part["timestep_indices"])
            for frame in part["frames"]:
                frame.pop("timestep_index_original")
                frame.pop("timestep_id")
                frame["timestep_index"] = part["timestep_indices"][frame["timestep_index"]]
                for key in ("file_path", "flame_param_path", "fg_mask_path"):
                    frame[key] = f"../{folder.name}/{frame[key]}"
            if db is None:
                db = part
            else:
                db["frames"] += part["frames"]
                db["timestep_indices"] += part["timestep_indices"]
        return db

    db = merged(sequences[:-1])
    shutil.copy(sequences[0] / "canonical_flame_param.npz", target / "canonical_flame_param.npz")
    base = {k: v for k, v in db.items() if k not in ("frames", "camera_indices")}
    train, val = {**base, "frames": []}, {**base, "frames": []}
    cams = db["camera_indices"]
    held = 8 if 8 in cams else cams[-1]
    train["camera_indices"], val["camera_indices"] = [i for i in cams if i != held], [held]
    for frame in db["frames"]:
        (train if frame["camera_index"] in train["camera_indices"] else val)["frames"].append(frame)
    test = merged(sequences[-1:])
    test["timestep_indices"] = sorted(test["timestep_indices"])
    for name, doc in (("train", train), ("val", val), ("test", test)):
        (target / f"transforms_{name}.json").write_text(json.dumps(doc, indent=4))
    (target / "sequences_trainval.txt").write_text("".join(f.name + "\n" for f in sequences[:-1]))
    (target / "sequences_test.txt").write_text(sequences[-1].name + "\n")
    return target
