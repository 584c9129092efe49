"""A trained avatar with its MoGaFace modules: the same ``render`` call, texture offsets included.

Evaluation, rendering and Blender call ``render(flame_params, camera, background)``; a parameter
dict may carry the timestamp's image feature as ``"texture_feature"`` (what the texture
attention reads); without it the learned default feature is used (parameter-driven inference).
"""

from __future__ import annotations

import os
import pathlib

import torch

from ..avatar.avatar import Avatar, camera_tensors
from ..splat import SplatOutput, rasterize
from .model import MoGaFace
from .posing import world_with_offsets

MODULES_FILE = "mogaface.pt"
FEATURE_KEY = "texture_feature"


class ModulatedAvatar:
    """:class:`Avatar` plus MoGaFace modules; every other attribute is the avatar's own."""

    def __init__(self, avatar: Avatar, model: MoGaFace):
        self.avatar = avatar
        self.model = model

    def __getattr__(self, name):
        return getattr(self.avatar, name)

    @staticmethod
    def _split(flame_params: dict) -> tuple[dict, torch.Tensor | None]:
        params = dict(flame_params)
        feature = params.pop(FEATURE_KEY, None)
        if feature is not None:
            feature = torch.as_tensor(feature, dtype=torch.float32).reshape(-1)
        return params, feature

    def world_posed(self, vertices: torch.Tensor, feature: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """World Gaussians on a posed mesh, modulated by the texture attention reading ``feature``."""
        faces = self.avatar.flame.faces
        offsets = self.model.texture_offsets(self.avatar.gaussians, faces, feature)
        return world_with_offsets(self.avatar.gaussians, vertices, faces, offsets)

    def world_gaussians(self, flame_params: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        params, feature = self._split(flame_params)
        return self.world_posed(self.avatar.posed_vertices(params), feature)

    def posed_vertices(self, flame_params: dict[str, torch.Tensor]) -> torch.Tensor:
        return self.avatar.posed_vertices(self._split(flame_params)[0])

    def render_posed(self, vertices: torch.Tensor, camera, background=(1.0, 1.0, 1.0),
                     feature: torch.Tensor | None = None) -> SplatOutput:
        return render_world(self.world_posed(vertices, feature), camera, background)

    def render(self, flame_params: dict[str, torch.Tensor], camera, background=(1.0, 1.0, 1.0)) -> SplatOutput:
        return render_world(self.world_gaussians(flame_params), camera, background)


def render_world(world: dict[str, torch.Tensor], camera, background) -> SplatOutput:
    """Splat world Gaussians as ``camera`` sees them."""
    viewmat, K = camera_tensors(camera)
    return rasterize(
        world["means"], world["quats"], world["scales"], world["opacities"], world["colors"],
        viewmat, K, camera.width, camera.height, background=torch.as_tensor(background, dtype=torch.float32),
    )


def load_run_avatar(run_dir: str | os.PathLike):
    """A run's avatar: modulated when the run has MoGaFace modules (``RUN/mogaface.pt``), else plain."""
    run_dir = pathlib.Path(run_dir)
    avatar = Avatar.load(run_dir / "avatar.pt")
    modules = run_dir / MODULES_FILE
    if not modules.exists():
        return avatar
    return ModulatedAvatar(avatar, MoGaFace.load(modules))
