"""LPIPS v0.1 with the AlexNet backbone (Zhang et al. 2018) in plain torch.

The network is torchvision's AlexNet ``features`` (five convolutions, ReLU taps after
each); LPIPS shifts and scales the input, unit-normalises each tap over channels, weighs
the squared differences with its learned 1x1 heads, averages over space and sums the
five layers. Differentiable, so it can serve as a loss as well as a metric.
"""

from __future__ import annotations

import functools

import torch
from torch import nn

from . import lpips_weights

# LPIPS' ScalingLayer constants, applied to inputs in [-1, 1].
_SHIFT = (-0.030, -0.088, -0.188)
_SCALE = (0.458, 0.448, 0.450)


class AlexNetTaps(nn.Module):
    """AlexNet's convolutional trunk; returns the five ReLU outputs LPIPS compares."""

    def __init__(self):
        super().__init__()
        self.convs = nn.ModuleList(
            [
                nn.Conv2d(3, 64, 11, stride=4, padding=2),
                nn.Conv2d(64, 192, 5, padding=2),
                nn.Conv2d(192, 384, 3, padding=1),
                nn.Conv2d(384, 256, 3, padding=1),
                nn.Conv2d(256, 256, 3, padding=1),
            ]
        )
        self.pool = nn.MaxPool2d(3, stride=2)

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        taps = []
        for index, conv in enumerate(self.convs):
            if index in (1, 2):  # max-pool after the first two taps, as in torchvision's features
                x = self.pool(x)
            x = torch.relu(conv(x))
            taps.append(x)
        return taps


def _unit_channels(x: torch.Tensor, eps: float = 1e-10) -> torch.Tensor:
    return x / (torch.sqrt(torch.sum(x * x, dim=1, keepdim=True)) + eps)


class LPIPSAlex(nn.Module):
    """LPIPS distance between image batches ``(N, 3, H, W)`` in [0, 1]; returns ``(N,)``."""

    def __init__(self):
        super().__init__()
        self.net = AlexNetTaps()
        self.heads = nn.ModuleList([nn.Conv2d(conv.out_channels, 1, 1, bias=False) for conv in self.net.convs])
        self.register_buffer("shift", torch.tensor(_SHIFT).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(_SCALE).view(1, 3, 1, 1))
        self.requires_grad_(False)
        self.eval()

    def load_weights(self, backbone: list, heads: list) -> "LPIPSAlex":
        """Set the weights from ``lpips_weights.read_backbone`` / ``read_heads`` arrays."""
        with torch.no_grad():
            for conv, (weight, bias) in zip(self.net.convs, backbone):
                conv.weight.copy_(torch.from_numpy(weight))
                conv.bias.copy_(torch.from_numpy(bias))
            for head, weight in zip(self.heads, heads):
                head.weight.copy_(torch.from_numpy(weight))
        return self

    def forward(self, x0: torch.Tensor, x1: torch.Tensor) -> torch.Tensor:
        taps0 = self.net(((2 * x0 - 1) - self.shift) / self.scale)
        taps1 = self.net(((2 * x1 - 1) - self.shift) / self.scale)
        total = 0
        for head, f0, f1 in zip(self.heads, taps0, taps1):
            diff = (_unit_channels(f0) - _unit_channels(f1)) ** 2
            total = total + head(diff).mean(dim=(2, 3))
        return total[:, 0]


@functools.lru_cache(maxsize=2)
def _cached_model(backbone_path: str, heads_path: str) -> LPIPSAlex:
    return LPIPSAlex().load_weights(lpips_weights.read_backbone(backbone_path), lpips_weights.read_heads(heads_path))


def load_lpips_alex() -> LPIPSAlex:
    """The LPIPS model with verified weights (built once per weights path and process).

    Raises ``InputError`` saying how to get the weights when they are missing or wrong.
    """
    backbone = lpips_weights.find_backbone()
    heads = lpips_weights.find_heads(backbone)
    return _cached_model(str(backbone), str(heads))
