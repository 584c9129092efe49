"""The refiner network: per view, the captured crop beside the avatar's render at the current
parameters; a convolutional encoder with group normalisation; a token from where the camera looks
at the head from; attention over the views; per-view offsets, averaged over views.

Outputs are multiples of each group's expected error (:mod:`.groups`) and start at exactly zero
(last layer zero-initialised): an untrained refiner returns its input.
"""

from __future__ import annotations

import torch
from torch import nn

from ..flame.lbs import axis_angle_to_matrix
from .groups import scale_vector

SPEC_KEYS = ("crop", "width", "feature_dim", "heads", "layers", "n_expr")


def _block(c_in: int, c_out: int) -> list[nn.Module]:
    return [nn.Conv2d(c_in, c_out, 3, stride=2, padding=1), nn.GroupNorm(8, c_out), nn.ReLU(inplace=True)]


class CropEncoder(nn.Module):
    """``(B, 9, S, S)`` (observed, rendered, their difference) → ``(B, d)``; five stride-2 blocks,
    a 3×3 map flattened so the feature keeps where things moved, plus a linear read of the
    difference image at 12×12 (the active-appearance-model shortcut: an offset is first of all a
    linear function of the difference, which this path learns within a few steps)."""

    def __init__(self, crop: int, width: int, feature_dim: int):
        super().__init__()
        channels = [9, width, 2 * width, 3 * width, 4 * width, 4 * width]
        self.convs = nn.Sequential(*[m for a, b in zip(channels[:-1], channels[1:]) for m in _block(a, b)])
        self.pool = nn.AdaptiveAvgPool2d(3)
        self.project = nn.Linear(channels[-1] * 9, feature_dim)
        self.difference_pool = nn.AdaptiveAvgPool2d(12)
        self.direct = nn.Linear(3 * 144, feature_dim)

    def forward(self, observed: torch.Tensor, rendered: torch.Tensor) -> torch.Tensor:
        difference = 4.0 * (observed - rendered)
        x = torch.cat([observed * 2 - 1, rendered * 2 - 1, difference], dim=1)
        return self.project(self.pool(self.convs(x)).flatten(1)) + self.direct(self.difference_pool(difference).flatten(1))


def camera_in_head_frame(w2c: torch.Tensor, rotation: torch.Tensor, translation: torch.Tensor) -> torch.Tensor:
    """``(V, 10)``: each camera's direction and distance from the head, its viewing and down axes,
    in the head's own frame (FLAME global rotation and translation)."""
    head = axis_angle_to_matrix(rotation.reshape(1, 3))[0]
    cam_rot = w2c[:, :3, :3]
    centre = -(cam_rot.transpose(1, 2) @ w2c[:, :3, 3:])[..., 0]
    local = (centre - translation.reshape(1, 3)) @ head
    distance = local.norm(dim=1, keepdim=True).clamp_min(1e-6)
    forward = cam_rot[:, 2] @ head
    down = cam_rot[:, 1] @ head
    return torch.cat([local / distance, distance, forward, down], dim=1)


class Refiner(nn.Module):
    def __init__(self, spec: dict):
        super().__init__()
        self.spec = {k: spec[k] for k in SPEC_KEYS}
        d = spec["feature_dim"]
        self.encoder = CropEncoder(spec["crop"], spec["width"], d)
        self.camera_token = nn.Sequential(nn.Linear(10, d), nn.ReLU(), nn.Linear(d, d))
        layer = nn.TransformerEncoderLayer(d, spec["heads"], 2 * d, dropout=0.0, batch_first=True, norm_first=True)
        self.fusion = nn.TransformerEncoder(layer, spec["layers"], enable_nested_tensor=False)
        self.register_buffer("scales", scale_vector(spec["n_expr"]))
        self.head = nn.Sequential(nn.LayerNorm(d), nn.Linear(d, d), nn.ReLU(), nn.Linear(d, len(self.scales)))
        nn.init.zeros_(self.head[-1].weight)
        nn.init.zeros_(self.head[-1].bias)

    @property
    def crop(self) -> int:
        return self.spec["crop"]

    def forward(self, observed: torch.Tensor, rendered: torch.Tensor, cameras: torch.Tensor) -> torch.Tensor:
        """``(B, V, 3, S, S)`` crops and ``(B, V, 10)`` camera tokens → ``(B, V, n)`` per-view offsets in
        the parameters' units (average over views for the frame's offset)."""
        b, v = observed.shape[:2]
        features = self.encoder(observed.flatten(0, 1), rendered.flatten(0, 1)).reshape(b, v, -1)
        fused = self.fusion(features + self.camera_token(cameras))
        return self.head(fused) * self.scales
