"""Cameras both ways: a capture camera → Blender camera settings, a Blender camera → OpenCV.

Also the whole capture as Blender sees it (:func:`capture_scene`: cameras, first-view images,
frame range).
"""

from __future__ import annotations

import dataclasses
import os
import pathlib

import numpy as np

from ..camera import Camera, look_point
from ..data.capture import Capture
from ..errors import InputError
from .axes import CV_TO_BLENDER_CAMERA, flame_to_blender, flame_to_blender_matrix, timestep_to_frame

# -- cameras ------------------------------------------------------------------------------------

SENSOR_WIDTH_MM = 36.0


@dataclasses.dataclass
class BlenderCamera:
    """Everything a Blender camera needs to image exactly like one capture camera.

    ``lens``/``sensor_width`` in mm with ``sensor_fit='HORIZONTAL'``; shifts in units of the
    image width; ``pixel_aspect`` (x, y) for fx ≠ fy (both ≥ 1, as Blender requires);
    ``matrix_world`` 4×4 in Blender world axes; ``image_path`` of its first view, if any.
    """

    name: str
    camera_id: str
    lens: float
    sensor_width: float
    shift_x: float
    shift_y: float
    resolution: tuple[int, int]
    pixel_aspect: tuple[float, float]
    matrix_world: np.ndarray
    image_path: str | None = None
    sensor_fit: str = "HORIZONTAL"


def blender_camera(camera: Camera, name: str | None = None, image_path=None) -> BlenderCamera:
    """A capture :class:`~mogaface.core.camera.Camera` (OpenCV ``K``, ``w2c``) as Blender settings.

    Blender's view plane (horizontal sensor fit) spans ``sensor_width`` across the image
    width, so ``fx = lens·W/sensor_width``; pixel rows are ``pixel_aspect_y/pixel_aspect_x``
    times taller than columns are wide, so that ratio is ``fx/fy``; the shifts move the
    frame's centre away from the optical axis in units of the width.
    """
    width, height = camera.width, camera.height
    ratio = camera.fx / camera.fy  # pixel_aspect_y / pixel_aspect_x
    aspect = (1.0, ratio) if ratio >= 1.0 else (1.0 / ratio, 1.0)
    c2w_blender_camera = np.linalg.inv(camera.w2c) @ CV_TO_BLENDER_CAMERA
    return BlenderCamera(
        name=name or f"Camera {camera.camera_id}",
        camera_id=camera.camera_id,
        lens=camera.fx * SENSOR_WIDTH_MM / width,
        sensor_width=SENSOR_WIDTH_MM,
        shift_x=-(camera.cx - 0.5 * width) / width,
        shift_y=(camera.cy - 0.5 * height) / width * ratio,
        resolution=(width, height),
        pixel_aspect=aspect,
        matrix_world=flame_to_blender_matrix(c2w_blender_camera),
        image_path=None if image_path is None else os.fspath(image_path),
    )


@dataclasses.dataclass
class CaptureScene:
    """A capture as Blender sees it: its cameras (with first-view images) and its frame range."""

    root: str
    cameras: list[BlenderCamera]
    frame_start: int
    frame_end: int
    n_timesteps: int
    # Camera ids whose pose differs between frames (a union of sequences: VHAP moves each
    # sequence's cameras); they are imported at the pose of their first frame.
    moving_cameras: list[str] = dataclasses.field(default_factory=list)
    # Where the cameras look (Blender's world; :func:`~..camera.look_point`: for one camera, a tracked
    # clip's, the point of its axis nearest the origin, where the head stands): framed after an import.
    subject_centre: tuple[float, float, float] = (0.0, 0.0, 0.0)


#: Half the size of what a view framing the subject shows: a FLAME head with its neck and some room, in metres.
HEAD_RADIUS = 0.22


