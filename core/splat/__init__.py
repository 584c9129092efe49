"""The differentiable CPU Gaussian splat engine.

``rasterize(means, quats, scales, opacities, colors, viewmat, K, width, height, background=None)``
renders 3D Gaussians (3DGS semantics) with numba kernels and hand-written gradients. See
``docs/splat.md``.
"""

from .api import SplatOutput, rasterize

__all__ = ["SplatOutput", "rasterize"]
