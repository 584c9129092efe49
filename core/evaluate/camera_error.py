"""How far a capture's calibrated cameras (and a run's refined ones) are from the true cameras.

Synthetic captures made with ``--camera-noise`` keep the true cameras in ``cameras_gt.json``.
A method that refines cameras writes them beside the run as ``cameras_refined.json`` (the same
form: camera id → camera fields); its error is then reported beside the calibration's.

The rotation error is also split by what the images can see of it. Relative to the point the rig
looks at (the subject), a camera's error is an *orbit* (its centre off sideways, so it sees the
subject from a slightly other direction: only parallax shows it), a *roll* about its optical axis
(the image turns about the subject) and an *aim* (the subject lands off-centre: the image shifts).
``look_shift_mm`` is the common shift of the subject that the cameras agree on: an avatar that
drifted while every camera followed it.

A rigid motion of the whole rig, the subject moving with it, changes no image: it is a gauge that
refinement pins by holding the calibration's rigid motion. The calibration's own error in that
motion is then a floor under the rotation error that no refinement can go below (0.24° on the
1°-noise capture of docs/notebook/2026-11-26-camera-refinement.md).
``rotation_aligned_deg`` and ``position_aligned_mm`` are
measured after the rigid motion that best aligns the rig with the truth, so they show how well
the cameras sit relative to one another.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib

import numpy as np

from ..camera import look_point
from ..data.camera_file import read_cameras
from ..flame.numpy_model import axis_angle_to_matrix
from ..run.cameras import ScoringCameras
from ..run.names import REFINED_CAMERAS_FILE


def pose_error(camera, truth) -> tuple[float, float]:
    """Rotation error (degrees) and camera-centre distance (mm) of one camera against the truth."""
    rotation = _angle(camera.w2c[:3, :3] @ truth.w2c[:3, :3].T)
    return rotation, float(np.linalg.norm(camera.center - truth.center) * 1000.0)


def _turn(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking direction ``a`` to direction ``b``."""
    axis = np.cross(a, b)
    sin = float(np.linalg.norm(axis))
    if sin < 1e-12:
        return np.eye(3)
    return axis_angle_to_matrix((axis / sin * np.arctan2(sin, float(a @ b)))[None])[0]


def _angle(rotation: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0))))


def error_parts(camera, truth, point: np.ndarray) -> tuple[float, float, float]:
    """``(orbit, roll, aim)`` in degrees of ``camera`` against ``truth``, about the looked-at ``point``.

    Orbit: the angle between the directions to ``point`` from the two centres. Roll and aim: the
    rest of the rotation once the true camera is moved to the estimated centre and turned by that
    orbit, about the optical axis and across it.
    """
    orbit = _turn(point - truth.center, point - camera.center)
    rest = camera.w2c[:3, :3] @ orbit @ truth.w2c[:3, :3].T  # in the camera's axes
    half_sine = np.array([rest[2, 1] - rest[1, 2], rest[0, 2] - rest[2, 0], rest[1, 0] - rest[0, 1]]) / 2.0
    return _angle(orbit), float(np.degrees(abs(np.arcsin(np.clip(half_sine[2], -1, 1))))), float(
        np.degrees(np.arcsin(np.clip(np.hypot(half_sine[0], half_sine[1]), 0, 1))))


def look_shift(cameras: dict, truth: dict, point: np.ndarray) -> np.ndarray:
    """The shift ``δ`` (metres) for which ``point + δ`` lands where ``point`` does through the true
    cameras, in least squares over the cameras (Gauss-Newton, linear to well under a millimetre)."""
    ids = [cid for cid in truth if cid in cameras]
    target = np.concatenate([truth[cid].project(point[None])[0][0] for cid in ids])

    def landed(shift):
        return np.concatenate([cameras[cid].project((point + shift)[None])[0][0] for cid in ids])

    shift, step = np.zeros(3), 1e-4
    for _ in range(3):
        base = landed(shift)
        jacobian = np.stack([(landed(shift + step * e) - base) / step for e in np.eye(3)], 1)
        shift = shift + np.linalg.lstsq(jacobian, target - base, rcond=None)[0]
    return shift


