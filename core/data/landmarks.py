"""2D facial landmarks of a capture, in the layout VHAP's tracker writes them.

VHAP detects 68 iBUG points per image (STAR by default, or face-alignment) and keeps them in its
preprocessing folder, one file per camera, ``landmark2d/STAR/<camera id>.npz`` (a monocular
sequence: one file, ``landmark2d/STAR.npz``). Its export does not copy them; a user copies that
``landmark2d`` folder into the capture. Each file holds

- ``face_landmark_2d`` (N,68,3): x / image width, y / image height (origin top left), confidence;
  a frame with no face found is a row of −1;
- ``bounding_box`` (N,5): x1, y1, x2, y2 (pixels), score (optional here).

Row ``i`` is the sequence's ``i``-th timestep, which is the capture's ``timestep_index`` of a
single-sequence export. A union of sequences (VHAP's ``combine_nerf_datasets.py``: frames in the
sibling sequence folders, timesteps numbered across them) reads each sequence folder's own
``landmark2d/``, row by the timestep that folder's split files give the frame, and places it at the
union's index; landmark files in the union folder itself, numbered as the union, are read first.
"""

from __future__ import annotations

import os
import pathlib

import numpy as np

from ..errors import InputError
from ..flame.landmarks import IBUG_COUNT
from ..io.npz import load_npz, save_npz

LANDMARK_DIR = "landmark2d"
DETECTORS = ("STAR", "face-alignment")  # VHAP's subfolders, in the order they are looked for


def landmark_files(root, camera_ids) -> dict[str, pathlib.Path]:
    """The landmark file of each camera that has one (``root/landmark2d/…``)."""
    folder = pathlib.Path(root) / LANDMARK_DIR
    found = {}
    for camera_id in camera_ids:
        for candidate in [folder / d / f"{camera_id}.npz" for d in DETECTORS] + [folder / f"{camera_id}.npz"]:
            if candidate.is_file():
                found[camera_id] = candidate
                break
    if not found and len(camera_ids) == 1:  # a monocular sequence: one file named after the detector
        for d in DETECTORS:
            if (folder / f"{d}.npz").is_file():
                found[next(iter(camera_ids))] = folder / f"{d}.npz"
                break
    return found


def read_landmark_file(path, width: int, height: int, timesteps: int) -> np.ndarray:
    """``(timesteps, 68, 3)``: x, y in pixels of a ``width`` × ``height`` image, and a weight in
    [0, 1] (0 where no face was found). ``timesteps`` is how many rows the capture needs."""
    arrays = load_npz(path)
    if "face_landmark_2d" not in arrays:
        raise InputError(path, "face_landmark_2d", f"missing (keys: {sorted(arrays)})")
    points = np.asarray(arrays["face_landmark_2d"], np.float64)
    if points.ndim != 3 or points.shape[1:] != (IBUG_COUNT, 3):
        raise InputError(path, "face_landmark_2d", f"expected shape (N, {IBUG_COUNT}, 3), found {points.shape}")
    if len(points) < timesteps:
        raise InputError(path, "face_landmark_2d", f"{len(points)} rows for a capture of {timesteps} timesteps "
                                                   "(landmarks of another sequence, or of part of it?)")
    points = points[:timesteps]
    if not np.all(np.isfinite(points)):
        raise InputError(path, "face_landmark_2d", "holds NaN or infinite values")
    missing = np.any(points[..., :2] == -1, axis=(1, 2))  # VHAP's row of −1: no face in that frame
    xy = points[..., :2] * np.array([width, height])
    weight = np.where(missing[:, None], 0.0, np.clip(points[..., 2], 0.0, 1.0))
    return np.concatenate([xy, weight[..., None]], -1)


def read_landmarks(root, cameras: dict, timesteps: int) -> dict[str, np.ndarray]:
    """Every camera's landmarks that the capture holds (see :func:`read_landmark_file`)."""
    files = landmark_files(root, sorted(cameras))
    return {cid: read_landmark_file(path, cameras[cid].width, cameras[cid].height, timesteps)
            for cid, path in files.items()}


def capture_landmarks(capture, cameras: dict) -> dict[str, np.ndarray]:
    """Every camera's landmarks as rows of ``capture``'s timestep indices (rows of weight 0 where
    no file covers the frame): the capture's own ``landmark2d/``, or, for a union of sequences,
    each sequence folder's (see the module's docstring)."""
    from .capture import Capture
    from .capture_entries import union_path

    steps = max(f.timestep_index for f in capture.frames()) + 1
    own = read_landmarks(capture.root, cameras, steps)
    if own:
        return own
    sequences: dict[pathlib.Path, list] = {}  # a union's sequence folder → (frame, path inside it)
    for frame in capture.frames():
        if (where := union_path(frame.file_path)) is not None:
            folder = pathlib.Path(os.path.normpath(capture.root / ".." / where[0]))
            sequences.setdefault(folder, []).append((frame, where[1]))
    rows: dict[str, np.ndarray] = {}
    for folder, frames in sequences.items():
        if not (folder / LANDMARK_DIR).is_dir():
            continue
        local = {f.file_path: f.timestep_index for f in Capture.open(folder).frames()}
        found = read_landmarks(folder, cameras, max(local.values()) + 1)
        for frame, inside in frames:
            if frame.camera_id not in found:
                continue
            if inside not in local:
                raise InputError(folder, inside, f"the union's frame {frame.file_path} is not listed in the "
                                                 "sequence folder's own split files (no landmark row to take)")
            rows.setdefault(frame.camera_id, np.zeros((steps, IBUG_COUNT, 3)))[frame.timestep_index] = (
                found[frame.camera_id][local[inside]])
    return rows


def write_landmark_file(root, camera_id: str, pixels: np.ndarray, width: int, height: int,
                        detector: str = DETECTORS[0]) -> pathlib.Path:
    """Write ``(N,68,3)`` landmarks (x, y in pixels, confidence) as VHAP does:
    ``landmark2d/<detector>/<camera id>.npz``, coordinates divided by the image size."""
    pixels = np.asarray(pixels, np.float64)
    if pixels.ndim != 3 or pixels.shape[1:] != (IBUG_COUNT, 3):
        raise ValueError(f"expected landmarks of shape (N, {IBUG_COUNT}, 3), got {pixels.shape}")
    normalised = pixels / np.array([width, height, 1.0])
    box = np.concatenate([pixels[..., :2].min(1), pixels[..., :2].max(1), np.ones((len(pixels), 1))], 1)
    path = pathlib.Path(root) / LANDMARK_DIR / detector / f"{camera_id}.npz"
    path.parent.mkdir(parents=True, exist_ok=True)
    save_npz(path, {"bounding_box": box.astype(np.float32), "face_landmark_2d": normalised.astype(np.float32)})
    return path
