"""Training offsets: a new random offset for every rendered observation, so the refiner learns how
the image answers a parameter change rather than recognising frames.

An offset is Gaussian noise of each group's expected error (:mod:`.groups`) times ``width``, the
whole offset scaled by a magnitude drawn uniformly in ``magnitude`` (so the small residuals a later
pass sees are as common as a tracker's full error). ``groups`` limits the offsets to some groups
(the others stay zero), e.g. the head's translation alone.
"""

from __future__ import annotations

import numpy as np

from .groups import group_sizes, scale_vector


class OffsetSampler:
    def __init__(self, n_expr: int, width: float = 1.0, magnitude: tuple[float, float] = (0.3, 1.5), seed: int = 0,
                 groups: tuple[str, ...] | None = None):
        self.scales = scale_vector(n_expr).numpy().astype(np.float64)
        self.width = width
        self.magnitude = magnitude
        self.rng = np.random.default_rng(seed)
        sizes = group_sizes(n_expr)
        chosen = tuple(sizes) if groups is None else tuple(groups)
        self.mask = np.concatenate([np.full(size, name in chosen, np.float64) for name, size in sizes.items()])

    def __call__(self) -> np.ndarray:
        """One flat offset (:func:`.groups.flatten` order), in the parameters' units."""
        size = self.rng.uniform(*self.magnitude) * self.width
        return (self.rng.normal(size=len(self.scales)) * self.scales * self.mask * size).astype(np.float32)
