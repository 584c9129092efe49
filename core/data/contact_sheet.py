"""A contact sheet: every view of one timestep of a capture in one image."""

from __future__ import annotations

import numpy as np

from ..errors import CaptureError
from .capture import Capture


def contact_sheet(capture: Capture, timestep: int | None = None, columns: int = 8) -> np.ndarray:
    """Tile the views of ``timestep`` (default: the first) in camera order, ``columns`` per row."""
    timestep = capture.timesteps[0] if timestep is None else int(timestep)
    frames = sorted((f for f in capture.frames() if f.timestep_index == timestep), key=lambda f: f.camera_index)
    if not frames:
        raise CaptureError(capture.root, "timestep_index", f"no frames for timestep {timestep}")
    images = [capture.load_image(f)[0] for f in frames]
    height = max(i.shape[0] for i in images)
    width = max(i.shape[1] for i in images)
    rows = -(-len(images) // columns)
    sheet = np.ones((rows * height, min(columns, len(images)) * width, 3), dtype=np.float32)
    for k, image in enumerate(images):
        r, c = divmod(k, columns)
        sheet[r * height : r * height + image.shape[0], c * width : c * width + image.shape[1]] = image[..., :3]
    return sheet