def capture_scene(folder, refined_cameras=None) -> CaptureScene:
    """Open a capture folder and describe its Blender scene (cameras, images, timeline).

    Each camera's background image is its view at the first timestep it was captured in.
    ``refined_cameras``: a run's ``cameras_refined.json`` (camera refinement); the cameras it
    names take its poses, the others (the held-out camera) keep the capture's.
    Raises :class:`~mogaface.core.errors.CaptureError` naming the file of the first problem.
    """
    capture = Capture.open(folder)
    refined = _refined_poses(capture, refined_cameras)
    first_frame = {}
    for frame in sorted(capture.frames(), key=lambda f: (f.timestep_index, f.camera_index)):
        first_frame.setdefault(frame.camera_id, frame)
    cameras, poses = [], []
    for camera_id, camera in capture.cameras.items():
        frame = first_frame.get(camera_id)
        image = capture.path(frame, "file_path") if frame is not None else None
        pose = refined.get(camera_id) or (capture.camera(frame) if frame is not None else camera)
        cameras.append(blender_camera(pose, f"Camera {camera_id}", image))
        poses.append(pose)
    moving = sorted({f.camera_id for f in capture.frames() if f.camera_id not in refined
                     if not np.allclose(capture.camera(f).w2c, capture.camera(first_frame[f.camera_id]).w2c)})
    return CaptureScene(
        root=os.fspath(capture.root),
        cameras=cameras,
        frame_start=timestep_to_frame(min(capture.timesteps)),
        frame_end=timestep_to_frame(max(capture.timesteps)),
        n_timesteps=len(capture.timesteps),
        moving_cameras=moving,
        subject_centre=tuple(float(v) for v in flame_to_blender(look_point(poses))),
    )


def _refined_poses(capture: Capture, path) -> dict[str, Camera]:
    """The refined cameras of ``path`` (none when ``path`` is empty), checked against the capture."""
    if not path:
        return {}
    from ..data.camera_file import read_cameras

    path = pathlib.Path(path)
    if not path.is_file():
        raise InputError(path, None, "refined cameras file not found")
    refined = read_cameras(path)
    unknown = sorted(set(refined) - set(capture.cameras))
    if unknown:
        raise InputError(path, unknown[0], f"camera id not in the capture {capture.root} "
                                           f"(known: {', '.join(sorted(capture.cameras))})")
    return refined



def opencv_camera(matrix_world, lens: float, sensor_width: float, sensor_height: float, sensor_fit: str,
                  shift_x: float, shift_y: float, resolution: tuple[int, int],
                  pixel_aspect: tuple[float, float] = (1.0, 1.0), camera_id: str = "blender") -> Camera:
    """A Blender camera (settings as Blender stores them) → an OpenCV :class:`Camera`.

    The inverse of :func:`blender_camera`, for every sensor fit: Blender fits the sensor to
    the width (``HORIZONTAL``, or ``AUTO`` when the frame is at least as wide as tall) or the
    height, and measures shifts in units of that fitted size. ``matrix_world`` may carry scale;
    only its rotation and position are used.
    """
    width, height = int(resolution[0]), int(resolution[1])
    ratio = float(pixel_aspect[1]) / float(pixel_aspect[0])  # pixel height / width = fx / fy
    if sensor_fit == "AUTO":
        horizontal, sensor = width >= height * ratio, sensor_width
    else:
        horizontal = sensor_fit == "HORIZONTAL"
        sensor = sensor_width if horizontal else sensor_height
    fitted = width if horizontal else height * ratio  # the fitted size, in units of a pixel's width
    fx = lens * fitted / sensor
    fy = fx / ratio
    cx = 0.5 * width - shift_x * fitted
    cy = 0.5 * height + shift_y * fitted / ratio
    matrix = np.asarray(matrix_world, np.float64).copy()
    matrix[:3, :3] /= np.linalg.norm(matrix[:3, :3], axis=0)
    c2w_cv = flame_to_blender_matrix(np.eye(4)).T @ matrix @ CV_TO_BLENDER_CAMERA
    return Camera(K=np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), w2c=np.linalg.inv(c2w_cv),
                  width=width, height=height, camera_id=camera_id)
