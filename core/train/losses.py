"""Training losses: ``0.8·L1 + 0.2·(1 − SSIM)`` on the image, plus the binding hinges.

SSIM and PSNR here are torch twins of :mod:`mogaface.core.metrics.images` (the scores), kept apart
for a reason: they run every step inside autograd (differentiable, no input checks, no mask, no
copy to numpy). The SSIM has the metric's definition, with its window (``SSIM_SIGMA``,
``SSIM_TRUNCATE``: 11 taps), population covariances, data range 1 and the mean over the
border-cropped "valid" area, so the loss optimises what :func:`mogaface.core.metrics.images.ssim`
reports.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from ..metrics.images import SSIM_SIGMA, SSIM_TRUNCATE

SSIM_RADIUS = int(SSIM_TRUNCATE * SSIM_SIGMA + 0.5)  # scikit-image's truncation: 5, 11 taps
_C1 = 0.01**2
_C2 = 0.03**2


def _gaussian_taps(sigma: float = SSIM_SIGMA, radius: int = SSIM_RADIUS) -> torch.Tensor:
    x = torch.arange(-radius, radius + 1, dtype=torch.float64)
    taps = torch.exp(-0.5 * (x / sigma) ** 2)
    return (taps / taps.sum()).float()


_TAPS = _gaussian_taps()


def _blur(x: torch.Tensor) -> torch.Tensor:
    """Separable Gaussian filter of ``(B,C,H,W)`` over the valid area (no padding)."""
    channels = x.shape[1]
    taps = _TAPS.to(x.dtype)
    horizontal = taps.view(1, 1, 1, -1).expand(channels, 1, 1, -1)
    vertical = taps.view(1, 1, -1, 1).expand(channels, 1, -1, 1)
    return F.conv2d(F.conv2d(x, horizontal, groups=channels), vertical, groups=channels)


class _SSIM(torch.autograd.Function):
    """:func:`ssim_torch` by the numba kernels of :mod:`.ssim_kernels` (the prediction differentiated)."""

    @staticmethod
    def forward(ctx, pred, target):
        import numpy as np

        from . import ssim_kernels

        a = np.ascontiguousarray(pred.detach().permute(2, 0, 1).numpy())
        b = np.ascontiguousarray(target.detach().permute(2, 0, 1).numpy())
        c, h, w = a.shape
        radius = SSIM_RADIUS
        derivs = np.empty((c, 3, h - 2 * radius, w - 2 * radius), np.float32)
        total = ssim_kernels.forward(a, b, _TAPS.numpy(), np.float32(_C1), np.float32(_C2), derivs)
        ctx.state = (a, b, derivs)
        return pred.new_tensor(total / derivs[:, 0].size)

    @staticmethod
    def backward(ctx, grad_output):
        import numpy as np

        from . import ssim_kernels

        a, b, derivs = ctx.state
        grad = np.empty_like(a)
        ssim_kernels.backward(a, b, _TAPS.numpy(), derivs, np.float32(float(grad_output) / derivs[:, 0].size), grad)
        return torch.from_numpy(grad).permute(1, 2, 0), None


def ssim(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean SSIM of two ``(H,W,3)`` (or ``(H,W)``) images in [0,1]; differentiable in ``pred``.

    float32 CPU images of at least the window's size go through the numba kernels (forward and
    backward about 4.5x less CPU time than torch's convolutions at 802x550); the rest through
    :func:`ssim_torch`."""
    fast = (pred.dtype == torch.float32 and target.dtype == torch.float32 and not target.requires_grad
            and pred.device.type == "cpu" and min(pred.shape[:2]) > 2 * SSIM_RADIUS)
    if not fast:
        return ssim_torch(pred, target)
    if pred.dim() == 2:
        pred, target = pred[..., None], target[..., None]
    return _SSIM.apply(pred, target)


def ssim_torch(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """:func:`ssim` in torch operations (any dtype, both inputs differentiable): the reference."""
    if pred.dim() == 2:
        pred, target = pred[..., None], target[..., None]
    a = pred.permute(2, 0, 1)[None]
    b = target.permute(2, 0, 1)[None]
    stacked = _blur(torch.cat([a, b, a * a, b * b, a * b], dim=1))
    c = a.shape[1]
    mu_a, mu_b, aa, bb, ab = stacked.split(c, dim=1)
    var_a = aa - mu_a * mu_a
    var_b = bb - mu_b * mu_b
    cov = ab - mu_a * mu_b
    numerator = (2 * mu_a * mu_b + _C1) * (2 * cov + _C2)
    denominator = (mu_a * mu_a + mu_b * mu_b + _C1) * (var_a + var_b + _C2)
    return (numerator / denominator).mean()


def l1(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    return (pred - target).abs().mean()


def image_loss(pred: torch.Tensor, target: torch.Tensor, ssim_weight: float = 0.2) -> dict[str, torch.Tensor]:
    """``(1 − λ)·L1 + λ·(1 − SSIM)`` and its parts (``l1``, ``ssim``, ``rgb``)."""
    l1_value = l1(pred, target)
    ssim_value = ssim(pred, target)
    rgb = (1 - ssim_weight) * l1_value + ssim_weight * (1 - ssim_value)
    return {"l1": l1_value, "ssim": ssim_value, "rgb": rgb}


def _masked_mean(values: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    """Mean over the rows ``mask`` keeps (all when None; 0 when none): a weighted sum, no gather."""
    if mask is None:
        return values.mean() if values.shape[0] else values.sum() * 0
    weights = mask.to(values.dtype)
    return (values * weights).sum() / weights.sum().clamp_min(1.0)


def position_hinge(local_position: torch.Tensor, threshold: float = 1.0,
                   mask: torch.Tensor | None = None) -> torch.Tensor:
    """Mean ``relu(|μ_local| − threshold)`` over the rows ``mask`` keeps (e.g. the visible Gaussians):
    keeps Gaussians near their triangle (in its units)."""
    return _masked_mean(F.relu(local_position.norm(dim=-1) - threshold), mask)


def scaling_hinge(local_log_scale: torch.Tensor, threshold: float = 0.6,
                  mask: torch.Tensor | None = None) -> torch.Tensor:
    """Mean over the rows ``mask`` keeps of ``|relu(exp(s_local) − threshold)|``: no Gaussian much
    larger than its triangle."""
    return _masked_mean(F.relu(torch.exp(local_log_scale) - threshold).norm(dim=-1), mask)


def opacity_mean(opacity_logit: torch.Tensor) -> torch.Tensor:
    """The mean opacity of every Gaussian: with a budget of Gaussians, the ones the images do not
    need fade until the next pass moves them where they are needed."""
    return torch.sigmoid(opacity_logit).mean()


def size_mean(local_log_scale: torch.Tensor) -> torch.Tensor:
    """The mean local scale (triangle units) of every Gaussian: small splats where the face is flat,
    fewer of them covering each pixel."""
    return torch.exp(local_log_scale).mean()


def psnr(pred: torch.Tensor, target: torch.Tensor) -> float:
    """PSNR in dB (data range 1), for progress reports only."""
    mse = float(((pred.detach() - target) ** 2).mean())
    return float("inf") if mse == 0 else -10.0 * math.log10(mse)
