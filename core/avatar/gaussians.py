"""The trainable Gaussians of an avatar, stored in their triangles' local space."""

from __future__ import annotations

import math

import torch

from ..errors import InputError
from .binding import bound_to_world, triangle_frames

SH_C0 = 0.28209479177387814  # the degree-0 spherical harmonic: colour = SH_C0·dc + 0.5
PARAMETER_NAMES = ("local_position", "local_log_scale", "local_rotation", "opacity_logit", "sh_dc", "sh_rest")


def rgb_to_sh_dc(rgb: torch.Tensor) -> torch.Tensor:
    return (rgb - 0.5) / SH_C0


class BoundGaussians(torch.nn.Module):
    """Gaussians bound to mesh triangles: ``binding`` (triangle id) plus local parameters.

    Parameters (one row per Gaussian): ``local_position (N,3)``, ``local_log_scale (N,3)``,
    ``local_rotation (N,4)`` wxyz, ``opacity_logit (N,)``, ``sh_dc (N,1,3)``,
    ``sh_rest (N,(D+1)²−1,3)`` for the maximum degree ``D``; ``active_sh_degree`` ≤ D says
    how many are used (raised on a schedule while training).
    """

    def __init__(self, binding: torch.Tensor, max_sh_degree: int = 3, **parameters: torch.Tensor):
        super().__init__()
        if not 0 <= max_sh_degree <= 3:
            raise InputError(None, "max_sh_degree", f"must lie in [0, 3], got {max_sh_degree}")
        self.max_sh_degree = max_sh_degree
        self.active_sh_degree = 0
        self.register_buffer("binding", binding.long())
        n = len(binding)
        rest = (max_sh_degree + 1) ** 2 - 1
        shapes = {
            "local_position": (n, 3),
            "local_log_scale": (n, 3),
            "local_rotation": (n, 4),
            "opacity_logit": (n,),
            "sh_dc": (n, 1, 3),
            "sh_rest": (n, rest, 3),
        }
        for name, shape in shapes.items():
            value = parameters.get(name)
            if value is None:
                raise InputError(None, name, "missing Gaussian parameter")
            if tuple(value.shape) != shape:
                raise InputError(None, name, f"expected shape {shape}, found {tuple(value.shape)}")
            setattr(self, name, torch.nn.Parameter(value.detach().float().clone()))

    @classmethod
    def one_per_triangle(
        cls, n_faces: int, max_sh_degree: int = 3, opacity: float = 0.1, color: float = 0.5
    ) -> "BoundGaussians":
        """One Gaussian at each triangle's centroid, the triangle's size, grey, faint."""
        n = n_faces
        rotation = torch.zeros(n, 4)
        rotation[:, 0] = 1
        return cls(
            torch.arange(n),
            max_sh_degree,
            local_position=torch.zeros(n, 3),
            local_log_scale=torch.zeros(n, 3),
            local_rotation=rotation,
            opacity_logit=torch.full((n,), math.log(opacity / (1 - opacity))),
            sh_dc=rgb_to_sh_dc(torch.full((n, 1, 3), color)),
            sh_rest=torch.zeros(n, (max_sh_degree + 1) ** 2 - 1, 3),
        )

    def __len__(self) -> int:
        return len(self.binding)

    def tensors(self) -> dict[str, torch.Tensor]:
        """Every per-Gaussian tensor by name (parameters and ``binding``), for saving and editing."""
        return {"binding": self.binding, **{name: getattr(self, name) for name in PARAMETER_NAMES}}

    def param_groups(self, lr, position_lr: float) -> list[dict]:
        """The optimiser's groups, one per parameter and named after it (densification edits them
        by name). ``lr``: the ``[lr]`` settings; ``position_lr``: the position rate of this step."""
        rates = {"local_position": position_lr, "local_log_scale": lr.scaling, "local_rotation": lr.rotation,
                 "opacity_logit": lr.opacity, "sh_dc": lr.color, "sh_rest": lr.color * lr.color_rest_ratio}
        return [{"params": [getattr(self, name)], "lr": rates[name], "name": name} for name in PARAMETER_NAMES]

    def colors(self) -> torch.Tensor:
        """SH coefficients of the active degree, ``(N,(d+1)²,3)``."""
        used = (self.active_sh_degree + 1) ** 2 - 1
        return torch.cat([self.sh_dc, self.sh_rest[:, :used]], dim=1)

    def world(self, vertices: torch.Tensor, faces: torch.Tensor) -> dict[str, torch.Tensor]:
        """World-space Gaussians on the posed mesh ``vertices (V,3)``: the splat engine's inputs."""
        frames = triangle_frames(vertices, faces)
        means, scales, quats = bound_to_world(
            frames, self.binding, self.local_position, self.local_log_scale, self.local_rotation
        )
        return {
            "means": means,
            "quats": quats,
            "scales": scales,
            "opacities": torch.sigmoid(self.opacity_logit),
            "colors": self.colors(),
        }
