"""The per-frame parameters the refiner regresses, and the scale of each group.

A group's scale is the error a tracker typically makes on it (the default capture's tracker:
expression 0.4 + bias 0.3 per coefficient, rotations 8 + 6 mrad, translation 0.8 + 0.6 mm). The
network's outputs are multiples of these scales and the loss is measured in them, so every group
weighs the same however different its units.
"""

from __future__ import annotations

import numpy as np
import torch

# name -> (count, or None for the model's expression count; expected error)
GROUPS: dict[str, tuple[int | None, float]] = {
    "expr": (None, 0.5),
    "rotation": (3, 0.01),
    "neck_pose": (3, 0.01),
    "jaw_pose": (3, 0.01),
    "eyes_pose": (6, 0.01),
    "translation": (3, 0.001),
}


def group_sizes(n_expr: int) -> dict[str, int]:
    return {name: (n_expr if count is None else count) for name, (count, _) in GROUPS.items()}


def scale_vector(n_expr: int) -> torch.Tensor:
    """Each regressed value's expected error, in the order of :func:`flatten`."""
    return torch.cat([torch.full((size,), GROUPS[name][1]) for name, size in group_sizes(n_expr).items()])


def flatten(params: dict[str, np.ndarray], n_expr: int) -> np.ndarray:
    """The regressed groups of one frame's parameters as one vector (float32)."""
    return np.concatenate([np.asarray(params[name], np.float32).reshape(-1)[:size]
                           for name, size in group_sizes(n_expr).items()]).astype(np.float32)


def split(offset, n_expr: int) -> dict:
    """A flat offset (numpy or torch) as ``{group: its slice}``, in :func:`flatten` order."""
    parts, start = {}, 0
    for name, size in group_sizes(n_expr).items():
        parts[name] = offset[start:start + size]
        start += size
    return parts


def add_offset(params: dict[str, np.ndarray], offset: np.ndarray, n_expr: int) -> dict[str, np.ndarray]:
    """``params`` with a flat offset added to the regressed groups (others kept as they are)."""
    return {**params, **{name: (np.asarray(params[name], np.float32) + part).astype(np.float32)
                         for name, part in split(offset, n_expr).items()}}
