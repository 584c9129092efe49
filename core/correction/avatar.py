"""A trained avatar with its MoGaFace modules: the same ``render`` call, texture offsets included.

Evaluation, rendering and Blender call ``render(flame_params, camera, background)``; the texture
attention reads the same parameters (expression, jaw, neck, eyes), so the avatar's appearance
follows whichever parameters drive it (tracked, smoothed, fitted, keyed in Blender). A run's
avatar is loaded by :meth:`~..run.folder.RunFolder.load_avatar`, which wraps it whenever the run
has modules.
"""

from __future__ import annotations

import torch

from ..avatar.avatar import Avatar, camera_tensors
from ..splat import SplatOutput, rasterize
from .model import MoGaFace
from .posing import world_with_offsets


class ModulatedAvatar:
    """:class:`Avatar` plus MoGaFace modules; every other attribute is the avatar's own."""

    def __init__(self, avatar: Avatar, model: MoGaFace):
        self.avatar = avatar
        self.model = model

    def __getattr__(self, name):
        return getattr(self.avatar, name)

    def world_posed(self, vertices: torch.Tensor, flame_params: dict) -> dict[str, torch.Tensor]:
        """World Gaussians on the mesh ``vertices`` posed by ``flame_params``, modulated by the
        texture attention reading those parameters."""
        faces = self.avatar.flame.faces
        offsets = self.model.texture_offsets(self.avatar.gaussians, faces, flame_params)
        return world_with_offsets(self.avatar.gaussians, vertices, faces, offsets)

    def world_gaussians(self, flame_params: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        return self.world_posed(self.avatar.posed_vertices(flame_params), flame_params)

    def render(self, flame_params: dict[str, torch.Tensor], camera, background=(1.0, 1.0, 1.0),
               vertex_shift=None) -> SplatOutput:
        vertices = self.avatar.posed_vertices(flame_params)
        vertices = vertices if vertex_shift is None else vertices + vertex_shift
        return render_world(self.world_posed(vertices, flame_params), camera, background)


def render_world(world: dict[str, torch.Tensor], camera, background) -> SplatOutput:
    """Splat world Gaussians as ``camera`` sees them."""
    viewmat, K = camera_tensors(camera)
    return rasterize(
        world["means"], world["quats"], world["scales"], world["opacities"], world["colors"],
        viewmat, K, camera.width, camera.height, background=torch.as_tensor(background, dtype=torch.float32),
    )

