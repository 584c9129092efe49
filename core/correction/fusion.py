"""Multi-view fusion: multi-head cross-attention of each view's feature over all views of a timestamp.

Each view's feature asks (query) the features of every view of the timestamp (keys, values),
so its correction is informed by the whole rig.
"""

from __future__ import annotations

import torch
from torch import nn


class MultiViewFusion(nn.Module):
    """``(V, d)`` per-view features → ``(V, d)`` fused per-view features (residual + layer norm)."""

    def __init__(self, feature_dim: int = 64, heads: int = 4):
        super().__init__()
        self.attention = nn.MultiheadAttention(feature_dim, heads, batch_first=True)
        self.norm = nn.LayerNorm(feature_dim)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        tokens = features[None]
        fused, _ = self.attention(tokens, tokens, tokens, need_weights=False)
        return self.norm(features + fused[0])
