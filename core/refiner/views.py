"""One frame's views as the refiner sees them: per view the observed head crop, the avatar's
render in the same window at the current parameters (no gradient), and the camera's token."""

from __future__ import annotations

import numpy as np
import torch

from ..avatar.avatar import flame_params_to_torch
from .crops import crop_camera, crop_image, head_window
from .network import camera_in_head_frame


@torch.no_grad()
def posed(avatar, params: dict[str, np.ndarray]) -> torch.Tensor:
    return avatar.posed_vertices(flame_params_to_torch(params))


@torch.no_grad()
def crop_cameras(cameras, vertices: torch.Tensor, size: int) -> list:
    """Per camera, the crop camera of the head's window at these vertices."""
    points = vertices.numpy()
    return [crop_camera(c, head_window(c, points), size) for c in cameras]


@torch.no_grad()
def render_crops(avatar, vertices: torch.Tensor, crops, background) -> torch.Tensor:
    """``(V, 3, S, S)`` renders of the posed avatar in each crop camera."""
    return torch.stack([avatar.render_posed(vertices, c, background).rgb.clamp(0, 1).permute(2, 0, 1) for c in crops])


@torch.no_grad()
def image_crops(images, cameras, vertices: torch.Tensor, size: int, background) -> torch.Tensor:
    """``(V, 3, S, S)``: each full-view image cut to its head window."""
    points = vertices.numpy()
    return torch.stack([crop_image(img, head_window(c, points), size, background) for img, c in zip(images, cameras)])


def camera_tokens(cameras, params: dict[str, np.ndarray]) -> torch.Tensor:
    w2c = torch.as_tensor(np.stack([c.w2c for c in cameras]), dtype=torch.float32)
    return camera_in_head_frame(w2c, torch.as_tensor(params["rotation"], dtype=torch.float32),
                                torch.as_tensor(params["translation"], dtype=torch.float32))
