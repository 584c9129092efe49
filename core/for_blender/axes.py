"""Where the project's conventions meet Blender's: world axes, camera axes, timeline, pixel rows.

The one axis conversion (FLAME/OpenCV world, y up → Blender world, z up), scene frames ↔
timesteps, and images ↔ Blender's bottom-to-top pixel rows.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError

# -- axes ---------------------------------------------------------------------------------------

#: FLAME world (y up, z toward the face's front) → Blender world (z up): +90° about x, so
#: FLAME +y → Blender +z and FLAME +z (the face's front) → Blender −y (the usual front view).
FLAME_TO_BLENDER = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])

# OpenCV camera axes (x right, y down, z forward) ↔ Blender camera axes (x right, y up, z back).
CV_TO_BLENDER_CAMERA = np.diag([1.0, -1.0, -1.0, 1.0])


def flame_to_blender(points) -> np.ndarray:
    """Points or directions ``(…,3)`` in FLAME world axes → Blender world axes (float64).

    The single place where the project's y-up world meets Blender's z-up world; every
    position that crosses into Blender (mesh vertices, shape keys, cameras) goes through it.
    """
    return np.asarray(points, dtype=np.float64) @ FLAME_TO_BLENDER.T


def blender_to_flame(points) -> np.ndarray:
    """The inverse of :func:`flame_to_blender`."""
    return np.asarray(points, dtype=np.float64) @ FLAME_TO_BLENDER


def flame_to_blender_matrix(matrix) -> np.ndarray:
    """A 4×4 transform whose output is in FLAME world → the same transform into Blender world."""
    world = np.eye(4)
    world[:3, :3] = FLAME_TO_BLENDER
    return world @ np.asarray(matrix, dtype=np.float64)


# -- timeline -----------------------------------------------------------------------------------

#: Blender's timeline starts at frame 1: timestep ``t`` is shown on frame ``t + FRAME_OFFSET``.
FRAME_OFFSET = 1


def timestep_to_frame(timestep: int) -> int:
    """The scene frame that shows capture/tracking timestep ``timestep``."""
    return int(timestep) + FRAME_OFFSET


def frame_to_timestep(frame: int) -> int:
    """The timestep shown on scene frame ``frame``."""
    return int(frame) - FRAME_OFFSET


# -- images -------------------------------------------------------------------------------------


def image_pixels(image) -> np.ndarray:
    """An ``(H,W,3|4)`` image (uint8, or float in [0,1]) → Blender's flat RGBA float32 pixels.

    Blender stores rows bottom to top; our images are top to bottom.
    """
    array = np.asarray(image)
    if array.ndim != 3 or array.shape[2] not in (3, 4):
        raise InputError(None, "texture", f"expected an (H, W, 3|4) image, found shape {array.shape}")
    values = array.astype(np.float32) / 255.0 if array.dtype == np.uint8 else array.astype(np.float32)
    if values.shape[2] == 3:
        values = np.concatenate([values, np.ones(values.shape[:2] + (1,), np.float32)], axis=2)
    return np.ascontiguousarray(values[::-1]).reshape(-1)
