"""Training offsets: a new random offset every step, wider than a tracker's error, across
expression space, so the refiner learns to read offsets rather than recognise frames.

An offset is, per group, Gaussian noise of ``width`` times the group's scale times a magnitude
drawn uniformly in [0, 1] per sample (so small residuals, what later passes see, are as common
as large ones). With probability ``jump``, the expression instead jumps to a random combination
of components (each coefficient drawn from the training expressions' spread), not only the
neighbourhood of the frame's own expression. ``groups`` limits the offsets to some groups (the
others stay zero), e.g. a refiner of head pose alone.
"""

from __future__ import annotations

import numpy as np

from .groups import group_sizes, scale_vector


class OffsetSampler:
    def __init__(self, n_expr: int, expr_spread: np.ndarray | None = None, width: float = 2.0,
                 jump: float = 0.3, seed: int = 0, groups: tuple[str, ...] | None = None):
        self.n_expr = n_expr
        self.scales = scale_vector(n_expr).numpy().astype(np.float64)
        self.expr_spread = None if expr_spread is None else np.asarray(expr_spread, np.float64)
        self.width = width
        self.jump = jump
        self.rng = np.random.default_rng(seed)
        self.sizes = group_sizes(n_expr)
        self.groups = tuple(self.sizes) if groups is None else tuple(groups)

    def __call__(self, start: np.ndarray) -> np.ndarray:
        """One offset for a frame whose regressed values are ``start`` (flat, :func:`.groups.flatten`)."""
        offset = np.empty_like(self.scales)
        at = 0
        for name, size in self.sizes.items():
            magnitude = self.rng.uniform(0.0, 1.0) if name in self.groups else 0.0
            offset[at:at + size] = self.rng.normal(size=size) * self.scales[at:at + size] * self.width * magnitude
            at += size
        if "expr" in self.groups and self.expr_spread is not None and self.rng.uniform() < self.jump:
            target = self.rng.normal(size=self.n_expr) * self.expr_spread
            offset[:self.n_expr] = target - start[:self.n_expr]
        return offset.astype(np.float32)
