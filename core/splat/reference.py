"""Pure-torch reference of the engine's semantics (autograd, slow): for tests and benchmarks only.

Same maths as the numba engine written the plain way: every pixel against every splat, depth
sorted, transmittance by cumulative product. Works in the dtype of ``means`` (use float64 for
checks). ``band_rows`` renders horizontal bands one at a time against the splats whose support
reaches them (optionally under gradient checkpointing) so larger scenes fit in memory.
"""

from __future__ import annotations

import math

import torch
from torch.utils.checkpoint import checkpoint

from .projection import BLUR, FAR, MAX_OFFSET, NEAR
from .raster import ALPHA_MAX, T_MIN
from .sh import sh_to_rgb
from .tiles import ALPHA_MIN, SIGMAS


def quat_to_rotmat(q: torch.Tensor) -> torch.Tensor:
    q = q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], -1).reshape(q.shape[:-1] + (3, 3))


def project(means, quats, scales, viewmat, K, width, height):
    """``means2d, conics (a, b, c), depths, cov2d (xx, xy, yy), radii, valid`` of every Gaussian."""
    dt = means.dtype
    V = torch.as_tensor(viewmat, dtype=dt)
    K = torch.as_tensor(K, dtype=dt)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    t = means @ V[:3, :3].T + V[:3, 3]
    valid = (t[:, 2] > NEAR) & (t[:, 2] < FAR) & torch.isfinite(t).all(-1)
    z = torch.where(valid, t[:, 2], torch.ones_like(t[:, 2]))
    tx, ty = torch.where(valid, t[:, 0], 0.0), torch.where(valid, t[:, 1], 0.0)
    R = quat_to_rotmat(quats.to(dt))
    M = R * scales.to(dt)[:, None, :]
    cov3 = M @ M.transpose(1, 2)
    lxp, lxn = (width - cx) / fx + 0.3 * width / fx, cx / fx + 0.3 * width / fx
    lyp, lyn = (height - cy) / fy + 0.3 * height / fy, cy / fy + 0.3 * height / fy
    u = torch.minimum(torch.maximum(tx / z, -lxn), lxp)
    v = torch.minimum(torch.maximum(ty / z, -lyn), lyp)
    zero = torch.zeros_like(z)
    J = torch.stack([fx / z, zero, -fx * u / z, zero, fy / z, -fy * v / z], -1).reshape(-1, 2, 3)
    A = J @ V[:3, :3]
    cov2 = A @ cov3 @ A.transpose(1, 2) + BLUR * torch.eye(2, dtype=dt)
    sxx, sxy, syy = cov2[:, 0, 0], cov2[:, 0, 1], cov2[:, 1, 1]
    det = sxx * syy - sxy * sxy
    valid = valid & (det > 0) & torch.isfinite(det)
    det = torch.where(valid, det, torch.ones_like(det))
    conics = torch.stack([syy / det, -sxy / det, sxx / det], -1)
    means2d = torch.stack([fx * tx / z + cx, fy * ty / z + cy], -1)
    centre = torch.tensor([0.5 * width, 0.5 * height], dtype=dt)
    valid = valid & ((means2d.detach() - centre).abs() < MAX_OFFSET).all(-1)
    with torch.no_grad():
        mid = 0.5 * (sxx + syy)
        lam = mid + (mid * mid - det).clamp_min(0).sqrt()
        radii = torch.where(valid, torch.ceil(3 * lam.sqrt()).clamp_max(2**30), 0).to(torch.int32)
    return means2d, conics, z, torch.stack([sxx, sxy, syy], -1).detach(), radii, valid


def support_q(opacities):
    """Largest Mahalanobis² distance where a splat still counts (<= 0: never); see ``tiles``."""
    q = 2 * torch.log((255.0 * opacities.detach().double()).clamp_min(1e-30))
    return torch.where(opacities.detach() > ALPHA_MIN, q.clamp_max(SIGMAS * SIGMAS), -1.0)


