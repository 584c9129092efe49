"""How far a tracked capture is from the truth its synthetic footage was rendered with.

``make-footage`` writes the truth aside (``truth/``: FLAME parameters and the camera of every
frame); ``track`` never reads it (``tests/test_guards.py``). Here both meet, per tracked frame:

- **mesh error** (mm): every vertex of the tracked head against the true one, both in the frame's
  camera (what the picture constrains): *raw*, and *aligned* by the similarity (rotation,
  translation, scale) that fits them best per frame, which forgives what one view cannot tell
  (how far the head is against how large, a turn along the line of sight);
- **expression-only** (mm): the expression's own displacement (the head with its expression and
  jaw, minus the same head neutral, both unposed): the face's motion, whatever the pose;
- **camera** (° and mm): the camera as the head sees it (its rotation and its centre in the
  head's frame, the camera-to-head pose of each frame), against the truth; the rotation both
  raw and after the one turn that best aligns the whole clip.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib

import numpy as np
import torch

from ..camera import Camera
from ..data import layout
from ..data.camera_file import read_cameras
from ..data.capture import Capture
from ..flame.lbs import axis_angle_to_matrix
from ..flame.model import FlameModel
from ..io.npz import load_npz


def similarity(source: np.ndarray, target: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """``(scale, rotation, offset)`` of the similarity ``x ↦ scale·rotation·x + offset`` that best
    fits ``source (N,3)`` to ``target`` (Umeyama)."""
    mu_s, mu_t = source.mean(0), target.mean(0)
    s, t = source - mu_s, target - mu_t
    u, sigma, vt = np.linalg.svd(t.T @ s / len(source))
    d = np.sign(np.linalg.det(u @ vt))
    rotation = u @ np.diag([1, 1, d]) @ vt
    scale = (sigma * [1, 1, d]).sum() / max((s ** 2).sum() / len(source), 1e-18)
    return float(scale), rotation, mu_t - scale * rotation @ mu_s


def similarity_aligned(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``source (N,3)`` moved by the similarity that best fits it to ``target``."""
    scale, rotation, offset = similarity(source, target)
    return scale * source @ rotation.T + offset


def camera_onto(camera: Camera, scale: float, rotation: np.ndarray, offset: np.ndarray) -> Camera:
    """``camera`` moved into the world of a head that ``x ↦ scale·rotation·x + offset`` carries onto
    the head ``camera`` looks at: it sees the first head as ``camera`` sees the second. The scale
    becomes the camera's distance (a picture is the same when the scene and the camera's distance
    to it scale together), as the aligned mesh error forgives what one view cannot tell."""
    w2c = np.eye(4)
    w2c[:3, :3] = camera.R @ rotation
    w2c[:3, 3] = (camera.R @ offset + camera.t) / scale
    return dataclasses.replace(camera, w2c=w2c)


def head_to_world(params: dict, joints: np.ndarray) -> np.ndarray:
    """4×4 of the head's frame (FLAME's root, turned by ``rotation`` about the root joint, moved by
    ``translation``) into the world: with a camera's ``w2c`` in front, what one picture of the head
    constrains."""
    rotation = axis_angle_to_matrix(torch.as_tensor(params["rotation"].reshape(1, 3), dtype=torch.float64))[0].numpy()
    head = np.eye(4)
    head[:3, :3] = rotation
    head[:3, 3] = joints[0] - rotation @ joints[0] + params["translation"].reshape(3)
    return head


def vertices_and_joints(model: FlameModel, params: dict, posed: bool) -> tuple[np.ndarray, np.ndarray]:
    """The head's vertices and rest joints for ``params`` (numpy); unposed: shape, expression and jaw only."""
    names = ("shape", "expr", "rotation", "neck_pose", "jaw_pose", "eyes_pose", "translation")
    given = {k: torch.as_tensor(np.asarray(params[k], np.float64).reshape(1, -1)) for k in names if k in params}
    if not posed:
        given = {k: v for k, v in given.items() if k in ("shape", "expr", "jaw_pose")}
    with torch.no_grad():
        vertices, joints = model.evaluate(**given)
    return vertices[0].numpy(), joints[0].numpy()


def _angle(rotation: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(rotation) - 1) / 2, -1, 1))))


