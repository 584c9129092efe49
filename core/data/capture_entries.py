"""One frame entry of a capture's split file, checked: its camera (intrinsics, pose) and its paths.

:class:`~.capture.Capture` parses each entry through these; a problem raises
:class:`~mogaface.core.errors.CaptureError` naming the split file and the entry's field.
"""

from __future__ import annotations

import math
import pathlib

import numpy as np

from ..camera import Camera, intrinsics_matrix, opengl_c2w_to_opencv_w2c
from ..errors import CaptureError
from ..limits import (
    MAX_FOCAL_RATIO,
    MAX_IMAGE_PIXELS,
    MAX_IMAGE_SIDE,
    MAX_PRINCIPAL_OFFSET_RATIO,
    MIN_FOCAL_RATIO,
    MIN_IMAGE_SIDE,
)
from . import layout


def int_field(frame: dict, name: str, source, where: str) -> int:
    value = frame.get(name)
    if value is None:
        raise CaptureError(source, f"{where}.{name}", "missing key")
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise CaptureError(source, f"{where}.{name}", f"expected a non-negative integer, got {value!r}")
    return value


def _number(frame: dict, top: dict, name: str, source, where: str, default=None) -> float | None:
    value = frame.get(name, top.get(name, default))
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise CaptureError(source, f"{where}.{name}", f"expected a finite number, got {value!r}")
    return float(value)


def frame_camera(frame: dict, top: dict, camera_id: str, source, where: str) -> Camera:
    """The camera of one frame entry: per-frame fields first, then the file's top-level ones."""
    w = _number(frame, top, "w", source, where)
    h = _number(frame, top, "h", source, where)
    for name, value in (("w", w), ("h", h)):
        if value is None:
            raise CaptureError(source, f"{where}.{name}", "missing key (not in the frame nor at the top level)")
        if value <= 0 or value != int(value):
            raise CaptureError(source, f"{where}.{name}", f"expected a positive integer, got {value!r}")
    w, h = int(w), int(h)
    fx = _number(frame, top, "fl_x", source, where)
    if fx is None:
        angle = _number(frame, top, "camera_angle_x", source, where)
        if angle is None:
            raise CaptureError(source, f"{where}.fl_x", "missing key (neither fl_x nor camera_angle_x given)")
        if not 0 < angle < math.pi:
            raise CaptureError(source, f"{where}.camera_angle_x", f"expected an angle in (0, pi), got {angle}")
        fx = 0.5 * w / math.tan(0.5 * angle)
    fy = _number(frame, top, "fl_y", source, where)
    if fy is None:
        angle = _number(frame, top, "camera_angle_y", source, where)
        fy = fx if angle is None else 0.5 * h / math.tan(0.5 * angle)
    cx = _number(frame, top, "cx", source, where, 0.5 * w)
    cy = layout.cy_from_file(_number(frame, top, "cy", source, where, 0.5 * h), h, layout.cy_origin(top, source))
    if fx <= 0 or fy <= 0:
        raise CaptureError(source, f"{where}.fl_x", f"focal lengths must be positive, got {fx}, {fy}")
    _check_intrinsics(w, h, fx, fy, cx, cy, source, where)
    matrix = frame.get("transform_matrix")
    if matrix is None:
        raise CaptureError(source, f"{where}.transform_matrix", "missing key")
    try:
        c2w = np.array(matrix, dtype=np.float64)
    except (TypeError, ValueError):
        raise CaptureError(source, f"{where}.transform_matrix", "expected a 4x4 list of numbers") from None
    if c2w.shape != (4, 4):
        raise CaptureError(source, f"{where}.transform_matrix", f"expected a 4x4 matrix, got shape {c2w.shape}")
    if not np.isfinite(c2w).all():
        row, column = np.argwhere(~np.isfinite(c2w))[0]
        raise CaptureError(source, f"{where}.transform_matrix", f"expected finite numbers, found {c2w[row, column]} "
                                                                f"in row {row}, column {column}")
    rot = c2w[:3, :3]
    if not np.allclose(c2w[3], [0, 0, 0, 1], atol=1e-6) or not np.allclose(rot @ rot.T, np.eye(3), atol=1e-4):
        raise CaptureError(source, f"{where}.transform_matrix", "not a rigid camera-to-world transform")
    return Camera(intrinsics_matrix(fx, fy, cx, cy), opengl_c2w_to_opencv_w2c(c2w), w, h, camera_id)


