"""Correction targets the avatar makes itself: renders at a known expression offset.

The photometric loss teaches the correction only through the render's gradient with respect to
the mesh, which is weak while the Gaussians are blurry and blind to any offset that every
timestamp shares (the Gaussians, bound to the mesh, follow it). Rendering the current avatar at
``ψ_tracked + ε`` from the encoder's own cameras gives views whose correction is known exactly:
``ε``. Regressing it teaches the encoder to read an expression off an image relative to the
tracked one, which is what it must do on the captured views. No ground truth is involved, and
no captured image other than the encoder's usual inputs.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from .avatar import render_world


def render_views(avatar, vertices: torch.Tensor, cameras, size: int, background) -> torch.Tensor:
    """``(V, 3, size, size)`` renders of a posed mesh as the encoder sees views (no gradient)."""
    images = []
    with torch.no_grad():
        world = avatar.gaussians.world(vertices, avatar.flame.faces)
        for camera in cameras:
            factor = size / max(camera.width, camera.height)
            rgb = render_world(world, camera.scaled(factor) if factor < 1.0 else camera, background).rgb
            image = rgb.permute(2, 0, 1)[None].clamp(0.0, 1.0)
            if image.shape[-2:] != (size, size):
                image = F.interpolate(image, size=(size, size), mode="area")
            images.append(image[0])
    return torch.stack(images)


def rendered_target_loss(model, avatar, params: dict, cameras, size: int, background, offset_std: float,
                         generator: torch.Generator) -> torch.Tensor:
    """Mean squared error of the correction regressed from renders at ``ψ_tracked + ε`` against ``ε``.

    One ``ε ~ N(0, offset_std²)`` per call, shared by the views (one timestamp, one expression);
    the loss trains the encoder, fusion and head only.
    """
    tracked = params["expr"][0].detach()
    offset = torch.randn(tracked.shape, generator=generator) * offset_std
    with torch.no_grad():
        vertices = avatar.posed_vertices({**params, "expr": (tracked + offset)[None]})
    images = render_views(avatar, vertices, cameras, size, background)
    per_view, _ = model.correct(images, tracked)
    return ((per_view - offset[None]) ** 2).mean()
