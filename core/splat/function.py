"""The autograd bridge: torch tensors in, numba kernels run, hand-written gradients out.

Two stages, each an ``autograd.Function``: projection (3D -> 2D ellipses) and rasterization (2D
ellipses -> images). The 2D means between them are an ordinary tensor of the graph, which is how
densification reads the screen-space gradient.
"""

from __future__ import annotations

import numba
import numpy as np
import torch

from . import cancel, projection, raster, tiles


def _np(t: torch.Tensor) -> np.ndarray:
    # numpy makes it contiguous if needed (e.g. the stride-0 gradient of a sum) without a torch
    # parallel region
    return np.ascontiguousarray(t.detach().numpy())


ITEMS_PER_THREAD = 8192


class _threads:
    """Run per-splat passes on fewer threads when they are short: waking a second thread costs
    more than it saves there, and far more when other processes hold the cores."""

    def __init__(self, items):
        self.count = max(1, min(numba.get_num_threads(), items // ITEMS_PER_THREAD))

    def __enter__(self):
        self.old = numba.get_num_threads()
        numba.set_num_threads(self.count)

    def __exit__(self, *exc):
        numba.set_num_threads(self.old)


class Project(torch.autograd.Function):
    """``means, quats, scales -> means2d (N,2), conics (N,3), depths (N,)`` (+ cov2d, radii)."""

    @staticmethod
    def forward(ctx, means, quats, scales, viewmat, K, width, height):
        n = means.shape[0]
        m, q, s = _np(means), _np(quats), _np(scales)
        means2d = np.empty((n, 2), np.float32)
        conics = np.empty((n, 3), np.float32)
        depths = np.empty(n, np.float32)
        cov2d = np.empty((n, 3), np.float64)
        radii = np.empty(n, np.int32)
        with _threads(n):
            projection.project_forward(m, q, s, viewmat, K, width, height, means2d, conics, depths, cov2d, radii)
        ctx.state = (m, q, s, viewmat, K, width, height, radii)
        cov2d_t, radii_t = torch.from_numpy(cov2d), torch.from_numpy(radii)
        ctx.mark_non_differentiable(cov2d_t, radii_t)
        return torch.from_numpy(means2d), torch.from_numpy(conics), torch.from_numpy(depths), cov2d_t, radii_t

    @staticmethod
    def backward(ctx, v_means2d, v_conics, v_depths, _cov, _radii):
        m, q, s, viewmat, K, width, height, radii = ctx.state
        n = m.shape[0]
        v_m = np.empty((n, 3), np.float32)
        v_q = np.empty((n, 4), np.float32)
        v_s = np.empty((n, 3), np.float32)
        with _threads(n):
            projection.project_backward(m, q, s, viewmat, K, width, height, radii, _np(v_means2d),
                                        _np(v_conics), _np(v_depths), v_m, v_q, v_s)
        return torch.from_numpy(v_m), torch.from_numpy(v_q), torch.from_numpy(v_s), None, None, None, None


def tile_queue(work: np.ndarray, threads: int) -> np.ndarray:
    """Tile order for the compositing kernels: numba hands each thread one contiguous block of the
    queue, so tiles sorted by work are dealt round-robin (block ``b`` holds the ``b``-th, ``b+T``-th,
    ... heaviest), which gives every thread the same work within one tile. Each tile writes only its
    own pixels and slots, so the order changes no result."""
    by_work = np.argsort(-work, kind="stable")
    deal = np.argsort(np.arange(by_work.shape[0]) % max(1, threads), kind="stable")
    return by_work[deal].astype(np.int64)


class Rasterize(torch.autograd.Function):
    """2D splats -> ``rgb (H,W,3), alpha (H,W), depth (H,W)`` (+ visibility mask)."""

    @staticmethod
    def forward(ctx, means2d, conics, colors, opacities, depths, background, cov2d, radii, width, height):
        m2, con, col, op, dep = _np(means2d), _np(conics), _np(colors), _np(opacities), _np(depths)
        with _threads(m2.shape[0]):
            bins = tiles.bin_gaussians(m2, _np(cov2d), dep, op, _np(radii), width, height)
            packed = raster.pack(bins.order, m2, con, _np(cov2d), op, col, dep)
        work = np.diff(bins.tile_offsets)
        queue = tile_queue(work, numba.get_num_threads())
        rgb = np.empty((height, width, 3), np.float32)
        depth = np.empty((height, width), np.float32)
        trans = np.empty((height, width), np.float32)
        last = np.empty((height, width), np.int32)
        raster.forward(packed, bins.ranks, bins.tile_offsets, queue, bins.tiles_x,
                       width, height, _np(background), rgb, depth, trans, last, cancel.FLAG)
        cancel.raise_if_requested()  # a partial image must never be used
        ctx.state = (bins, packed, queue, rgb, depth, trans, last, width, height, means2d.shape[0])
        visible = torch.from_numpy(bins.visible)
        ctx.mark_non_differentiable(visible)
        return torch.from_numpy(rgb), torch.from_numpy(1.0 - trans), torch.from_numpy(depth), visible

    @staticmethod
    def backward(ctx, v_rgb, v_alpha, v_depth, _visible):
        bins, packed, queue, rgb, depth, trans, last, width, height, n = ctx.state
        slot = np.empty((bins.ranks.shape[0], raster.NGRAD), np.float32)
        raster.backward(packed, bins.ranks, bins.tile_offsets, queue, bins.tiles_x,
                        width, height, rgb, depth, trans, last, _np(v_rgb), _np(v_alpha), _np(v_depth), slot,
                        cancel.FLAG)
        cancel.raise_if_requested()
        v_m2 = np.empty((n, 2), np.float32)
        v_con = np.empty((n, 3), np.float32)
        v_op = np.empty(n, np.float32)
        v_col = np.empty((n, 3), np.float32)
        v_dep = np.empty(n, np.float32)
        with _threads(n):
            raster.reduce_slots(bins.order, bins.rank_offsets, bins.isect_of, slot, n, v_m2, v_con, v_op,
                                v_col, v_dep)
        v_bg = None
        if ctx.needs_input_grad[5]:
            v_bg = torch.from_numpy(np.einsum("hw,hwc->c", trans, _np(v_rgb)).astype(np.float32))
        return (torch.from_numpy(v_m2), torch.from_numpy(v_con), torch.from_numpy(v_col),
                torch.from_numpy(v_op), torch.from_numpy(v_dep), v_bg, None, None, None, None)
