"""Texture offsets applied in triangle-local space, then the binding maps the Gaussians to world.

Because ``Δμ, Δs, Δr`` are added to the local parameters before :func:`bound_to_world`, they are
expressed in the triangle's frame and units and move rigidly with the mesh, exactly like the
Gaussians they modulate.
"""

from __future__ import annotations

import torch

from ..avatar.binding import bound_to_world, triangle_frames


def canonical_points(gaussians, canonical_vertices: torch.Tensor, faces: torch.Tensor,
                     centre: torch.Tensor, half_extent: torch.Tensor) -> torch.Tensor:
    """Each Gaussian's position on the canonical (neutral) mesh, scaled into [-1, 1]³ (no gradient)."""
    with torch.no_grad():
        frames = triangle_frames(canonical_vertices, faces)
        means, _, _ = bound_to_world(frames, gaussians.binding, gaussians.local_position,
                                     gaussians.local_log_scale, gaussians.local_rotation)
        return ((means - centre) / half_extent).clamp(-1.0, 1.0)


def world_with_offsets(gaussians, vertices: torch.Tensor, faces: torch.Tensor,
                       offsets: dict[str, torch.Tensor] | None) -> dict[str, torch.Tensor]:
    """:meth:`BoundGaussians.world` with local offsets added first (``offsets`` None: the plain avatar)."""
    if offsets is None:
        return gaussians.world(vertices, faces)
    frames = triangle_frames(vertices, faces)
    means, scales, quats = bound_to_world(
        frames, gaussians.binding,
        gaussians.local_position + offsets["position"],
        gaussians.local_log_scale + offsets["log_scale"],
        gaussians.local_rotation + offsets["rotation"],
    )
    return {
        "means": means,
        "quats": quats,
        "scales": scales,
        "opacities": torch.sigmoid(gaussians.opacity_logit + offsets["opacity"][:, 0]),
        "colors": gaussians.colors(),
    }
