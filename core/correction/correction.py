"""The correction head: an MLP from a fused view feature (and the tracked expression) to ``Δψ``.

The tracked expression is an input too, so the head can express "the image says ψ, the tracker
said ψ_tracked" as a correction; its last layer starts at zero, so training starts exactly at
the tracked expressions (the Freeze baseline).
"""

from __future__ import annotations

import torch
from torch import nn


class CorrectionHead(nn.Module):
    """``(V, d)`` fused features, ``(n_expr,)`` tracked expression → ``(V, n_expr)`` corrections."""

    def __init__(self, feature_dim: int, n_expr: int, hidden: int = 128):
        super().__init__()
        self.hidden = nn.Sequential(nn.Linear(feature_dim + n_expr, hidden), nn.ReLU(inplace=True),
                                    nn.Linear(hidden, hidden), nn.ReLU(inplace=True))
        self.out = nn.Linear(hidden, n_expr)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def forward(self, fused: torch.Tensor, tracked_expr: torch.Tensor) -> torch.Tensor:
        tracked = tracked_expr.reshape(1, -1).expand(fused.shape[0], -1)
        return self.out(self.hidden(torch.cat([fused, tracked], dim=1)))
