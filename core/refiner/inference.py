"""Refining one frame: K passes of (render at the current parameters, compare with the views,
solve for the offset from the pooled features, then Gauss–Newton steps from the full-size crops
at that answer), in the head windows of the start. Every pass re-renders, so each corrects
what the last one left; in a run of several passes a pass is kept only when it lowers the
photometric error on the views it was given (else half of it is tried), so extra passes cannot
walk away from what the images support.

A single pass is taken as solved, unchecked: its check would render every view again and double
its time, and on unseen frames the check kept every first pass in full
(docs/notebook/2026-11-26-multiview-refiner.md). Two or more passes check every pass, the first
included."""

from __future__ import annotations

import numpy as np
import torch

from ..errors import InputError
from .groups import add_offset, flatten
from .views import crop_cameras, full_size_gradient, image_crop, pooled_difference, posed, render_crop


def _known_views(refiner, cameras, images):
    kept = [(c, im) for c, im in zip(cameras, images) if refiner.knows(c.camera_id)]
    if not kept:
        raise InputError(None, "camera", f"none of the views' cameras ({[c.camera_id for c in cameras]}) is one "
                                         f"the refiner was trained for ({refiner.camera_ids})")
    return [c for c, _ in kept], [im for _, im in kept]


def _error(observed, rendered) -> float:
    return float(np.mean([(o - r).abs().mean() for o, r in zip(observed, rendered)]))


@torch.no_grad()
def refine(avatar, refiner, params: dict[str, np.ndarray], cameras, images, background, passes: int = 1
           ) -> list[dict[str, np.ndarray]]:
    """The parameters after each of ``passes`` passes, given full-view ``images`` (H, W, 3) from
    ``cameras``; ``params`` is the start (e.g. the tracked parameters). Views from cameras the
    refiner was not trained for are not used. A single pass is not checked (module docstring)."""
    n_expr = refiner.spec["n_expr"]
    cameras, images = _known_views(refiner, cameras, images)
    ids = [c.camera_id for c in cameras]
    history = []
    head = posed(avatar, params)
    crops = crop_cameras(cameras, head.vertices, refiner.spec["render_limit"])
    observed = [image_crop(image, crop, background) for image, crop in zip(images, crops)]
    rendered = [render_crop(head, crop, background) for crop in crops]
    error = _error(observed, rendered)
    for done in range(passes):
        features = torch.stack([pooled_difference(o, r, refiner.grid) for o, r in zip(observed, rendered)])
        solved = add_offset(params, refiner.offset(features, ids), n_expr)
        for _ in range(refiner.full_size_steps(ids)):
            gradient = full_size_gradient(avatar, solved, crops, observed, background, n_expr)
            solved = add_offset(solved, refiner.full_size_offset(gradient, ids), n_expr)
        if passes == 1:
            return [solved]
        move = flatten(solved, n_expr) - flatten(params, n_expr)
        for share in (1.0, 0.5):  # keep the step only where the views agree it helps (same windows)
            candidate = add_offset(params, move * share, n_expr)
            moved = posed(avatar, candidate)
            candidate_renders = [render_crop(moved, crop, background) for crop in crops]
            candidate_error = _error(observed, candidate_renders)
            if candidate_error < error:
                params, rendered, error = candidate, candidate_renders, candidate_error
                break
        else:  # the images support no further step: later passes would solve the same system again
            return history + [params] * (passes - done)
        history.append(params)
    return history