def visible_bounds(means2d, cov2d, opacities, valid, width, height):
    """The engine's visibility: the (slightly widened) support box reaches a pixel centre."""
    q = support_q(opacities)
    qm = q * 1.001 + 0.01
    c = cov2d.double()
    m = means2d.detach().double()
    ex, ey = (qm * c[:, 0]).clamp_min(0).sqrt(), (qm * c[:, 2]).clamp_min(0).sqrt()
    j0 = torch.ceil((m[:, 0] - ex).clamp_min(-1) - 0.5).clamp_min(0)
    j1 = torch.floor((m[:, 0] + ex).clamp_max(width + 1) - 0.5).clamp_max(width - 1)
    i0 = torch.ceil((m[:, 1] - ey).clamp_min(-1) - 0.5).clamp_min(0)
    i1 = torch.floor((m[:, 1] + ey).clamp_max(height + 1) - 0.5).clamp_max(height - 1)
    vis = valid & (q > 0) & (j0 <= j1) & (i0 <= i1)
    return vis, i0, i1


def _composite(px, py, means2d, conics, opacities, colors, depths, background):
    """Front-to-back compositing of depth-sorted splats at pixel centres ``px, py (P,)``."""
    dx = px[:, None] - means2d[None, :, 0]
    dy = py[:, None] - means2d[None, :, 1]
    q = conics[:, 0] * dx * dx + 2 * conics[:, 1] * dx * dy + conics[:, 2] * dy * dy
    alpha = (opacities * torch.exp(-0.5 * q)).clamp_max(ALPHA_MAX)
    with torch.no_grad():
        ok = (q <= SIGMAS * SIGMAS) & (alpha >= ALPHA_MIN)
        t_incl = torch.cumprod(1 - torch.where(ok, alpha, 0), dim=1)
        ok = ok & (t_incl >= T_MIN)
    alpha = torch.where(ok, alpha, 0)
    one_minus = 1 - alpha
    T = torch.cumprod(torch.cat([torch.ones_like(one_minus[:, :1]), one_minus[:, :-1]], 1), 1)
    w = alpha * T
    t_final = torch.prod(one_minus, 1)
    rgb = w @ colors + t_final[:, None] * background
    return rgb, 1 - t_final, w @ depths


def rasterize_reference(means, quats, scales, opacities, colors, viewmat, K, width, height,
                        background=None, band_rows=None, use_checkpoint=False):
    """Same signature and outputs as ``rasterize`` (a dict), plus ``means2d`` with its grad kept."""
    dt = means.dtype
    viewmat = torch.as_tensor(viewmat, dtype=dt)
    if colors.dim() == 3:
        campos = -viewmat[:3, :3].T @ viewmat[:3, 3]
        colors = sh_to_rgb(colors, means, campos)
    means2d, conics, depths, cov2d, radii, valid = project(means, quats, scales, viewmat, K, width, height)
    if means2d.requires_grad:
        means2d.retain_grad()
    vis, i0, i1 = visible_bounds(means2d, cov2d, opacities, valid, width, height)
    idx = torch.nonzero(vis).flatten()
    idx = idx[torch.sort(depths.detach()[idx], stable=True).indices]
    bg = torch.zeros(3, dtype=dt) if background is None else background.to(dt)
    args = (means2d[idx], conics[idx], opacities[idx].to(dt), colors[idx].to(dt), depths[idx])
    band = height if band_rows is None else band_rows
    rgbs, alphas, depths_out = [], [], []
    for r0 in range(0, height, band):
        r1 = min(r0 + band, height)
        ys, xs = torch.meshgrid(torch.arange(r0, r1, dtype=dt) + 0.5, torch.arange(width, dtype=dt) + 0.5,
                                indexing="ij")
        sel = (i1[idx] >= r0) & (i0[idx] <= r1 - 1)
        part = tuple(a[sel] for a in args)
        if use_checkpoint:
            out = checkpoint(_composite, xs.flatten(), ys.flatten(), *part, bg, use_reentrant=False)
        else:
            out = _composite(xs.flatten(), ys.flatten(), *part, bg)
        rgbs.append(out[0].reshape(r1 - r0, width, 3))
        alphas.append(out[1].reshape(r1 - r0, width))
        depths_out.append(out[2].reshape(r1 - r0, width))
    radii = torch.where(vis, radii, 0)
    return {"rgb": torch.cat(rgbs), "alpha": torch.cat(alphas), "depth": torch.cat(depths_out),
            "radii": radii, "means2d": means2d}


