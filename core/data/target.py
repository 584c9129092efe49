"""A view's ground truth as the methods that read images see it: the captured image on the training
background (scoring compares a render with it; the refiner and test-time fitting read it)."""

from __future__ import annotations

import numpy as np

from .capture import Capture, Frame


def target_image(capture: Capture, frame: Frame, background, capture_background=None) -> np.ndarray:
    """The ground truth on the training background: as stored when the capture was recorded on
    that background, else composited onto it through the foreground mask."""
    rgb, mask = capture.load_image(frame)
    if capture_background is not None and np.allclose(capture_background, background):
        return np.asarray(rgb, dtype=np.float32)
    bg = np.asarray(background, dtype=np.float32)
    return (rgb * mask[..., None] + bg * (1.0 - mask[..., None])).astype(np.float32)


def area_resized(image, width: int, height: int):
    """An ``(H,W,3)`` torch image averaged down to ``(height,width,3)``: each pixel the mean of the
    area it covers (a training view and test-time fitting at a camera's scaled size)."""
    import torch

    scaled = torch.nn.functional.interpolate(image.permute(2, 0, 1)[None], size=(height, width), mode="area")
    return scaled[0].permute(1, 2, 0).contiguous()