def tracking_errors(capture_dir, truth_dir, camera_id: str | None = None) -> dict:
    """Mean errors of a tracked capture against its footage's truth (see the module's docstring);
    ``camera_id``: only that camera's frames (one clip of several tracked together, ``truth_dir``
    that clip's)."""
    capture_dir, truth_dir = pathlib.Path(capture_dir), pathlib.Path(truth_dir)
    report = json.loads((capture_dir / "tracking.json").read_text())
    capture = Capture.open(capture_dir)
    model = FlameModel.load(truth_dir / "head.pkl", dtype=torch.float64)
    fitted_model = FlameModel.load(capture_dir / report["head_model"], dtype=torch.float64)
    truth_cameras = read_cameras(truth_dir / "cameras.json")
    frames = {f.timestep_index: f for f in capture.frames() if camera_id in (None, f.camera_id)}
    if not frames:
        raise ValueError(f"{capture_dir}: no tracked frame of camera {camera_id}")
    rows = []
    for t, frame in sorted(frames.items()):
        index = report["input_frames"][t]
        truth = load_npz(truth_dir / "flame_param" / f"{index:05d}.npz")
        fitted = load_npz(capture_dir / layout.flame_param_path(t))
        true_camera, camera = truth_cameras[f"{index:05d}"], capture.camera(frame)
        true_vertices, true_joints = vertices_and_joints(model, truth, posed=True)
        fit_vertices, fit_joints = vertices_and_joints(fitted_model, fitted, posed=True)
        in_true = true_vertices @ true_camera.w2c[:3, :3].T + true_camera.w2c[:3, 3]
        in_fit = fit_vertices @ camera.w2c[:3, :3].T + camera.w2c[:3, 3]
        neutral_true = vertices_and_joints(model, {**truth, "expr": 0 * truth["expr"], "jaw_pose": 0 * truth["jaw_pose"]},
                                 posed=False)[0]
        neutral_fit = vertices_and_joints(fitted_model, {**fitted, "expr": 0 * fitted["expr"],
                                               "jaw_pose": 0 * fitted["jaw_pose"]}, posed=False)[0]
        expression_true = vertices_and_joints(model, truth, posed=False)[0] - neutral_true
        expression_fit = vertices_and_joints(fitted_model, fitted, posed=False)[0] - neutral_fit
        true_pose = true_camera.w2c @ head_to_world(truth, true_joints)
        fit_pose = camera.w2c @ head_to_world(fitted, fit_joints)
        true_centre = np.linalg.inv(true_pose)[:3, 3]  # the camera's centre in the head's frame
        fit_centre = np.linalg.inv(fit_pose)[:3, 3]
        rows.append({
            "mesh_mm": 1000 * np.linalg.norm(in_fit - in_true, axis=1).mean(),
            "mesh_aligned_mm": 1000 * np.linalg.norm(similarity_aligned(in_fit, in_true) - in_true, axis=1).mean(),
            "expression_mm": 1000 * np.linalg.norm(expression_fit - expression_true, axis=1).mean(),
            "rotation": fit_pose[:3, :3].T @ true_pose[:3, :3],
            "centre_mm": 1000 * np.linalg.norm(fit_centre - true_centre),
        })
    turns = np.stack([row["rotation"] for row in rows])
    u, _, vt = np.linalg.svd(turns.sum(0))  # the one turn nearest to every frame's (chordal mean)
    mean_turn = u @ np.diag([1, 1, np.sign(np.linalg.det(u @ vt))]) @ vt
    return {
        "frames": len(rows),
        "mesh_mm": round(float(np.mean([r["mesh_mm"] for r in rows])), 3),
        "mesh_aligned_mm": round(float(np.mean([r["mesh_aligned_mm"] for r in rows])), 3),
        "expression_mm": round(float(np.mean([r["expression_mm"] for r in rows])), 3),
        "camera_rotation_deg": round(float(np.mean([_angle(r["rotation"]) for r in rows])), 3),
        "camera_rotation_aligned_deg": round(float(np.mean([_angle(mean_turn.T @ r["rotation"]) for r in rows])), 3),
        "camera_centre_mm": round(float(np.mean([r["centre_mm"] for r in rows])), 2),
        "reprojection_px": round(float(np.mean([report["reprojection_px"]["per_frame"][t] for t in frames])), 3),
        "focal_px": next((clip["focal_px"] for clip in report.get("clips", []) if clip["camera"] == camera_id),
                         report["focal_px"]),
    }