def look_at_camera(width, height, fov_x_deg=50.0, principal=None):
    """An identity-pose camera (at the origin, looking down +z) and its ``K``."""
    fx = 0.5 * width / math.tan(math.radians(fov_x_deg) / 2)
    cx, cy = (0.5 * width, 0.5 * height) if principal is None else principal
    K = torch.tensor([[fx, 0.0, cx], [0.0, fx, cy], [0.0, 0.0, 1.0]], dtype=torch.float64)
    return torch.eye(4, dtype=torch.float64), K


def random_scene(n, seed, sh_degree=None, depth=2.0, spread=0.35, scale=0.05, opacity=(0.05, 0.95)):
    """Random Gaussians in front of an identity camera: float32 tensors
    ``means, quats, scales, opacities, colors``."""
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g) * spread
    means[:, 2] = depth + means[:, 2]
    quats = torch.randn(n, 4, generator=g)
    scales = scale * (0.2 + torch.rand(n, 3, generator=g))
    opacities = opacity[0] + (opacity[1] - opacity[0]) * torch.rand(n, generator=g)
    if sh_degree is None:
        colors = torch.rand(n, 3, generator=g)
    else:
        colors = 0.3 * torch.randn(n, (sh_degree + 1) ** 2, 3, generator=g)
    return means, quats, scales, opacities, colors


def closest_to_threshold(means, quats, scales, opacities, viewmat, K, width, height):
    """Smallest relative distance of any (pixel, splat) pair to a decision threshold of the
    compositing (q = 9, alpha = 1/255, alpha = 0.99, T = 1e-4), in float64: scenes used to compare
    float32 with float64 should keep this well above float32 rounding."""
    with torch.no_grad():
        dt = torch.float64
        m2, con, z, cov, radii, valid = project(means.to(dt), quats.to(dt), scales.to(dt), viewmat, K,
                                                width, height)
        idx = torch.nonzero(valid).flatten()
        idx = idx[torch.sort(z[idx], stable=True).indices]
        ys, xs = torch.meshgrid(torch.arange(height, dtype=dt) + 0.5, torch.arange(width, dtype=dt) + 0.5,
                                indexing="ij")
        dx = xs.flatten()[:, None] - m2[idx, 0]
        dy = ys.flatten()[:, None] - m2[idx, 1]
        c = con[idx]
        q = c[:, 0] * dx * dx + 2 * c[:, 1] * dx * dy + c[:, 2] * dy * dy
        raw = opacities.to(dt)[idx] * torch.exp(-0.5 * q)
        alpha = raw.clamp_max(ALPHA_MAX)
        ok = (q <= 9) & (alpha >= ALPHA_MIN)
        t_incl = torch.cumprod(1 - torch.where(ok, alpha, 0), 1)
        far = torch.full_like(q, 1.0)
        gaps = [torch.where(raw >= ALPHA_MIN, ((q - 9) / 9).abs(), far),
                torch.where(q <= 9, ((raw - ALPHA_MIN) / ALPHA_MIN).abs(), far),
                torch.where(ok, ((raw - ALPHA_MAX) / ALPHA_MAX).abs(), far),
                torch.where(ok, ((t_incl - T_MIN) / T_MIN).abs(), far)]
        return min(float(gap.min()) if gap.numel() else 1.0 for gap in gaps)
