"""The project's one camera: a pinhole in OpenCV axes, plus the one GL <-> CV conversion.

Conventions (see docs/data-format.md):

- camera axes are OpenCV: x right, y down, z forward (points in front have z > 0);
- ``K`` holds ``fx, fy, cx, cy`` in pixels; a point projects to ``u = fx*x/z + cx``,
  ``v = fy*y/z + cy``; pixel (row i, column j) covers ``[j, j+1) x [i, i+1)`` and has its
  centre at ``(j + 0.5, i + 0.5)``;
- ``w2c`` maps world points (homogeneous, column vectors) to camera points.

Capture datasets in the GaussianAvatars/VHAP layout store camera-to-world matrices in OpenGL
axes (x right, y up, z backward); :func:`opengl_c2w_to_opencv_w2c` and
:func:`opencv_w2c_to_opengl_c2w` are the only place where that conversion happens.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .errors import InputError

# Flipping y and z turns OpenGL camera axes into OpenCV camera axes (and back).
_GL_CV_FLIP = np.diag([1.0, -1.0, -1.0, 1.0])


def _rigid_inverse(m: np.ndarray) -> np.ndarray:
    """Inverse of a 4x4 rotation+translation, exact for orthonormal rotations."""
    out = np.eye(4)
    rot = m[:3, :3]
    out[:3, :3] = rot.T
    out[:3, 3] = -rot.T @ m[:3, 3]
    return out


def _check_matrix(value, shape: tuple[int, ...], field: str) -> np.ndarray:
    array = np.asarray(value, dtype=np.float64)
    if array.shape != shape:
        raise InputError(None, field, f"expected shape {shape}, got {array.shape}")
    if not np.isfinite(array).all():
        raise InputError(None, field, "contains NaN or inf")
    return array


def opengl_c2w_to_opencv_w2c(c2w) -> np.ndarray:
    """Dataset camera-to-world (OpenGL axes) -> our world-to-camera (OpenCV axes), 4x4 float64."""
    c2w = _check_matrix(c2w, (4, 4), "transform_matrix")
    return np.linalg.inv(c2w @ _GL_CV_FLIP)


def opencv_w2c_to_opengl_c2w(w2c) -> np.ndarray:
    """Our world-to-camera (OpenCV axes) -> dataset camera-to-world (OpenGL axes), 4x4 float64."""
    w2c = _check_matrix(w2c, (4, 4), "w2c")
    return np.linalg.inv(w2c) @ _GL_CV_FLIP


def intrinsics_matrix(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """The 3x3 pinhole matrix ``K`` from focal lengths and principal point, in pixels."""
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=np.float64)


def focal_from_fov(fov: float, size: int) -> float:
    """Focal length in pixels giving full field of view ``fov`` (radians) across ``size`` pixels."""
    return 0.5 * size / math.tan(0.5 * fov)


FILM_DIAGONAL_MM = math.hypot(36.0, 24.0)  # the 35 mm film frame a "35 mm equivalent" focal length refers to


def focal_from_35mm(focal_35mm: float, width: int, height: int) -> float:
    """A 35 mm equivalent focal length (EXIF ``FocalLengthIn35mmFilm``) in pixels of a ``width`` ×
    ``height`` image: the same diagonal field of view (CIPA DC-008's definition)."""
    return float(focal_35mm) * math.hypot(width, height) / FILM_DIAGONAL_MM


@dataclasses.dataclass
class Camera:
    """A pinhole camera: intrinsics ``K`` (pixels), ``w2c`` (OpenCV axes), image size, id.

    Arrays are stored as float64; construction validates shapes and finiteness and
    raises :class:`~mogaface.core.errors.InputError` on bad values.
    """

    K: np.ndarray
    w2c: np.ndarray
    width: int
    height: int
    camera_id: str = "0"

    def __post_init__(self):
        self.K = _check_matrix(self.K, (3, 3), "K")
        self.w2c = _check_matrix(self.w2c, (4, 4), "w2c")
        self.width = int(self.width)
        self.height = int(self.height)
        self.camera_id = str(self.camera_id)
        if self.width <= 0 or self.height <= 0:
            raise InputError(None, "width/height", f"image size must be positive, got {self.width}x{self.height}")
        if self.fx <= 0 or self.fy <= 0:
            raise InputError(None, "K", f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")

    # -- intrinsics ---------------------------------------------------------------------------
    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def fov_x(self) -> float:
        """Horizontal field of view in radians (``camera_angle_x``), for a centred principal point."""
        return 2.0 * math.atan(0.5 * self.width / self.fx)

    @property
    def fov_y(self) -> float:
        """Vertical field of view in radians (``camera_angle_y``), for a centred principal point."""
        return 2.0 * math.atan(0.5 * self.height / self.fy)

    # -- extrinsics ---------------------------------------------------------------------------
    @property
    def R(self) -> np.ndarray:
        """World-to-camera rotation (3,3)."""
        return self.w2c[:3, :3]

    @property
    def t(self) -> np.ndarray:
        """World-to-camera translation (3,)."""
        return self.w2c[:3, 3]

    @property
    def c2w(self) -> np.ndarray:
        """Camera-to-world (4,4), OpenCV axes."""
        return np.linalg.inv(self.w2c)

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates (3,)."""
        return self.c2w[:3, 3].copy()

    # -- geometry -----------------------------------------------------------------------------
    def world_to_camera(self, points) -> np.ndarray:
        """World points (N,3) -> camera-space points (N,3), OpenCV axes."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return points @ self.R.T + self.t

    def project(self, points) -> tuple[np.ndarray, np.ndarray]:
        """World points (N,3) -> pixel coordinates ``uv`` (N,2) and camera depth ``z`` (N,).

        Points with ``z <= 0`` (behind the camera) get non-finite or meaningless ``uv``;
        check ``depth > 0`` before using them.
        """
        cam = self.world_to_camera(points)
        z = cam[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.fx * cam[:, 0] / z + self.cx
            v = self.fy * cam[:, 1] / z + self.cy
        return np.stack([u, v], axis=1), z

    def scaled(self, factor: float) -> "Camera":
        """The same camera imaging ``factor`` times as many pixels per axis (pixel centres align)."""
        K = self.K.copy()
        K[:2] *= factor
        return Camera(K, self.w2c.copy(), round(self.width * factor), round(self.height * factor), self.camera_id)

    # -- constructors -------------------------------------------------------------------------
    @classmethod
    def look_at(
        cls,
        eye,
        target,
        up=(0.0, 1.0, 0.0),
        *,
        width: int,
        height: int,
        fov_x: float | None = None,
        fx: float | None = None,
        fy: float | None = None,
        cx: float | None = None,
        cy: float | None = None,
        camera_id: str = "0",
    ) -> "Camera":
        """A camera at ``eye`` looking at ``target`` with world ``up`` pointing up in the image.

        Give the focal length as ``fov_x`` (radians) or ``fx`` (pixels); ``fy`` defaults to
        ``fx`` (square pixels) and the principal point to the image centre.
        """
        eye = np.asarray(eye, dtype=np.float64)
        forward = np.asarray(target, dtype=np.float64) - eye
        norm = np.linalg.norm(forward)
        if norm == 0:
            raise InputError(None, "target", "look_at target equals the eye position")
        forward /= norm
        right = np.cross(forward, np.asarray(up, dtype=np.float64))  # x = z cross (-y)
        if np.linalg.norm(right) < 1e-9:
            raise InputError(None, "up", "look_at up vector is parallel to the viewing direction")
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        R = np.stack([right, down, forward])  # rows: camera axes in world coordinates
        w2c = np.eye(4)
        w2c[:3, :3] = R
        w2c[:3, 3] = -R @ eye
        if fx is None:
            if fov_x is None:
                raise InputError(None, "fov_x", "give fov_x or fx")
            fx = focal_from_fov(fov_x, width)
        fy = fx if fy is None else fy
        cx = 0.5 * width if cx is None else cx
        cy = 0.5 * height if cy is None else cy
        return cls(intrinsics_matrix(fx, fy, cx, cy), w2c, width, height, camera_id)


def look_point(cameras) -> np.ndarray:
    """The point nearest every camera's optical axis (least squares): where the rig looks."""
    normal, rhs = np.zeros((3, 3)), np.zeros(3)
    for camera in cameras:
        axis = camera.w2c[2, :3]  # the optical axis (OpenCV +z) in world axes
        across = np.eye(3) - np.outer(axis, axis)
        normal += across
        rhs += across @ camera.center
    return np.linalg.lstsq(normal, rhs, rcond=None)[0]  # (min-norm where the axes are parallel)
