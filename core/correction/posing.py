"""Texture offsets applied in triangle-local space, then the binding maps the Gaussians to world.

Because ``Δμ, Δs, Δr`` are added to the local parameters before :func:`bound_to_world`, they are
expressed in the triangle's frame and units and move rigidly with the mesh, exactly like the
Gaussians they modulate.
"""

from __future__ import annotations

import torch

from ..avatar.binding import TriangleFrames, bound_to_world, triangle_frames


def canonical_points(gaussians, frames: TriangleFrames, centre: torch.Tensor,
                     half_extent: torch.Tensor) -> torch.Tensor:
    """Each Gaussian's position on the canonical (neutral) mesh with triangle ``frames``, scaled
    into [-1, 1]³ (no gradient: the triplane is read there, it does not move the Gaussians)."""
    with torch.no_grad():
        binding = gaussians.binding
        local = gaussians.local_position
        means = frames.scale[binding][:, None] * (frames.rotation[binding] @ local[..., None])[..., 0] \
            + frames.centroid[binding]
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
