"""Latent texture attention: a triplane read at each Gaussian's canonical position, fused with the
timestamp's image feature by a light attention block, decoded by a multi-head MLP into per-Gaussian
offsets ``Δμ (3), Δs (3), Δr (4), Δα (1)`` in the Gaussian's triangle-local space.

The image feature is split into a few tokens; each Gaussian's triplane descriptor queries them
(one head of dot-product attention), so what the views show modulates each Gaussian differently.
Every output head starts at zero: an untrained module changes nothing.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

OFFSET_SIZES = {"position": 3, "log_scale": 3, "rotation": 4, "opacity": 1}


class LatentTextureAttention(nn.Module):
    """Canonical points ``(N, 3)`` in [-1, 1]³ and an image feature ``(d,)`` → offsets per Gaussian."""

    def __init__(self, feature_dim: int = 64, plane_size: int = 64, plane_dim: int = 16, hidden: int = 32,
                 tokens: int = 4):
        super().__init__()
        self.planes = nn.Parameter(0.1 * torch.randn(3, plane_dim, plane_size, plane_size,
                                                     generator=torch.Generator().manual_seed(0)))
        self.tokens, self.hidden_dim = tokens, hidden
        self.to_tokens = nn.Linear(feature_dim, tokens * hidden)
        self.query = nn.Linear(3 * plane_dim, hidden)
        self.mix = nn.Sequential(nn.Linear(3 * plane_dim + hidden, hidden), nn.ReLU(inplace=True))
        self.heads = nn.ModuleDict({name: nn.Linear(hidden, size) for name, size in OFFSET_SIZES.items()})
        for head in self.heads.values():
            nn.init.zeros_(head.weight)
            nn.init.zeros_(head.bias)

    def sample(self, points: torch.Tensor) -> torch.Tensor:
        """``h(p) = H_xy(p_xy) ⊕ H_xz(p_xz) ⊕ H_yz(p_yz)``: ``(N, 3·plane_dim)``."""
        x, y, z = points.unbind(-1)
        grid = torch.stack([torch.stack([x, y], -1), torch.stack([x, z], -1), torch.stack([y, z], -1)])
        sampled = F.grid_sample(self.planes, grid[:, None], mode="bilinear", padding_mode="border",
                                align_corners=False)  # (3, C, 1, N)
        return sampled[:, :, 0].permute(2, 0, 1).reshape(points.shape[0], -1)

    def forward(self, points: torch.Tensor, feature: torch.Tensor) -> dict[str, torch.Tensor]:
        h = self.sample(points)
        tokens = self.to_tokens(feature.reshape(-1)).view(self.tokens, self.hidden_dim)
        scores = self.query(h) @ tokens.T / math.sqrt(self.hidden_dim)  # (N, tokens)
        attended = scores.softmax(-1) @ tokens  # (N, hidden)
        v = self.mix(torch.cat([h, attended], dim=1))
        return {name: head(v) for name, head in self.heads.items()}
