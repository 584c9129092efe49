"""The one camera class and the OpenGL <-> OpenCV conversion of dataset cameras."""

import math

import numpy as np
import pytest

from mogaface.core.camera import (
    Camera,
    intrinsics_matrix,
    opencv_w2c_to_opengl_c2w,
    opengl_c2w_to_opencv_w2c,
)
from mogaface.core.errors import InputError


def _random_rigid(rng) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    m = np.eye(4)
    m[:3, :3] = q
    m[:3, 3] = rng.normal(size=3)
    return m


def test_project_known_point():
    cam = Camera(intrinsics_matrix(100, 120, 64, 40), np.eye(4), 128, 80, "c0")
    uv, z = cam.project([[0.1, 0.2, 1.0], [0.0, 0.0, 2.0]])
    np.testing.assert_allclose(uv, [[74.0, 64.0], [64.0, 40.0]])
    np.testing.assert_allclose(z, [1.0, 2.0])


def test_fov_matches_focal():
    cam = Camera(intrinsics_matrix(50, 25, 50, 25), np.eye(4), 100, 50)
    assert cam.fov_x == pytest.approx(math.pi / 2)
    assert cam.fov_y == pytest.approx(math.pi / 2)


def test_look_at_orientation():
    cam = Camera.look_at((0, 0, 2), (0, 0, 0), width=64, height=48, fov_x=0.6)
    np.testing.assert_allclose(cam.center, [0, 0, 2], atol=1e-12)
    np.testing.assert_allclose(cam.R @ cam.R.T, np.eye(3), atol=1e-12)
    uv, z = cam.project([[0, 0, 0], [0, 0.1, 0], [0.1, 0, 0]])
    np.testing.assert_allclose(uv[0], [32, 24])
    assert z[0] == pytest.approx(2.0)
    assert uv[1, 1] < 24  # world up is image up (smaller row)
    assert uv[2, 0] > 32  # looking down -z with y up, world +x is on the right
    np.testing.assert_allclose(cam.c2w @ cam.w2c, np.eye(4), atol=1e-12)


def test_scaled_camera_aligns_pixel_centres():
    cam = Camera.look_at((0.3, 0.1, 1), (0, 0, 0), width=20, height=10, fov_x=0.7)
    big = cam.scaled(3)
    assert (big.width, big.height) == (60, 30)
    pts = np.random.default_rng(0).normal(size=(5, 3)) * 0.1
    np.testing.assert_allclose(big.project(pts)[0], 3 * cam.project(pts)[0])


def test_gl_cv_round_trip():
    rng = np.random.default_rng(1)
    for _ in range(10):
        c2w_gl = _random_rigid(rng)
        w2c = opengl_c2w_to_opencv_w2c(c2w_gl)
        np.testing.assert_allclose(opencv_w2c_to_opengl_c2w(w2c), c2w_gl, atol=1e-12)
        w2c2 = _random_rigid(rng)
        np.testing.assert_allclose(opengl_c2w_to_opencv_w2c(opencv_w2c_to_opengl_c2w(w2c2)), w2c2, atol=1e-12)


def test_gl_camera_projects_known_points():
    # A hand-made OpenGL camera: at (0, 0, 2), identity rotation, so it looks down world -z
    # with world +y up and world +x to the right.
    c2w_gl = np.eye(4)
    c2w_gl[:3, 3] = [0, 0, 2]
    cam = Camera(intrinsics_matrix(100, 100, 50, 40), opengl_c2w_to_opencv_w2c(c2w_gl), 100, 80)
    uv, z = cam.project([[0, 0, 0], [0.2, 0, 0], [0, 0.2, 0], [0, 0, 3]])
    np.testing.assert_allclose(uv[:3], [[50, 40], [60, 40], [50, 30]])
    np.testing.assert_allclose(z[:3], [2, 2, 2])
    assert z[3] < 0  # behind the camera
    np.testing.assert_allclose(cam.center, [0, 0, 2])


def test_look_at_matches_gl_conversion():
    cam = Camera.look_at((1, 0.5, 2), (0, 0.1, 0), width=64, height=64, fov_x=0.5)
    c2w_gl = opencv_w2c_to_opengl_c2w(cam.w2c)
    # OpenGL cameras look down their -z axis: the third column points away from the target.
    forward = -c2w_gl[:3, 2]
    expected = np.array([0, 0.1, 0]) - np.array([1, 0.5, 2])
    np.testing.assert_allclose(forward, expected / np.linalg.norm(expected), atol=1e-12)
    assert c2w_gl[1, 1] > 0  # camera up has a positive world-y component


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(K=np.eye(4), w2c=np.eye(4), width=4, height=4),
        dict(K=np.eye(3), w2c=np.eye(3), width=4, height=4),
        dict(K=np.full((3, 3), np.nan), w2c=np.eye(4), width=4, height=4),
        dict(K=np.eye(3), w2c=np.eye(4), width=0, height=4),
    ],
)
def test_bad_camera_rejected(kwargs):
    with pytest.raises(InputError):
        Camera(**kwargs)
