"""The training loss's SSIM as numba kernels with a hand-written backward.

Same definition as :func:`mogaface.core.train.losses.ssim` (separable Gaussian window over the valid
area, population statistics, C1 = 0.01², C2 = 0.03²): torch's grouped convolutions and the autograd
graph of the ten statistic maps cost about as much as a fifth of a real-scale training step, where
two passes over the image with the window in registers do. Only the prediction is differentiated.

Forward: a horizontal pass (five windowed sums per pixel of each channel row: a, b, a², b², ab),
a vertical pass that ends in the SSIM map, its sum, and the map's derivatives with respect to the
three statistics that depend on the prediction (μa, E[a²], E[ab]). Backward: those derivatives,
scaled by the upstream gradient, blurred back (the window's transpose: the same symmetric taps,
zero outside the valid area) and combined as ``G_μ + 2a·G_aa + b·G_ab``.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .. import numba_locator  # noqa: F401  (the kernels' cache filed by code: before they are defined)


@njit(cache=True, parallel=True, fastmath=True, nogil=True)
def forward(a, b, taps, c1, c2, derivs):
    """Sum of the SSIM map of ``a, b`` (C, H, W) float32; fills ``derivs`` (C, 3, Hv, Wv) with
    dS/dμa, dS/dE[a²], dS/dE[ab] at each valid pixel."""
    n_c, h, w = a.shape
    r = taps.shape[0]
    hv, wv = h - r + 1, w - r + 1
    horiz = np.empty((n_c, 5, h, wv), np.float32)
    for ci in prange(n_c * h):
        c, i = ci // h, ci % h
        s0 = horiz[c, 0, i]
        s1 = horiz[c, 1, i]
        s2 = horiz[c, 2, i]
        s3 = horiz[c, 3, i]
        s4 = horiz[c, 4, i]
        s0[:] = 0.0
        s1[:] = 0.0
        s2[:] = 0.0
        s3[:] = 0.0
        s4[:] = 0.0
        ra = a[c, i]
        rb = b[c, i]
        for k in range(r):
            t = taps[k]
            for j in range(wv):
                x = ra[j + k]
                y = rb[j + k]
                s0[j] += t * x
                s1[j] += t * y
                s2[j] += t * x * x
                s3[j] += t * y * y
                s4[j] += t * x * y
    partial = np.zeros(n_c * hv, np.float64)
    for ci in prange(n_c * hv):
        c, i = ci // hv, ci % hv
        mu_a = np.zeros(wv, np.float32)
        mu_b = np.zeros(wv, np.float32)
        aa = np.zeros(wv, np.float32)
        bb = np.zeros(wv, np.float32)
        ab = np.zeros(wv, np.float32)
        for k in range(r):
            t = taps[k]
            h0 = horiz[c, 0, i + k]
            h1 = horiz[c, 1, i + k]
            h2 = horiz[c, 2, i + k]
            h3 = horiz[c, 3, i + k]
            h4 = horiz[c, 4, i + k]
            for j in range(wv):
                mu_a[j] += t * h0[j]
                mu_b[j] += t * h1[j]
                aa[j] += t * h2[j]
                bb[j] += t * h3[j]
                ab[j] += t * h4[j]
        d_mu = derivs[c, 0, i]
        d_aa = derivs[c, 1, i]
        d_ab = derivs[c, 2, i]
        total = np.float32(0.0)
        for j in range(wv):
            x, y = mu_a[j], mu_b[j]
            n1 = 2 * x * y + c1
            n2 = 2 * (ab[j] - x * y) + c2
            e1 = x * x + y * y + c1
            e2 = (aa[j] - x * x) + (bb[j] - y * y) + c2
            inv = 1 / (e1 * e2)
            s = n1 * n2 * inv
            total += s
            d_mu[j] = 2 * inv * (y * (n2 - n1) - s * x * (e2 - e1))
            d_aa[j] = -s * e1 * inv
            d_ab[j] = 2 * n1 * inv
        partial[ci] = total
    return partial.sum()


@njit(cache=True, parallel=True, fastmath=True, nogil=True)
def backward(a, b, taps, derivs, scale, grad):
    """``grad`` (C, H, W) = d(scale · Σ SSIM map)/da."""
    n_c, h, w = a.shape
    r = taps.shape[0]
    hv, wv = h - r + 1, w - r + 1
    vert = np.empty((n_c, 3, h, wv), np.float32)
    for ci in prange(n_c * h):
        c, i = ci // h, ci % h
        for m in range(3):
            row = vert[c, m, i]
            row[:] = 0.0
            for k in range(r):
                q = i - k
                if q < 0 or q >= hv:
                    continue
                t = taps[k] * scale
                src = derivs[c, m, q]
                for j in range(wv):
                    row[j] += t * src[j]
    for ci in prange(n_c * h):
        c, i = ci // h, ci % h
        g0 = np.zeros(w, np.float32)
        g1 = np.zeros(w, np.float32)
        g2 = np.zeros(w, np.float32)
        v0 = vert[c, 0, i]
        v1 = vert[c, 1, i]
        v2 = vert[c, 2, i]
        for k in range(r):
            t = taps[k]
            for j in range(wv):
                g0[j + k] += t * v0[j]
                g1[j + k] += t * v1[j]
                g2[j + k] += t * v2[j]
        ra = a[c, i]
        rb = b[c, i]
        out = grad[c, i]
        for j in range(w):
            out[j] = g0[j] + 2 * ra[j] * g1[j] + rb[j] * g2[j]
