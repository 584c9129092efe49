"""Real spherical harmonics (degrees 0-3) in the 3DGS convention, in torch (autograd does the rest)."""

from __future__ import annotations

import torch

C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
      0.5462742152960396)
C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
      -0.4570457994644658, 1.445305721320277, -0.5900435899266435)


def sh_basis(dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """The ``(degree+1)^2`` basis values for unit directions ``dirs (N,3)``, 3DGS signs and order."""
    x, y, z = dirs.unbind(-1)
    out = [torch.full_like(x, C0)]
    if degree >= 1:
        out += [-C1 * y, C1 * z, -C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        out += [C2[0] * x * y, C2[1] * y * z, C2[2] * (2 * zz - xx - yy), C2[3] * x * z,
                C2[4] * (xx - yy)]
    if degree >= 3:
        out += [C3[0] * y * (3 * xx - yy), C3[1] * x * y * z, C3[2] * y * (4 * zz - xx - yy),
                C3[3] * z * (2 * zz - 3 * xx - 3 * yy), C3[4] * x * (4 * zz - xx - yy),
                C3[5] * z * (xx - yy), C3[6] * x * (xx - 3 * yy)]
    return torch.stack(out, -1)


def sh_degree(n_coeffs: int) -> int:
    """Degree d with ``(d+1)^2 == n_coeffs``, or -1."""
    for d in range(4):
        if (d + 1) ** 2 == n_coeffs:
            return d
    return -1


def sh_to_rgb(coeffs: torch.Tensor, means: torch.Tensor, campos: torch.Tensor) -> torch.Tensor:
    """Colours ``(N,3)`` of SH ``coeffs (N,(d+1)^2,3)`` seen along the ray camera -> mean:
    ``max(Σ basis·coeff + 0.5, 0)``, as 3DGS stores and renders them."""
    degree = sh_degree(coeffs.shape[1])
    dirs = means - campos.to(means.dtype)
    dirs = dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    basis = sh_basis(dirs, degree).to(coeffs.dtype)
    return (torch.einsum("nk,nkc->nc", basis, coeffs) + 0.5).clamp_min(0.0)
