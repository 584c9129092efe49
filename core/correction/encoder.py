"""The view encoder: a small convolutional net from one downsampled view image to a feature ``F_i``.

Kept tiny (four stride-2 convolutions and one linear layer) so that encoding eight views per
training step costs a few milliseconds on two CPU cores; the spatial map is flattened rather
than pooled so the feature still knows *where* the mouth and eyes moved.
"""

from __future__ import annotations

import torch
from torch import nn


class ViewEncoder(nn.Module):
    """``(B, 3, S, S)`` images in [0, 1] → ``(B, feature_dim)`` features."""

    def __init__(self, input_size: int = 128, feature_dim: int = 64, width: int = 16):
        super().__init__()
        channels = [3, width, 2 * width, 4 * width, 4 * width]
        layers = []
        for c_in, c_out in zip(channels[:-1], channels[1:]):
            layers += [nn.Conv2d(c_in, c_out, 3, stride=2, padding=1), nn.ReLU(inplace=True)]
        self.convs = nn.Sequential(*layers)
        side = input_size
        for _ in range(4):
            side = (side + 1) // 2
        self.input_size = input_size
        self.project = nn.Linear(channels[-1] * side * side, feature_dim)
        self.feature_dim = feature_dim

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        x = self.convs(images * 2.0 - 1.0)
        return self.project(x.flatten(1))
