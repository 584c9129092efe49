"""A frame's posed Gaussians as point data for Blender (positions and per-point attributes).

For users who want the Gaussians themselves in the scene (Geometry Nodes, instancing, other
renderers); the exact picture stays the splat engine's. Values are those a render rasterizes
(:meth:`Avatar.world_gaussians`), in the head object's local Blender axes.
"""

from __future__ import annotations

import numpy as np

from .avatar import load_avatar
from .axes import flame_to_blender

#: The FLAME → Blender axis change (+90° about x) as a unit quaternion (w, x, y, z).
FLAME_TO_BLENDER_QUAT = np.array([np.sqrt(0.5), np.sqrt(0.5), 0.0, 0.0])
SH_C0 = 0.28209479177387814


def quaternion_product(a, b) -> np.ndarray:
    """Hamilton product of quaternions (w, x, y, z), broadcast over leading axes."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a, np.float64), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, np.float64), -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def gaussian_points(avatar_path, values: dict) -> dict:
    """``position (N,3)``, ``scale (N,3)``, ``rotation (N,4)`` wxyz, ``opacity (N,)``, ``color (N,4)`` RGBA.

    ``values``: what the head shows (as in a render request). Colour is the view-independent
    part (the SH DC term) in sRGB values, alpha 1; float32 arrays, Blender axes.
    """
    import torch

    from ..avatar.avatar import flame_params_to_torch
    from .render import fitted_params

    avatar = load_avatar(avatar_path)
    with torch.no_grad():
        world = avatar.world_gaussians(flame_params_to_torch(fitted_params(values, avatar)))
    colors = world["colors"].numpy()
    rgb = colors if colors.ndim == 2 else SH_C0 * colors[:, 0] + 0.5
    quats = world["quats"].numpy().astype(np.float64)
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    n = len(quats)
    return {
        "position": flame_to_blender(world["means"].numpy()).astype(np.float32),
        "scale": world["scales"].numpy().astype(np.float32),
        "rotation": quaternion_product(FLAME_TO_BLENDER_QUAT, quats).astype(np.float32),
        "opacity": world["opacities"].numpy().astype(np.float32).reshape(n),
        "color": np.concatenate([np.clip(rgb, 0.0, 1.0), np.ones((n, 1))], axis=1).astype(np.float32),
    }
