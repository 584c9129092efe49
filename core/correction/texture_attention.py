"""Latent texture attention: a triplane read at each Gaussian's canonical position, fused with the
frame's FLAME code by a light attention block, decoded by a multi-head MLP into per-Gaussian
offsets ``Δμ (3), Δs (3), Δr (4), Δα (1)`` in the Gaussian's triangle-local space.

The code (:func:`flame_code`: the corrected expression and the jaw, neck and eye rotations) is split
into a few tokens; each Gaussian's triplane descriptor queries them (one head of dot-product
attention), so the expression modulates each Gaussian differently. The paper conditions on the
timestamp's image feature instead; a per-timestamp input lets the module learn a per-frame
correction that no parameter reproduces (it absorbed the tracker's frame-by-frame misalignment
here) and leaves it nothing to animate with on a new frame. Read from the parameters, the
texture follows whichever parameters drive the avatar. Every output head starts at zero: an
untrained module changes nothing.

The forward is written for 100k Gaussians on a CPU: the triplane read by numba kernels
(:mod:`.triplane_kernels`), the query folded into the tokens (``q(h)·k = h·(W_qᵀk) + b_q·k``, a
``(3C, tokens)`` matrix instead of an ``(N, hidden)`` one), the attended tokens folded into the mix
layer's weights, and the four heads as one matrix: the same function as the layers read one by
one (:meth:`LatentTextureAttention.forward_layers`, the reference), with the same parameters, in
less than half the time.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

OFFSET_SIZES = {"position": 3, "log_scale": 3, "rotation": 4, "opacity": 1}
# The FLAME parameters the texture reads, and their sizes besides the expression's. The global
# rotation and the translation move the head rigidly and do not change how it looks.
CODE_JOINTS = {"jaw_pose": 3, "neck_pose": 3, "eyes_pose": 6}


def code_size(n_expr: int) -> int:
    return n_expr + sum(CODE_JOINTS.values())


def flame_code(params: dict, n_expr: int) -> torch.Tensor:
    """``(code_size,)``: one frame's expression (first ``n_expr`` coefficients) and jaw, neck and eye
    rotations from a FLAME parameter dict (batch 1; differentiable)."""
    from ..errors import InputError

    parts = []
    for name, size in {"expr": n_expr, **CODE_JOINTS}.items():
        if name not in params:
            raise InputError(None, name, "the texture attention needs this FLAME parameter")
        value = torch.as_tensor(params[name], dtype=torch.float32).reshape(-1)
        if value.numel() < size:
            raise InputError(None, name, f"expected at least {size} values, got {value.numel()}")
        parts.append(value[:size])
    return torch.cat(parts)


class LatentTextureAttention(nn.Module):
    """Canonical points ``(N, 3)`` in [-1, 1]³ and a FLAME code ``(code_dim,)`` → offsets per Gaussian."""

    def __init__(self, code_dim: int, plane_size: int = 64, plane_dim: int = 16, hidden: int = 32,
                 tokens: int = 4):
        super().__init__()
        self.planes = nn.Parameter(0.1 * torch.randn(3, plane_dim, plane_size, plane_size,
                                                     generator=torch.Generator().manual_seed(0)))
        self.tokens, self.hidden_dim = tokens, hidden
        self.to_tokens = nn.Linear(code_dim, tokens * hidden)
        self.query = nn.Linear(3 * plane_dim, hidden)
        self.mix = nn.Sequential(nn.Linear(3 * plane_dim + hidden, hidden), nn.ReLU(inplace=True))
        self.heads = nn.ModuleDict({name: nn.Linear(hidden, size) for name, size in OFFSET_SIZES.items()})
        for head in self.heads.values():
            nn.init.zeros_(head.weight)
            nn.init.zeros_(head.bias)

    def sample(self, points: torch.Tensor) -> torch.Tensor:
        """``h(p) = H_xy(p_xy) ⊕ H_xz(p_xz) ⊕ H_yz(p_yz)``: ``(N, 3·plane_dim)``.

        float32 CPU points without gradient go through the numba kernels; the rest through
        :meth:`sample_torch`."""
        fast = (points.dtype == torch.float32 and self.planes.dtype == torch.float32
                and points.device.type == "cpu" and not points.requires_grad)
        return _TriplaneRead.apply(self.planes, points) if fast else self.sample_torch(points)

    def sample_torch(self, points: torch.Tensor) -> torch.Tensor:
        """:meth:`sample` by ``F.grid_sample`` (any dtype, points differentiable): the reference."""
        x, y, z = points.unbind(-1)
        grid = torch.stack([torch.stack([x, y], -1), torch.stack([x, z], -1), torch.stack([y, z], -1)])
        sampled = F.grid_sample(self.planes, grid[:, None], mode="bilinear", padding_mode="border",
                                align_corners=False)  # (3, C, 1, N)
        return sampled[:, :, 0].permute(2, 0, 1).reshape(points.shape[0], -1)

    def forward(self, points: torch.Tensor, code: torch.Tensor) -> dict[str, torch.Tensor]:
        h = self.sample(points)
        tokens = self.to_tokens(code.reshape(-1)).view(self.tokens, self.hidden_dim)
        keys = tokens.T / math.sqrt(self.hidden_dim)  # (hidden, tokens)
        mix = self.mix[0]
        into_h, into_attended = mix.weight.split([h.shape[1], self.hidden_dim], dim=1)
        # h read once for the attention's scores and its own share of the mix layer
        scores, mixed = torch.addmm(torch.cat([self.query.bias @ keys, mix.bias]), h,
                                    torch.cat([self.query.weight.T @ keys, into_h.T], dim=1)
                                    ).split([self.tokens, self.hidden_dim], dim=1)
        v = torch.addmm(mixed, scores.softmax(-1), tokens @ into_attended.T).relu_()
        heads = self.heads.values()
        out = torch.addmm(torch.cat([head.bias for head in heads]), v,
                          torch.cat([head.weight for head in heads]).T)
        return dict(zip(self.heads.keys(), out.split([head.out_features for head in heads], dim=1)))

    def forward_layers(self, points: torch.Tensor, code: torch.Tensor) -> dict[str, torch.Tensor]:
        """:meth:`forward` layer by layer, as the module is described: the reference."""
        h = self.sample_torch(points)
        tokens = self.to_tokens(code.reshape(-1)).view(self.tokens, self.hidden_dim)
        scores = self.query(h) @ tokens.T / math.sqrt(self.hidden_dim)  # (N, tokens)
        attended = scores.softmax(-1) @ tokens  # (N, hidden)
        v = self.mix(torch.cat([h, attended], dim=1))
        return {name: head(v) for name, head in self.heads.items()}


class _TriplaneRead(torch.autograd.Function):
    """:meth:`LatentTextureAttention.sample_torch` by the kernels of :mod:`.triplane_kernels` (the
    planes differentiated, the points not)."""

    @staticmethod
    def forward(ctx, planes, points):
        from . import triplane_kernels

        flat = points.detach().contiguous()
        out = torch.empty(len(flat), planes.shape[0] * planes.shape[1], dtype=torch.float32)
        triplane_kernels.forward(planes.detach().permute(0, 2, 3, 1).contiguous().numpy(), flat.numpy(),
                                 out.numpy())
        ctx.save_for_backward(flat)
        ctx.plane_shape = planes.shape
        return out

    @staticmethod
    def backward(ctx, grad_out):
        from . import triplane_kernels

        (points,) = ctx.saved_tensors
        planes, channels, size, _ = ctx.plane_shape
        grad = torch.empty(planes, size, size, channels, dtype=torch.float32)
        triplane_kernels.backward(points.numpy(), grad_out.contiguous().numpy(), size, grad.numpy())
        return grad.permute(0, 3, 1, 2), None
