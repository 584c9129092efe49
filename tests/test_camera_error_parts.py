"""The split of a camera's rotation error into orbit, roll and aim, and the common look shift:
each known motion of a camera lands in its own part, and a known shift of what every camera looks
at is found again; the error after aligning the rig ignores a rigid motion of the whole rig."""

import dataclasses

import numpy as np
import pytest

from mogaface.core.camera import Camera, look_point
from mogaface.core.evaluate.camera_error import camera_summary, error_parts, look_shift, pose_error

SUBJECT = np.array([0.02, 1.55, -0.01])


def ring(target=SUBJECT, count=8, radius=1.0):
    """Cameras on an arc in front of ``target``, each looking at it."""
    cameras = {}
    for k, azimuth in enumerate(np.radians(np.linspace(-70, 70, count))):
        eye = SUBJECT + radius * np.array([np.sin(azimuth), 0.1 * np.cos(3 * azimuth), np.cos(azimuth)])
        cameras[f"cam{k}"] = Camera.look_at(eye, target, width=128, height=128, fov_x=np.radians(22),
                                            camera_id=f"cam{k}")
    return cameras


def rotated(camera, axis_angle, about):
    """``camera`` turned by ``axis_angle`` (world axes) about the point ``about``."""
    angle = np.linalg.norm(axis_angle)
    k = np.array([[0, -axis_angle[2], axis_angle[1]], [axis_angle[2], 0, -axis_angle[0]],
                  [-axis_angle[1], axis_angle[0], 0]]) / angle
    turn = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k
    c2w = np.eye(4)
    c2w[:3, :3] = turn @ camera.c2w[:3, :3]
    c2w[:3, 3] = turn @ (camera.center - about) + about
    return dataclasses.replace(camera, w2c=np.linalg.inv(c2w))


def test_the_rig_looks_at_its_subject():
    assert np.allclose(look_point(ring().values()), SUBJECT, atol=1e-9)


@pytest.mark.parametrize("part", ["orbit", "roll", "aim"])
def test_each_motion_lands_in_its_own_part(part):
    truth = ring()["cam2"]
    angle = np.radians(0.5)
    forward = truth.w2c[2, :3]
    sideways = np.cross(forward, [0.0, 1.0, 0.0])
    sideways /= np.linalg.norm(sideways)
    moved = {"orbit": rotated(truth, angle * np.array([0.0, 1.0, 0.0]), SUBJECT),
             "roll": rotated(truth, angle * forward, truth.center),
             "aim": rotated(truth, angle * sideways, truth.center)}[part]
    parts = dict(zip(("orbit", "roll", "aim"), error_parts(moved, truth, SUBJECT)))
    assert parts[part] == pytest.approx(0.5, abs=2e-3)
    assert all(value < 2e-3 for name, value in parts.items() if name != part)
    assert pose_error(moved, truth)[0] == pytest.approx(0.5, abs=1e-6)


def test_a_common_shift_of_the_looked_at_point_is_found():
    truth = ring()
    shift = np.array([0.001, -0.002, 0.0025])
    aimed = ring(target=SUBJECT + shift)  # same centres, every camera turned to the shifted point
    assert np.allclose(look_shift(aimed, truth, SUBJECT), shift, atol=2e-5)
    assert np.allclose(look_shift(truth, truth, SUBJECT), 0.0, atol=1e-9)


def test_the_aligned_error_ignores_a_motion_of_the_whole_rig_and_keeps_the_rest():
    truth = ring()
    whole = np.array([0.004, -0.007, 0.005])  # radians, about a point off the subject
    moved = {cid: rotated(camera, whole, SUBJECT + [0.1, 0.2, -0.3]) for cid, camera in truth.items()}
    summary = camera_summary(moved, truth)
    assert summary["rotation_deg"] == pytest.approx(np.degrees(np.linalg.norm(whole)), abs=1e-6)
    assert summary["position_mm"] > 1.0
    assert summary["rotation_aligned_deg"] < 1e-6 and summary["position_aligned_mm"] < 1e-6
    # One camera turned by 0.8° on top: it alone carries the error once the rig is aligned (the
    # alignment shares out a little of it: 1/8 of the turn to every camera, nearly).
    one = dict(moved, cam3=rotated(moved["cam3"], np.radians(0.8) * np.array([0.0, 0.6, 0.8]), moved["cam3"].center))
    aligned = camera_summary(one, truth)["rotation_aligned_deg"]
    assert aligned == pytest.approx((0.8 * 7 / 8 + 7 * 0.8 / 8) / 8, rel=0.02)