def aligned_rig(cameras: dict, truth: dict) -> dict:
    """``cameras`` moved by the rigid motion ``X ↦ G·X + g`` of the world that best aligns them
    with ``truth`` (``G``: the rotation nearest the mean of ``R_estᵀ·R_true``; ``g``: the mean
    centre difference after it), keyed as ``truth``."""
    ids = [cid for cid in truth if cid in cameras]
    mean = sum(cameras[cid].w2c[:3, :3].T @ truth[cid].w2c[:3, :3] for cid in ids)
    u, _, vt = np.linalg.svd(mean)
    undo = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt  # = Gᵀ: R_est·Gᵀ ≈ R_true
    shift = np.mean([truth[cid].center - undo.T @ cameras[cid].center for cid in ids], 0)
    moved = {}
    for cid in ids:
        w2c = np.eye(4)
        w2c[:3, :3] = cameras[cid].w2c[:3, :3] @ undo
        w2c[:3, 3] = -w2c[:3, :3] @ (undo.T @ cameras[cid].center + shift)
        moved[cid] = dataclasses.replace(cameras[cid], w2c=w2c)
    return moved


def camera_summary(cameras: dict, truth: dict) -> dict:
    """Mean errors of ``cameras`` against ``truth`` (the cameras both have), split as `eval` reports them."""
    ids = [cid for cid in truth if cid in cameras]
    if not ids:
        return {}
    rotation, position = np.array([pose_error(cameras[cid], truth[cid]) for cid in ids]).T
    point = look_point([truth[cid] for cid in ids])
    orbit, roll, aim = np.array([error_parts(cameras[cid], truth[cid], point) for cid in ids]).T
    aligned = aligned_rig(cameras, truth)
    rotation_aligned, position_aligned = np.array([pose_error(aligned[cid], truth[cid]) for cid in ids]).T
    return {"cameras": len(ids), "rotation_deg": float(rotation.mean()), "position_mm": float(position.mean()),
            "orbit_deg": float(orbit.mean()), "roll_deg": float(roll.mean()), "aim_deg": float(aim.mean()),
            "look_shift_mm": [round(float(v) * 1000.0, 3) for v in look_shift(cameras, truth, point)],
            "rotation_aligned_deg": float(rotation_aligned.mean()),
            "position_aligned_mm": float(position_aligned.mean())}


def delay_errors(true_delays: dict, learned: dict) -> dict:
    """How far learned camera delays (timesteps) are from the true ones, against assuming none."""
    ids = [cid for cid in learned if cid in true_delays]
    truth = np.array([true_delays[cid] for cid in ids])
    guess = np.array([learned[cid] for cid in ids])
    return {"cameras": len(ids), "assumed_synchronised_mean_abs": float(np.abs(truth).mean()),
            "learned_mean_abs_error": float(np.abs(guess - truth).mean()),
            "correlation": float(np.corrcoef(guess, truth)[0, 1]) if len(ids) > 2 and guess.std() > 0 else None}


def camera_errors(capture, run_dir: str | os.PathLike | None = None) -> dict:
    """``{"calibrated": {...}, "refined": {...}, "calibrated_refined_cameras": {...}, "delays": {...}}``
    mean errors (each where the capture has the truth and the run an estimate); ``{}`` for captures
    without true cameras."""
    from ..data.capture_info import capture_info
    from ..run.names import DELAYS_FILE
    from ..train.camera_delays import read_delays

    true_delays = capture_info(capture.root).get("camera_delays")
    delays = pathlib.Path(run_dir) / DELAYS_FILE if run_dir is not None else None
    timing = ({"delays": delay_errors(true_delays, read_delays(delays))}
              if true_delays and delays is not None and delays.exists() else {})
    truth = ScoringCameras(capture).truth
    if not truth:
        return timing
    result = {"calibrated": camera_summary(capture.cameras, truth), **timing}
    refined = pathlib.Path(run_dir) / REFINED_CAMERAS_FILE if run_dir is not None else None
    if refined is not None and refined.exists():
        cameras = read_cameras(refined)
        result["refined"] = camera_summary(cameras, truth)
        # the calibration of the same cameras (the held-out one is not refined): the fair "before"
        result["calibrated_refined_cameras"] = camera_summary({cid: capture.cameras[cid] for cid in cameras
                                                         if cid in capture.cameras}, truth)
    return result
