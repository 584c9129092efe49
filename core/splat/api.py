"""``rasterize``: the one entry point of the splat engine, with input checks and its output type."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..errors import InputError
from .function import Project, Rasterize
from .sh import sh_degree, sh_to_rgb

MAX_COLOR = 1e6  # colours are clamped to [-MAX_COLOR, MAX_COLOR]: composited sums stay finite


@dataclass
class SplatOutput:
    """One rendered view.

    ``rgb (H,W,3)``, ``alpha (H,W)`` (1 - final transmittance), ``depth (H,W)`` (Σ wᵢ zᵢ, the
    alpha-weighted camera depth; divide by ``alpha`` for the expected depth), ``radii (N,) int32``
    (3-sigma screen radius in pixels, 0 = not visible). ``means2d (N,2)`` are the projected centres
    in pixels; when they take part in the graph their gradient is kept, so after ``backward()``
    ``out.means2d.grad`` is dL/d(mean2d), the screen-space positional gradient densification uses.
    """

    rgb: torch.Tensor
    alpha: torch.Tensor
    depth: torch.Tensor
    radii: torch.Tensor
    means2d: torch.Tensor

    @property
    def visible(self) -> torch.Tensor:
        return self.radii > 0


def _tensor(name, value, shape, dtype=torch.float32):
    if not isinstance(value, torch.Tensor):
        raise InputError(None, name, f"expected a torch.Tensor, got {type(value).__name__}")
    if value.dtype != dtype:
        raise InputError(None, name, f"expected dtype {dtype}, got {value.dtype}")
    if value.device.type != "cpu":
        raise InputError(None, name, f"expected a CPU tensor, got device {value.device}")
    if value.dim() != len(shape) or any(want is not None and got != want
                                         for got, want in zip(value.shape, shape)):
        want = "(" + ", ".join("N" if w is None else str(w) for w in shape) + ")"
        raise InputError(None, name, f"expected shape {want}, got {tuple(value.shape)}")
    return value


def _camera(name, value, shape):
    if isinstance(value, torch.Tensor):
        value = value.detach().cpu().double().numpy()
    value = np.ascontiguousarray(value, dtype=np.float64)
    if value.shape != shape:
        raise InputError(None, name, f"expected shape {shape}, got {value.shape}")
    if not np.all(np.isfinite(value)):
        raise InputError(None, name, "expected finite values")
    return value


def rasterize(means, quats, scales, opacities, colors, viewmat, K, width, height,
              background=None) -> SplatOutput:
    """Render Gaussians into a ``height x width`` image from a pinhole camera.

    means (N,3) world; quats (N,4) wxyz, normalised here; scales (N,3) linear; opacities (N,) in
    [0,1]; colors (N,3) RGB or (N,(d+1)^2,3) SH coefficients, d <= 3; viewmat (4,4) world-to-camera
    (OpenCV axes); K (3,3) in pixels; background (3,) or None (black). All float32 tensors;
    gradients reach means, quats, scales, opacities, colors (and background).
    """
    if not isinstance(width, (int, np.integer)) or not isinstance(height, (int, np.integer)) \
            or width < 1 or height < 1:
        raise InputError(None, "width/height", f"expected positive integers, got {width!r}, {height!r}")
    width, height = int(width), int(height)
    means = _tensor("means", means, (None, 3))
    n = means.shape[0]
    quats = _tensor("quats", quats, (n, 4))
    scales = _tensor("scales", scales, (n, 3))
    opacities = _tensor("opacities", opacities, (n,))
    if isinstance(colors, torch.Tensor) and colors.dim() == 3:
        colors = _tensor("colors", colors, (n, None, 3))
        if sh_degree(colors.shape[1]) < 0:
            raise InputError(None, "colors", f"expected (d+1)^2 SH coefficients with d <= 3, got {colors.shape[1]}")
    else:
        colors = _tensor("colors", colors, (n, 3))
    viewmat = _camera("viewmat", viewmat, (4, 4))
    K = _camera("K", K, (3, 3))
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise InputError(None, "K", f"expected positive focal lengths, got fx={K[0, 0]}, fy={K[1, 1]}")
    if background is None:
        background = torch.zeros(3, dtype=torch.float32)
    background = _tensor("background", background, (3,))

    if colors.dim() == 3:
        rot, trans = torch.from_numpy(viewmat[:3, :3]), torch.from_numpy(viewmat[:3, 3])
        campos = (-rot.T @ trans).float()
        colors = sh_to_rgb(colors, means, campos)
    colors = colors.clamp(-MAX_COLOR, MAX_COLOR)
    means2d, conics, depths, cov2d, radii = Project.apply(means, quats, scales, viewmat, K, width, height)
    if means2d.requires_grad:
        means2d.retain_grad()
    rgb, alpha, depth, visible = Rasterize.apply(means2d, conics, colors, opacities, depths, background,
                                                 cov2d, radii, width, height)
    radii = torch.where(visible, radii, torch.zeros_like(radii))
    return SplatOutput(rgb=rgb, alpha=alpha, depth=depth, radii=radii, means2d=means2d)