def _check_intrinsics(w, h, fx, fy, cx, cy, source, where) -> None:
    """Refuse sizes and intrinsics no real camera has (they only cost memory or time)."""
    if min(w, h) < MIN_IMAGE_SIDE:
        raise CaptureError(source, f"{where}.w/h", f"{w}x{h} is smaller than the limit ({MIN_IMAGE_SIDE} px a side: "
                                                   f"the image loss's SSIM window)")
    if max(w, h) > MAX_IMAGE_SIDE or w * h > MAX_IMAGE_PIXELS:
        raise CaptureError(source, f"{where}.w/h", f"{w}x{h} is larger than the limit "
                                                   f"({MAX_IMAGE_SIDE} px a side, {MAX_IMAGE_PIXELS} pixels)")
    size = max(w, h)
    for name, f in (("fl_x", fx), ("fl_y", fy)):
        if not MIN_FOCAL_RATIO * size <= f <= MAX_FOCAL_RATIO * size:
            raise CaptureError(source, f"{where}.{name}", f"focal length {f:g} px is outside "
                                                          f"[{MIN_FOCAL_RATIO * size:g}, {MAX_FOCAL_RATIO * size:g}] "
                                                          f"for a {w}x{h} image")
    for name, c, half in (("cx", cx, 0.5 * w), ("cy", cy, 0.5 * h)):
        if abs(c - half) > MAX_PRINCIPAL_OFFSET_RATIO * size:
            raise CaptureError(source, f"{where}.{name}", f"principal point {c:g} px is more than "
                                                          f"{MAX_PRINCIPAL_OFFSET_RATIO:g} image sizes off centre")


_RAW_CAMERA_KEYS = ("w", "h", "fl_x", "fl_y", "cx", "cy", "camera_angle_x", "camera_angle_y")


def _raw_camera_key(frame: dict, top: dict) -> tuple | None:
    """A frame's camera entries as a hashable tuple (None if malformed), to skip re-parsing repeats."""
    try:
        matrix = tuple(tuple(row) for row in frame.get("transform_matrix"))
    except TypeError:
        return None
    return tuple(frame.get(k, top.get(k)) for k in _RAW_CAMERA_KEYS) + (matrix,)


def _camera_difference(known: Camera, new: Camera) -> tuple[str, str] | None:
    """The first intrinsic in which two sightings of one camera id disagree, or None.

    The pose may differ: VHAP moves every sequence's cameras by that sequence's mean head
    translation, so in a union dataset one camera id has one pose per sequence.
    """
    for name, a, b in (
        ("w", known.width, new.width),
        ("h", known.height, new.height),
        ("fl_x", known.fx, new.fx),
        ("fl_y", known.fy, new.fy),
        ("cx", known.cx, new.cx),
        ("cy", known.cy, new.cy),
    ):
        if not np.isclose(a, b, rtol=1e-6, atol=1e-6):
            return name, f"{a:g} before, {b:g} here"
    return None


def empty_split_reason(split: str, doc: dict) -> str:
    """Why a split file lists no frames, in words a user can act on."""
    if split == "val" and doc.get("camera_indices") == []:
        return ("no camera is held out: VHAP writes an empty val split when the capture has a single "
                "camera (monocular)")
    return f"{layout.split_file(split)} lists no frames"


MESH_MODE_HINT = (
    "this folder holds meshes, not FLAME parameters (VHAP's export with --flame-mode mesh: "
    "'mesh_path' and 'exp_path' per frame); export the tracking again with "
    "'python vhap/export_as_nerf_dataset.py ... --flame-mode param' (the default)"
)


def check_frame_paths(root, entry: dict, source, where: str) -> None:
    """Every path a frame names follows the rule of :mod:`.paths` (text only; links at read time)."""
    for name in ("file_path", "flame_param_path"):
        if name not in entry:
            problem = MESH_MODE_HINT if name == "flame_param_path" and "mesh_path" in entry else "missing key"
            raise CaptureError(source, f"{where}.{name}", problem)
        layout.resolve_inside(root, entry[name], source, f"{where}.{name}")
    if entry.get("fg_mask_path") is not None:
        layout.resolve_inside(root, entry["fg_mask_path"], source, f"{where}.fg_mask_path")


def camera_of(entry, doc, camera_id, index, source, where, cameras, parsed) -> Camera:
    """This frame's camera; checks the id keeps one index and one set of intrinsics."""
    known = cameras.get(camera_id)
    if known is not None and known[0] != index:
        raise CaptureError(source, f"{where}.camera_index", f"camera {camera_id!r} has indices {known[0]} and {index}")
    raw = _raw_camera_key(entry, doc)
    camera = parsed.get((camera_id, raw)) if raw is not None else None
    if camera is not None:
        return camera
    camera = frame_camera(entry, doc, camera_id, source, where)
    if known is None:
        taken = next((cid for cid, (i, _) in cameras.items() if i == index), None)
        if taken is not None:
            raise CaptureError(source, f"{where}.camera_index",
                               f"index {index} is used by cameras {taken!r} and {camera_id!r}")
        cameras[camera_id] = (index, camera)
    else:
        difference = _camera_difference(known[1], camera)
        if difference is not None:
            raise CaptureError(
                source, f"{where}.{difference[0]}",
                f"camera {camera_id!r} appears twice with different values ({difference[1]})",
            )
    if raw is not None:
        parsed[(camera_id, raw)] = camera
    return camera


def union_path(file_path) -> tuple[str, str] | None:
    """``(sequence folder, path inside it)`` of a union's frame, whose image lies in a sibling
    folder (``../NAME/…``, as VHAP's ``combine_nerf_datasets.py`` writes it), or None."""
    parts = pathlib.PurePosixPath(file_path).parts if isinstance(file_path, str) else ()
    return (parts[1], "/".join(parts[2:])) if len(parts) > 2 and parts[0] == ".." else None
