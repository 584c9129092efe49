"""A cameras file: camera id → the camera fields of a split file (``cameras_gt.json``, a run's refined
or landmark-solved cameras), written and read here and nowhere else."""

from __future__ import annotations

from ..camera import Camera, opencv_w2c_to_opengl_c2w
from ..io.atomic import write_json
from ..io.jsonfile import read_json_object
from . import layout
from .capture_entries import frame_camera as camera_from_entry


def camera_fields(camera: Camera) -> dict:
    """A frame's camera entries: intrinsics, image size, fields of view, OpenGL ``transform_matrix``."""
    return {
        "fl_x": camera.fx,
        "fl_y": camera.fy,
        "cx": camera.cx,
        "cy": layout.cy_to_file(camera.cy, camera.height),
        "w": camera.width,
        "h": camera.height,
        "camera_angle_x": camera.fov_x,
        "camera_angle_y": camera.fov_y,
        "transform_matrix": opencv_w2c_to_opengl_c2w(camera.w2c).tolist(),
    }


def write_cameras(path, cameras: dict[str, Camera]) -> None:
    """A cameras file: camera id → the camera fields above (``cameras_gt.json``, refined or solved
    cameras; :func:`read_cameras` reads it), written atomically."""
    write_json(path, {camera_id: camera_fields(camera) for camera_id, camera in cameras.items()})


def read_cameras(path, cy_origin: str = "bottom") -> dict:
    """A ``{camera id: camera fields}`` JSON file (``cameras_gt.json``, refined cameras) → cameras.

    ``cy`` is read by the capture's convention (its split files' ``cy_origin``), as it was written.
    """
    entries = read_json_object(path)  # camera id → camera fields
    return {cid: camera_from_entry(entry, {"cy_origin": cy_origin}, cid, path, cid) for cid, entry in entries.items()}
