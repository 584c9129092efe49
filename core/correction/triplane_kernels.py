"""The texture attention's triplane read as numba kernels with a hand-written backward.

Same sampling as ``F.grid_sample(planes, grid, "bilinear", padding_mode="border",
align_corners=False)`` on the three axis planes, written straight into the ``(N, 3·C)`` rows the
attention reads. torch's path costs about five times as much at 100k Gaussians: its backward
scatters into the planes on one thread, and the ``(3, C, N)`` result is transposed twice (once
forward, once for the gradient). The points carry no gradient (the triplane is read where the
Gaussians sit, it does not move them), so only the planes are differentiated.

The planes are taken channel-last, ``(3, S, S, C)``, so that a texel's C values are adjacent.
The backward accumulates into one copy of the planes per block of points and sums the copies
in block order, so its result does not depend on how many threads ran it.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .. import numba_locator  # noqa: F401  (the kernels' cache filed by code: before they are defined)

#: Blocks of points whose plane gradients are summed apart (then in this order).
BLOCKS = 4
# (first, second) coordinate of each plane: xy, xz, yz.
_AXES = np.array([[0, 1], [0, 2], [1, 2]], np.int64)


@njit(inline="always")
def _corners(u, size):
    """Texel index and weight of the lower corner along one axis, from a coordinate in [-1, 1]
    (align_corners=False, border padding: clamped to the texel centres at the edge). The indices
    are clamped as integers too, so that a NaN coordinate reads a texel, never past the planes."""
    position = ((u + 1.0) * size - 1.0) * 0.5
    position = min(max(position, 0.0), size - 1.0)
    low = min(max(int(np.floor(position)), 0), size - 1)
    return low, min(low + 1, size - 1), np.float32(position - low)


@njit(inline="always")
def _bilinear(points, n, p, size):
    """Point ``n``'s four texels on plane ``p`` and their weights:
    ``x0, x1, y0, y1, w00, w01, w10, w11`` (``wyx``: row y, column x)."""
    x0, x1, wx = _corners(points[n, _AXES[p, 0]], size)
    y0, y1, wy = _corners(points[n, _AXES[p, 1]], size)
    return x0, x1, y0, y1, (1 - wx) * (1 - wy), wx * (1 - wy), (1 - wx) * wy, wx * wy


@njit(cache=True, parallel=True, fastmath=True, nogil=True)
def forward(planes, points, out):
    """``out`` (N, 3·C) = the planes ``(3, S, S, C)`` read at ``points`` (N, 3), plane by plane."""
    n_points = points.shape[0]
    size, channels = planes.shape[1], planes.shape[3]
    for n in prange(n_points):
        for p in range(3):
            x0, x1, y0, y1, w00, w01, w10, w11 = _bilinear(points, n, p, size)
            row = out[n, p * channels:(p + 1) * channels]
            for c in range(channels):
                row[c] = (w00 * planes[p, y0, x0, c] + w01 * planes[p, y0, x1, c]
                          + w10 * planes[p, y1, x0, c] + w11 * planes[p, y1, x1, c])


@njit(cache=True, parallel=True, fastmath=True, nogil=True)
def backward(points, grad_out, size, grad_planes):
    """``grad_planes`` (3, S, S, C) = d⟨grad_out, forward(planes, points)⟩ / d planes."""
    n_points = points.shape[0]
    channels = grad_planes.shape[3]
    copies = np.zeros((BLOCKS, 3, size, size, channels), np.float32)
    step = (n_points + BLOCKS - 1) // BLOCKS
    for block in prange(BLOCKS):
        into = copies[block]
        for n in range(block * step, min(n_points, (block + 1) * step)):
            for p in range(3):
                x0, x1, y0, y1, w00, w01, w10, w11 = _bilinear(points, n, p, size)
                for c in range(channels):
                    g = grad_out[n, p * channels + c]
                    into[p, y0, x0, c] += w00 * g
                    into[p, y0, x1, c] += w01 * g
                    into[p, y1, x0, c] += w10 * g
                    into[p, y1, x1, c] += w11 * g
    for py in prange(3 * size):
        p, y = py // size, py % size
        for x in range(size):
            for c in range(channels):
                total = np.float32(0.0)
                for block in range(BLOCKS):
                    total += copies[block, p, y, x, c]
                grad_planes[p, y, x, c] = total
