"""Each stage alone: projection (forward and backward), tile binning, spherical harmonics."""

import math

import numpy as np
import pytest
import torch

from mogaface.core.splat import tiles
from mogaface.core.splat.function import Project, tile_queue
from mogaface.core.splat.reference import look_at_camera, project, random_scene
from mogaface.core.splat.sh import sh_basis, sh_degree


def off_axis_scene(n, seed):
    """Random Gaussians, some far outside the view so the Jacobian clamp is exercised."""
    means, quats, scales, _, _ = random_scene(n, seed, spread=0.6, scale=0.1)
    means[: n // 4, 0] *= 8.0
    return means, quats, scales


def test_projection_matches_reference():
    means, quats, scales = off_axis_scene(200, 0)
    viewmat, K = look_at_camera(40, 30, principal=(15.0, 18.0))
    viewmat = viewmat.clone()
    viewmat[:3, :3] = torch.tensor([[0.96, -0.28, 0.0], [0.28, 0.96, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    viewmat[:3, 3] = torch.tensor([0.05, -0.1, 0.3], dtype=torch.float64)
    m2, con, dep, cov, radii = Project.apply(means, quats, scales, viewmat.numpy(), K.numpy(), 40, 30)
    r_m2, r_con, r_dep, r_cov, r_radii, valid = project(means.double(), quats.double(), scales.double(),
                                                        viewmat, K, 40, 30)
    assert valid.all() and (radii > 0).all()
    assert torch.allclose(m2.double(), r_m2, rtol=1e-6, atol=1e-4)
    assert torch.allclose(con.double(), r_con, rtol=1e-5, atol=1e-7)
    assert torch.allclose(dep.double(), r_dep, rtol=1e-6)
    assert torch.allclose(cov, r_cov, rtol=1e-9)
    assert torch.equal(radii, r_radii)


def test_projection_backward_matches_autograd():
    means, quats, scales = off_axis_scene(100, 1)
    viewmat, K = look_at_camera(40, 30)
    viewmat[:3, 3] = torch.tensor([0.02, 0.03, -0.2], dtype=torch.float64)
    g = torch.Generator().manual_seed(0)
    v = [torch.randn(100, 2, generator=g), torch.randn(100, 3, generator=g), torch.randn(100, generator=g)]
    ours = [p.clone().requires_grad_(True) for p in (means, quats, scales)]
    out = Project.apply(*ours, viewmat.numpy(), K.numpy(), 40, 30)
    sum((o * w).sum() for o, w in zip(out[:3], v)).backward()
    ref = [p.double().requires_grad_(True) for p in (means, quats, scales)]
    r_m2, r_con, r_dep, _, _, valid = project(*ref, viewmat, K, 40, 30)
    assert torch.equal(valid, out[4] > 0) and (~valid).any()  # some are behind the near plane
    w = valid.double()
    sum((o * u.double() * w.reshape(-1, *[1] * (u.dim() - 1))).sum()
        for o, u in zip((r_m2, r_con, r_dep), v)).backward()
    clamped = (r_m2[:, 0] < -0.3 * 40) | (r_m2[:, 0] > 1.3 * 40)
    assert clamped.any() and (~clamped).any()
    for a, b in zip(ours, ref):
        assert torch.allclose(a.grad.double(), b.grad, rtol=1e-4, atol=1e-5 * b.grad.abs().max())


def test_band_x_range_is_exact():
    rng = np.random.default_rng(0)
    for _ in range(200):
        a = rng.normal(size=(2, 2)) * rng.uniform(0.5, 10)
        sxx, sxy, syy = (a @ a.T + 0.3 * np.eye(2))[[0, 0, 1], [0, 1, 1]]
        mx, my, qm = rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(0.5, 9)
        y0 = rng.uniform(-10, 5)
        y1 = y0 + rng.uniform(0, 6)
        ey = math.sqrt(qm * syy)
        y0c, y1c = max(y0, my - ey), min(y1, my + ey)
        if y0c > y1c:
            continue
        xl, xr = tiles.band_x_range(mx, my, sxx, sxy, syy, qm, y0c, y1c)
        # brute force: the ellipse's x-extent on many rows of the band
        ys = np.linspace(y0c, y1c, 4001)
        det = sxx * syy - sxy * sxy
        rem = np.clip(qm - (ys - my) ** 2 / syy, 0, None)
        half = np.sqrt(rem * det / syy)
        centre = mx + sxy / syy * (ys - my)
        assert xl <= (centre - half).min() + 1e-9 and xr >= (centre + half).max() - 1e-9
        assert xl >= (centre - half).min() - 1e-2 and xr <= (centre + half).max() + 1e-2


def test_tile_lists_cover_support_and_are_depth_sorted():
    width, height = 70, 45
    means, quats, scales, opac, _ = random_scene(300, 2, spread=0.5, scale=0.08)
    viewmat, K = look_at_camera(width, height)
    m2, con, dep, cov, radii = Project.apply(means, quats, scales, viewmat.numpy(), K.numpy(), width, height)
    m2, con, dep, cov, radii = (t.numpy() for t in (m2, con, dep, cov, radii))
    op = opac.numpy()
    bins = tiles.bin_gaussians(m2, cov, dep, op, radii, width, height)
    ys, xs = np.mgrid[0:height, 0:width] + 0.5
    tiles_of_pixel = (ys // 16).astype(int) * bins.tiles_x + (xs // 16).astype(int)
    listed_total, needed_total = 0, 0
    for r, g in enumerate(bins.order):
        dx, dy = xs - m2[g, 0], ys - m2[g, 1]
        q = con[g, 0] * dx * dx + 2 * con[g, 1] * dx * dy + con[g, 2] * dy * dy
        alpha = op[g] * np.exp(-0.5 * q)
        needed = set(np.unique(tiles_of_pixel[(q <= 9) & (alpha >= 1 / 255)]).tolist())
        slots = bins.isect_of[bins.rank_offsets[r]:bins.rank_offsets[r + 1]]
        listed = {int(np.searchsorted(bins.tile_offsets, s, side="right") - 1) for s in slots}
        assert needed <= listed
        assert all(bins.ranks[s] == r for s in slots)
        listed_total += len(listed)
        needed_total += len(needed)
    assert listed_total <= 1.1 * needed_total  # tight, not just the bounding box
    for t in range(bins.tiles_x * bins.tiles_y):
        ranks = bins.ranks[bins.tile_offsets[t]:bins.tile_offsets[t + 1]]
        assert np.all(np.diff(ranks) > 0)  # front to back
    assert np.all(np.diff(dep[bins.order]) >= 0)
    assert set(bins.order.tolist()) == set(np.flatnonzero(bins.visible).tolist())


def test_sh_basis_is_orthonormal():
    n = 20000  # Fibonacci sphere quadrature
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = math.pi * (1 + 5 ** 0.5) * i
    r = np.sqrt(1 - z * z)
    dirs = torch.from_numpy(np.stack([r * np.cos(phi), r * np.sin(phi), z], -1))
    basis = sh_basis(dirs, 3)
    gram = basis.T @ basis * (4 * math.pi / n)
    assert torch.allclose(gram, torch.eye(16, dtype=torch.float64), atol=2e-3)


def test_sh_degree():
    assert [sh_degree(k) for k in (1, 4, 9, 16, 2, 25)] == [0, 1, 2, 3, -1, -1]


def test_polynomial_exp_is_accurate_where_splats_count():
    from mogaface.core.splat.raster import _exp_neg

    xs = np.linspace(-4.6, 0.0, 20001).astype(np.float32)
    approx = np.array([_exp_neg(x) for x in xs], np.float64)
    rel = np.abs(approx / np.exp(xs.astype(np.float64)) - 1)
    assert rel.max() < 2e-6


@pytest.mark.parametrize("threads", [1, 2, 3, 8])
def test_tile_queue_gives_each_thread_an_equal_block_of_work(threads):
    """The compositing kernels split the queue into one contiguous block per thread; with tiles
    sorted heavy-first a block held all the heavy tiles and the other thread idled."""
    work = np.random.default_rng(threads).pareto(1.5, size=1024).astype(np.int64)
    queue = tile_queue(work, threads)
    assert sorted(queue.tolist()) == list(range(work.shape[0]))
    blocks = np.array_split(queue, threads)
    sums = np.array([work[b].sum() for b in blocks])
    assert sums.max() - sums.min() <= work.max()
