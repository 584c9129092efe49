"""One frame's views as the refiner sees them: per view the head's window, the observed crop and the
avatar's render in the same window at the current parameters (no gradient), and their difference
area-pooled to the refiner's grid; and, for the full-size step, the gradient of the crops' squared
difference with respect to the regressed parameters.

Crops are rendered at the window's own pixel size (up to ``render_limit``) and pooled afterwards:
a Gaussian avatar rendered directly at a few dozen pixels is not the area average of its
full-size render, and that difference swamped the sub-pixel signal the refiner reads.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch
import torch.nn.functional as F

from ..avatar.avatar import flame_params_to_torch
from ..correction.avatar import render_world
from .crops import crop_camera, crop_image, head_window
from .groups import scale_vector, split


@dataclasses.dataclass(frozen=True)
class PosedHead:
    """The mesh and the world Gaussians at one set of parameters: posed once, rendered in every crop."""

    vertices: torch.Tensor
    world: dict[str, torch.Tensor]


def _pose(avatar, flame_params: dict[str, torch.Tensor]) -> PosedHead:
    vertices = avatar.posed_vertices(flame_params)
    return PosedHead(vertices, avatar.world_posed(vertices, flame_params))


@torch.no_grad()
def posed(avatar, params: dict[str, np.ndarray]) -> PosedHead:
    """The avatar at ``params``, with whatever of its appearance follows them (texture attention)."""
    return _pose(avatar, flame_params_to_torch(params))


@torch.no_grad()
def crop_cameras(cameras, vertices: torch.Tensor, render_limit: int) -> list:
    """Per camera, the crop camera of the head's window at these vertices, at the window's pixel size."""
    points = vertices.numpy()
    crops = []
    for camera in cameras:
        window = head_window(camera, points)
        crops.append((window, crop_camera(camera, window, min(render_limit, max(8, math.ceil(window.side))))))
    return crops


def _render(head: PosedHead, crop, background) -> torch.Tensor:
    return render_world(head.world, crop[1], background).rgb.clamp(0, 1).permute(2, 0, 1)


@torch.no_grad()
def render_crop(head: PosedHead, crop, background) -> torch.Tensor:
    """``(3, S, S)`` render of the posed avatar in one crop camera."""
    return _render(head, crop, background)


@torch.no_grad()
def image_crop(image, crop, background) -> torch.Tensor:
    """``(3, S, S)``: a full-view image cut to the crop's window, at the crop's size."""
    return crop_image(image, crop[0], crop[1].width, background)


def pooled_difference(observed: torch.Tensor, rendered: torch.Tensor, grid: int) -> torch.Tensor:
    """The refiner's feature of one view: ``(3·grid²,)``."""
    return F.adaptive_avg_pool2d((observed - rendered)[None], grid).flatten()


def full_size_gradient(avatar, params: dict[str, np.ndarray], crops, observed, background, n_expr: int
                       ) -> torch.Tensor:
    """``Σ_v J_vᵀ(o_v − r_v) / pixels_v`` at ``params``, in the refiner's units (each group's
    expected error): what every full-size pixel of the crops says about the parameters, where the
    pooled features keep only each cell's mean. One render and one backward per view."""
    scales = scale_vector(n_expr)
    offset = torch.zeros(len(scales), requires_grad=True)
    flame_params = flame_params_to_torch(params)
    with torch.enable_grad():
        for name, part in split(offset * scales, n_expr).items():
            flame_params[name] = flame_params[name] + part[None]
        head = _pose(avatar, flame_params)
        loss = sum(((_render(head, crop, background) - seen) ** 2).sum() / (2 * crop[1].width * crop[1].height)
                   for crop, seen in zip(crops, observed))
        (gradient,) = torch.autograd.grad(loss, offset)
    return -gradient.detach()
