"""How far a capture's calibrated cameras (and a run's refined ones) are from the true cameras.

Synthetic captures made with ``--camera-noise`` keep the true cameras in ``cameras_gt.json``.
A method that refines cameras writes them beside the run as ``cameras_refined.json`` (the same
form: camera id → camera fields); its error is then reported beside the calibration's.
"""

from __future__ import annotations

import os
import pathlib

import numpy as np

from .images import ScoringCameras, read_cameras

REFINED_CAMERAS_FILE = "cameras_refined.json"


def pose_error(camera, truth) -> tuple[float, float]:
    """Rotation error (degrees) and camera-centre distance (mm) of one camera against the truth."""
    relative = camera.w2c[:3, :3] @ truth.w2c[:3, :3].T
    angle = np.degrees(np.arccos(np.clip((np.trace(relative) - 1.0) / 2.0, -1.0, 1.0)))
    return float(angle), float(np.linalg.norm(camera.center - truth.center) * 1000.0)


def _summary(cameras: dict, truth: dict) -> dict:
    errors = [pose_error(cameras[cid], truth[cid]) for cid in truth if cid in cameras]
    if not errors:
        return {}
    rotation, position = np.array(errors).T
    return {"cameras": len(errors), "rotation_deg": float(rotation.mean()), "position_mm": float(position.mean())}


def camera_errors(capture, run_dir: str | os.PathLike | None = None) -> dict:
    """``{"calibrated": {...}, "refined": {...}, "calibrated_refined_cameras": {...}}`` mean errors;
    ``{}`` for captures without true cameras."""
    truth = ScoringCameras(capture).truth
    if not truth:
        return {}
    result = {"calibrated": _summary(capture.cameras, truth)}
    refined = pathlib.Path(run_dir) / REFINED_CAMERAS_FILE if run_dir is not None else None
    if refined is not None and refined.exists():
        cameras = read_cameras(refined)
        result["refined"] = _summary(cameras, truth)
        # the calibration of the same cameras (the held-out one is not refined): the fair "before"
        result["calibrated_refined_cameras"] = _summary({cid: capture.cameras[cid] for cid in cameras
                                                         if cid in capture.cameras}, truth)
    return result
