"""A camera's colour as an affine map of the avatar's colours, applied to a render over its background.

Real rigs disagree in colour (white balance, exposure); a run can learn, per training camera, an
affine colour ``c ↦ M·c + b`` (``core/train/camera_colour.py``) and evaluation can fit one for the
held-out camera (``core/evaluate/camera_alignment.py``). Either is held as its **change** from the
identity, a ``(3, 4)`` array ``[M − I | b]``, so that the identity is exactly zero and a render
through it is the render itself, bit for bit.

The map acts on the foreground only. A render over ``background`` with coverage ``α`` is
``rgb = F + (1 − α)·bg`` (``F``: the premultiplied foreground, ``Σ wᵢ cᵢ`` over the Gaussians);
recoloured it is ``M·F + α·b + (1 − α)·bg``: every Gaussian's colour mapped by the affine, the
background left as it is (a white background stays white).
"""

from __future__ import annotations

import math
import os

import numpy as np
import torch

from ..errors import InputError

IDENTITY = np.zeros((3, 4))  # the change of a camera that sees the avatar's own colours


def recolour(rgb: torch.Tensor, alpha: torch.Tensor, background, change) -> torch.Tensor:
    """``rgb (H,W,3)`` rendered over ``background`` with coverage ``alpha (H,W)``, its foreground
    mapped by ``change`` (``[M − I | b]``, ``(3, 4)``); differentiable in all three tensors."""
    change = torch.as_tensor(change, dtype=rgb.dtype)
    bg = torch.as_tensor(background, dtype=rgb.dtype)
    coverage = alpha[..., None]
    foreground = rgb - (1.0 - coverage) * bg
    return rgb + foreground @ change[:, :3].T + coverage * change[:, 3]


def matrix_and_offset(change) -> tuple[np.ndarray, np.ndarray]:
    """``(M (3,3), b (3,))`` of a change ``[M − I | b]``."""
    change = np.asarray(change, np.float64)
    return change[:, :3] + np.eye(3), change[:, 3].copy()


def read_camera_colours(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """A ``camera_colours.json``: camera id → ``{"matrix": 3×3, "offset": 3}``, as changes ``(3, 4)``."""
    from ..io.jsonfile import read_json_object

    changes = {}
    for camera_id, entry in read_json_object(path).items():
        if not isinstance(entry, dict) or set(entry) != {"matrix", "offset"}:
            raise InputError(path, camera_id, "expected {\"matrix\": 3×3 numbers, \"offset\": 3 numbers}")
        matrix, offset = _numbers(entry["matrix"], (3, 3)), _numbers(entry["offset"], (3,))
        if matrix is None or offset is None:
            raise InputError(path, camera_id, "expected a 3×3 matrix and 3 offsets of finite numbers")
        changes[str(camera_id)] = np.concatenate([matrix - np.eye(3), offset[:, None]], axis=1)
    return changes


def colour_entry(change) -> dict:
    """One camera's entry of a ``camera_colours.json``."""
    matrix, offset = matrix_and_offset(change)
    return {"matrix": matrix.tolist(), "offset": offset.tolist()}


def _numbers(value, shape: tuple[int, ...]) -> np.ndarray | None:
    """``value`` as a float array of ``shape`` (``(n,)`` or ``(m, n)``), or None when it is not one of
    finite numbers."""
    rows = value if len(shape) == 2 else [value]
    if not isinstance(rows, list) or len(rows) != (shape[0] if len(shape) == 2 else 1):
        return None
    for row in rows:
        if not isinstance(row, list) or len(row) != shape[-1] or any(
                isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) for x in row):
            return None
    return np.asarray(rows, np.float64).reshape(shape)
