"""Tile binning: which Gaussians touch which 16x16 tile, as depth-sorted per-tile work lists.

A Gaussian's support is the part of its 3-sigma ellipse (``dᵀΣ⁻¹d <= 9``) where its alpha can reach
1/255, i.e. ``dᵀΣ⁻¹d <= Q = min(9, 2 ln(255 o))``. Tiles are assigned row by row from the exact
extent of that ellipse (plus a small safety margin), so the lists are tight for thin, tilted splats
and the binning never changes the image, only the work.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .. import numba_locator  # noqa: F401  (the kernels' cache filed by code: before they are defined)

TILE = 16
ALPHA_MIN = 1.0 / 255.0
SIGMAS = 3.0
MAX_HALF = 1e7  # px; clamps the extent of absurdly large splats before float32 packing


@njit(cache=True, inline="always")
def support_q(opacity):
    """Largest Mahalanobis² distance at which a splat of this opacity still counts (<=0: never)."""
    if not (opacity > ALPHA_MIN):
        return -1.0
    return min(SIGMAS * SIGMAS, 2.0 * math.log(255.0 * opacity))


@njit(cache=True, inline="always")
def margin(q):
    """Conservative widening of ``q`` so float32 per-pixel tests never fall outside the bounds."""
    return q * 1.001 + 0.01


@njit(cache=True, inline="always")
def band_x_range(mx, my, sxx, sxy, syy, qm, y0, y1):
    """x-extent of the ellipse ``dᵀΣ⁻¹d <= qm`` over pixel-centre rows ``y0 <= y <= y1``."""
    k = sxy / syy
    s = sxx - sxy * k
    ds = sxy * math.sqrt(qm / sxx)  # dy of the right-most point of the ellipse
    dr = min(max(ds, y0 - my), y1 - my)  # right edge is concave in dy: nearest point to ds
    dl = min(max(-ds, y0 - my), y1 - my)  # left edge is convex: nearest point to -ds
    xr = mx + k * dr + math.sqrt(max(qm - dr * dr / syy, 0.0) * s)
    xl = mx + k * dl - math.sqrt(max(qm - dl * dl / syy, 0.0) * s)
    return xl, xr


@njit(cache=True, inline="always")
def pixel_span(lo, hi, first, last):
    """Pixel indices whose centres ``i + 0.5`` lie in ``[lo, hi]``, clipped to ``[first, last]``."""
    lo = max(lo, first - 1.0)
    hi = min(hi, last + 1.0)
    a = max(int(math.ceil(lo - 0.5)), first)
    b = min(int(math.floor(hi - 0.5)), last)
    return a, b


@njit(cache=True, parallel=True, nogil=True)
def pixel_bounds(means2d, cov2d, opacities, radii, width, height, bounds):
    """Fill ``bounds (N,4) int32`` = first/last pixel column and row of each support; visibility."""
    n = means2d.shape[0]
    visible = np.zeros(n, np.bool_)
    for g in prange(n):
        bounds[g, 0] = 0
        bounds[g, 1] = -1
        bounds[g, 2] = 0
        bounds[g, 3] = -1
        if radii[g] <= 0:
            continue
        q = support_q(np.float64(opacities[g]))
        if q <= 0.0:
            continue
        qm = margin(q)
        mx, my = np.float64(means2d[g, 0]), np.float64(means2d[g, 1])
        ex = math.sqrt(qm * cov2d[g, 0])
        ey = math.sqrt(qm * cov2d[g, 2])
        j0, j1 = pixel_span(mx - ex, mx + ex, 0, width - 1)
        i0, i1 = pixel_span(my - ey, my + ey, 0, height - 1)
        if j0 <= j1 and i0 <= i1:
            bounds[g, 0] = j0
            bounds[g, 1] = j1
            bounds[g, 2] = i0
            bounds[g, 3] = i1
            visible[g] = True
    return visible


@njit(cache=True)
def _tile_cols(g, ty, means2d, cov2d, opacities, bounds):
    i0 = max(bounds[g, 2], ty * TILE)
    i1 = min(bounds[g, 3], ty * TILE + TILE - 1)
    qm = margin(support_q(np.float64(opacities[g])))
    xl, xr = band_x_range(np.float64(means2d[g, 0]), np.float64(means2d[g, 1]),
                          cov2d[g, 0], cov2d[g, 1], cov2d[g, 2], qm, i0 + 0.5, i1 + 0.5)
    j0, j1 = pixel_span(xl, xr, bounds[g, 0], bounds[g, 1])
    if j0 > j1:
        return 0, -1
    return j0 // TILE, j1 // TILE


@njit(cache=True, parallel=True, nogil=True)
def _row_columns(order, means2d, cov2d, opacities, bounds, row_offsets, columns, counts):
    """Each rank's tile columns per tile row it reaches, ``columns[row_offsets[r] + i]`` for its
    ``i``-th row, and its number of tiles: the ellipse's extent is found once per row."""
    for r in prange(order.shape[0]):
        g = order[r]
        c = 0
        m = row_offsets[r]
        for ty in range(bounds[g, 2] // TILE, bounds[g, 3] // TILE + 1):
            t0, t1 = _tile_cols(g, ty, means2d, cov2d, opacities, bounds)
            columns[m, 0] = t0
            columns[m, 1] = t1
            m += 1
            c += t1 - t0 + 1
        counts[r] = c


@njit(cache=True, parallel=True, nogil=True)
def _tiles_of_ranks(order, bounds, row_offsets, columns, tiles_x, rank_offsets, tile_ids):
    """The tiles of each rank, rank-major: ``tile_ids[rank_offsets[r]:rank_offsets[r+1]]``."""
    for r in prange(order.shape[0]):
        ty = bounds[order[r], 2] // TILE
        m = rank_offsets[r]
        for row in range(row_offsets[r], row_offsets[r + 1]):
            for tx in range(columns[row, 0], columns[row, 1] + 1):
                tile_ids[m] = ty * tiles_x + tx
                m += 1
            ty += 1


@njit(cache=True)
def _group_by_tile(tile_ids, rank_offsets, n_tiles):
    """Stable counting sort of the rank-major pairs by tile: per-tile lists stay in depth order."""
    tile_offsets = np.zeros(n_tiles + 1, np.int64)
    for m in range(tile_ids.shape[0]):
        tile_offsets[tile_ids[m] + 1] += 1
    for t in range(n_tiles):
        tile_offsets[t + 1] += tile_offsets[t]
    fill = tile_offsets[:-1].copy()
    ranks = np.empty(tile_ids.shape[0], np.int32)
    isect_of = np.empty(tile_ids.shape[0], np.int64)
    for r in range(rank_offsets.shape[0] - 1):
        for m in range(rank_offsets[r], rank_offsets[r + 1]):
            t = tile_ids[m]
            slot = fill[t]
            fill[t] = slot + 1
            ranks[slot] = r
            isect_of[m] = slot
    return tile_offsets, ranks, isect_of


class Bins:
    """Per-tile work lists. ``ranks[tile_offsets[t]:tile_offsets[t+1]]`` are the depth ranks (index
    into ``order``) touching tile ``t``, front to back; ``isect_of[rank_offsets[r]:...]`` are the
    slots of rank ``r`` in those lists (for reducing per-slot gradients without atomics)."""

    __slots__ = ("order", "visible", "tiles_x", "tiles_y", "tile_offsets", "ranks",
                 "rank_offsets", "isect_of")

    def __init__(self, **fields):
        for k, v in fields.items():
            setattr(self, k, v)


def depth_order(depths, idx):
    """``idx`` sorted by depth, ties by index. Depths of visible splats are positive float32,
    whose bit patterns sort like integers: one int64 key sort (SIMD in numpy) does it."""
    keys = (depths[idx].view(np.int32).astype(np.int64) << 32) | idx.astype(np.int64)
    keys.sort()
    return keys & 0xFFFFFFFF


def bin_gaussians(means2d, cov2d, depths, opacities, radii, width, height) -> Bins:
    """Visibility, depth order and per-tile lists for float32/float64 numpy inputs."""
    n = means2d.shape[0]
    bounds = np.empty((n, 4), np.int32)
    visible = pixel_bounds(means2d, cov2d, opacities, radii, width, height, bounds)
    idx = np.flatnonzero(visible)
    order = depth_order(depths, idx)
    tiles_x = (width + TILE - 1) // TILE
    tiles_y = (height + TILE - 1) // TILE
    reached = bounds[order]
    row_offsets = np.zeros(order.shape[0] + 1, np.int64)
    np.cumsum(reached[:, 3] // TILE - reached[:, 2] // TILE + 1, out=row_offsets[1:])
    columns = np.empty((int(row_offsets[-1]), 2), np.int32)
    counts = np.empty(order.shape[0], np.int64)
    _row_columns(order, means2d, cov2d, opacities, bounds, row_offsets, columns, counts)
    rank_offsets = np.zeros(order.shape[0] + 1, np.int64)
    np.cumsum(counts, out=rank_offsets[1:])
    tile_ids = np.empty(int(rank_offsets[-1]), np.int32)
    _tiles_of_ranks(order, bounds, row_offsets, columns, tiles_x, rank_offsets, tile_ids)
    tile_offsets, ranks, isect_of = _group_by_tile(tile_ids, rank_offsets, tiles_x * tiles_y)
    return Bins(order=order, visible=visible, tiles_x=tiles_x, tiles_y=tiles_y,
                tile_offsets=tile_offsets, ranks=ranks, rank_offsets=rank_offsets, isect_of=isect_of)
