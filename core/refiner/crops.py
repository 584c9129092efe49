"""The head crop of one view: where the head projects, as a crop camera (renders come out
already cropped, at the crop's size, for the price of the crop) and the same window cut from
an image of the full view.

The window is a square around the projected mesh at the current parameters, widened by
``margin``; outside the image it is the background colour, as the render's would be.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch
import torch.nn.functional as F

from ..camera import Camera


@dataclasses.dataclass(frozen=True)
class Window:
    """A square of the full image: top-left corner and side, in pixels."""

    x0: float
    y0: float
    side: float


def head_window(camera: Camera, vertices: np.ndarray, margin: float = 1.15) -> Window:
    uv, _ = camera.project(np.asarray(vertices, np.float64))
    low, high = uv.min(0), uv.max(0)
    centre = 0.5 * (low + high)
    side = float(max(high - low) * margin)
    return Window(float(centre[0] - side / 2), float(centre[1] - side / 2), max(side, 1.0))


def crop_camera(camera: Camera, window: Window, size: int) -> Camera:
    """The camera whose ``size``² image is ``window`` of ``camera``'s image."""
    zoom = size / window.side
    K = camera.K.copy()
    K[0, 0] *= zoom
    K[1, 1] *= zoom
    K[0, 2] = (K[0, 2] - window.x0) * zoom
    K[1, 2] = (K[1, 2] - window.y0) * zoom
    return Camera(K, camera.w2c.copy(), size, size, camera.camera_id)


def crop_image(image: np.ndarray | torch.Tensor, window: Window, size: int, background) -> torch.Tensor:
    """``(3, size, size)``: ``window`` of an ``(H, W, 3)`` image, area-averaged then resampled."""
    rgb = torch.as_tensor(np.array(image, np.float32)).permute(2, 0, 1)[None]
    bg = torch.as_tensor(background, dtype=torch.float32).reshape(1, 3, 1, 1)
    shrink = max(1, int(window.side // size))
    if shrink > 1:
        rgb = F.avg_pool2d(rgb, shrink, ceil_mode=True)
    height, width = rgb.shape[-2] * shrink, rgb.shape[-1] * shrink  # the full image's pixels it spans
    # pixel centres of the crop, in the (possibly shrunk) image's normalised coordinates
    steps = (torch.arange(size, dtype=torch.float32) + 0.5) * window.side / size
    xs = (window.x0 + steps) / width * 2.0 - 1.0
    ys = (window.y0 + steps) / height * 2.0 - 1.0
    grid = torch.stack(torch.meshgrid(ys, xs, indexing="ij")[::-1], dim=-1)[None]
    out = F.grid_sample(rgb - bg, grid, mode="bilinear", padding_mode="zeros", align_corners=False) + bg
    return out[0].clamp(0.0, 1.0)
