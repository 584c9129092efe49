"""Refining one frame: K passes of (render at the current parameters, compare with the views,
add the regressed offset); every pass re-renders, so each corrects what the last one left."""

from __future__ import annotations

import numpy as np
import torch

from .groups import add_offset
from .views import camera_tokens, crop_cameras, image_crops, posed, render_crops


@torch.no_grad()
def refine(avatar, refiner, params: dict[str, np.ndarray], cameras, images, background, passes: int = 1
           ) -> list[dict[str, np.ndarray]]:
    """The parameters after each of ``passes`` passes, given full-view ``images`` (H, W, 3) from
    ``cameras``; ``params`` is the start (e.g. the tracked parameters)."""
    n_expr = refiner.spec["n_expr"]
    size = refiner.crop
    history = []
    for _ in range(passes):
        vertices = posed(avatar, params)
        crops = crop_cameras(cameras, vertices, size)
        observed = image_crops(images, cameras, vertices, size, background)
        rendered = render_crops(avatar, vertices, crops, background)
        offsets = refiner(observed[None], rendered[None], camera_tokens(cameras, params)[None])[0]
        params = add_offset(params, offsets.mean(0).numpy().astype(np.float32), n_expr)
        history.append(params)
    return history
