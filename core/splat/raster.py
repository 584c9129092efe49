"""Tile rasterization kernels: front-to-back alpha compositing and its backward.

One tile (16x16 pixels) per parallel task. Each splat of a tile's list visits only the pixels of
its support, row by row (the row's x-span comes from the ellipse), so thin and small splats cost
what they cover. The backward walks the same lists in the same order, rebuilding each pixel's
transmittance exactly as the forward did, and takes the light behind a splat as the pixel total
minus what is in front of it; each (tile, splat) pair writes its own gradient slot, so no two
threads ever write the same memory.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .tiles import ALPHA_MIN, MAX_HALF, SIGMAS, TILE, margin, support_q

T_MIN = 1e-4  # a pixel stops once its transmittance would fall below this
ALPHA_MAX = 0.99
NPACK = 16

# packed per-splat record (float32, one 64-byte line), in depth-rank order
MX, MY, CA, CB, CC, OP, CR, CG, CBL, DZ, QM, KX, SQS, ISYY, EY = range(15)


@njit(cache=True, parallel=True)
def pack(order, means2d, conics, cov2d, opacities, colors, depths):
    """Gather the per-splat data the kernels read, in depth order, as contiguous float32 rows."""
    n = order.shape[0]
    out = np.zeros((n, NPACK), np.float32)
    for r in prange(n):
        g = order[r]
        sxx, sxy, syy = cov2d[g, 0], cov2d[g, 1], cov2d[g, 2]
        qm = margin(support_q(np.float64(opacities[g])))
        out[r, MX] = means2d[g, 0]
        out[r, MY] = means2d[g, 1]
        out[r, CA] = conics[g, 0]
        out[r, CB] = conics[g, 1]
        out[r, CC] = conics[g, 2]
        out[r, OP] = opacities[g]
        out[r, CR] = colors[g, 0]
        out[r, CG] = colors[g, 1]
        out[r, CBL] = colors[g, 2]
        out[r, DZ] = depths[g]
        out[r, QM] = qm
        out[r, KX] = sxy / syy
        out[r, SQS] = min(math.sqrt(sxx - sxy * sxy / syy), MAX_HALF)
        out[r, ISYY] = 1.0 / syy
        out[r, EY] = min(math.sqrt(qm * syy), MAX_HALF)
    return out


@njit(cache=True, inline="always")
def _rows(p, y0, y1):
    my, ey = p[MY], p[EY]
    i0 = max(int(math.ceil(max(my - ey, y0 - 1.0) - 0.5)), y0)
    i1 = min(int(math.floor(min(my + ey, y1 + 1.0) - 0.5)), y1)
    return i0, i1


@njit(cache=True, inline="always")
def _cols(p, dy, x0, x1):
    rem = p[QM] - dy * dy * p[ISYY]
    if rem < 0.0:
        return 0, -1
    half = math.sqrt(rem) * p[SQS]
    xc = p[MX] + p[KX] * dy
    j0 = max(int(math.ceil(max(xc - half, x0 - 1.0) - 0.5)), x0)
    j1 = min(int(math.floor(min(xc + half, x1 + 1.0) - 0.5)), x1)
    return j0, j1


@njit(cache=True, parallel=True, fastmath=True)
def forward(packed, ranks, tile_offsets, tile_queue, tiles_x, width, height, background,
            rgb, depth, trans, last):
    """Composite every tile; writes ``rgb (H,W,3)``, ``depth``, final transmittance ``trans`` and
    ``last`` (the slot of the last splat that counted in each pixel, -1 if none)."""
    q_max = np.float32(SIGMAS * SIGMAS)
    a_min = np.float32(ALPHA_MIN)
    a_max = np.float32(ALPHA_MAX)
    t_min = np.float32(T_MIN)
    for qi in prange(tile_queue.shape[0]):
        t = tile_queue[qi]
        ty, tx = t // tiles_x, t % tiles_x
        x0, y0 = tx * TILE, ty * TILE
        x1, y1 = min(x0 + TILE, width) - 1, min(y0 + TILE, height) - 1
        T = np.ones(TILE * TILE, np.float32)
        cr = np.zeros(TILE * TILE, np.float32)
        cg = np.zeros(TILE * TILE, np.float32)
        cb = np.zeros(TILE * TILE, np.float32)
        cd = np.zeros(TILE * TILE, np.float32)
        lk = np.full(TILE * TILE, -1, np.int64)
        done = np.zeros(TILE * TILE, np.bool_)
        n_live = (x1 - x0 + 1) * (y1 - y0 + 1)
        for k in range(tile_offsets[t], tile_offsets[t + 1]):
            p = packed[ranks[k]]
            mx, my = p[MX], p[MY]
            ca, cbb, cc, op = p[CA], p[CB], p[CC], p[OP]
            i0, i1 = _rows(p, y0, y1)
            for i in range(i0, i1 + 1):
                dy = np.float32(i + 0.5) - my
                j0, j1 = _cols(p, dy, x0, x1)
                base = (i - y0) * TILE - x0
                for j in range(j0, j1 + 1):
                    pix = base + j
                    if done[pix]:
                        continue
                    dx = np.float32(j + 0.5) - mx
                    q = ca * dx * dx + np.float32(2.0) * cbb * dx * dy + cc * dy * dy
                    if q > q_max:
                        continue
                    alpha = min(a_max, op * math.exp(np.float32(-0.5) * q))
                    if alpha < a_min:
                        continue
                    t_next = T[pix] * (np.float32(1.0) - alpha)
                    if t_next < t_min:
                        done[pix] = True
                        n_live -= 1
                        continue
                    w = alpha * T[pix]
                    cr[pix] += w * p[CR]
                    cg[pix] += w * p[CG]
                    cb[pix] += w * p[CBL]
                    cd[pix] += w * p[DZ]
                    T[pix] = t_next
                    lk[pix] = k
            if n_live == 0:
                break
        for i in range(y0, y1 + 1):
            for j in range(x0, x1 + 1):
                pix = (i - y0) * TILE + (j - x0)
                tf = T[pix]
                rgb[i, j, 0] = cr[pix] + tf * background[0]
                rgb[i, j, 1] = cg[pix] + tf * background[1]
                rgb[i, j, 2] = cb[pix] + tf * background[2]
                depth[i, j] = cd[pix]
                trans[i, j] = tf
                last[i, j] = lk[pix]


NGRAD = 10  # per-slot gradient: mean2d x, y, conic a, b, c, opacity, colour r, g, b, depth


@njit(cache=True, parallel=True, fastmath=True)
def backward(packed, ranks, tile_offsets, tile_queue, tiles_x, width, height,
             rgb, depth, trans, last, v_rgb, v_alpha, v_depth, slot_grads):
    """Per-slot gradients of the splats' 2D mean, conic, opacity, colour and depth."""
    q_max = np.float32(SIGMAS * SIGMAS)
    a_min = np.float32(ALPHA_MIN)
    a_max = np.float32(ALPHA_MAX)
    one = np.float32(1.0)
    for qi in prange(tile_queue.shape[0]):
        t = tile_queue[qi]
        ty, tx = t // tiles_x, t % tiles_x
        x0, y0 = tx * TILE, ty * TILE
        x1, y1 = min(x0 + TILE, width) - 1, min(y0 + TILE, height) - 1
        T = np.ones(TILE * TILE, np.float32)
        rest = np.zeros(TILE * TILE, np.float32)  # light (dotted with its gradient) behind
        gr = np.zeros(TILE * TILE, np.float32)
        gg = np.zeros(TILE * TILE, np.float32)
        gb = np.zeros(TILE * TILE, np.float32)
        gd = np.zeros(TILE * TILE, np.float32)
        lk = np.full(TILE * TILE, -1, np.int64)
        k_end = tile_offsets[t]
        for i in range(y0, y1 + 1):
            for j in range(x0, x1 + 1):
                pix = (i - y0) * TILE + (j - x0)
                gr[pix] = v_rgb[i, j, 0]
                gg[pix] = v_rgb[i, j, 1]
                gb[pix] = v_rgb[i, j, 2]
                gd[pix] = v_depth[i, j]
                rest[pix] = (rgb[i, j, 0] * gr[pix] + rgb[i, j, 1] * gg[pix] + rgb[i, j, 2] * gb[pix]
                             + depth[i, j] * gd[pix] - trans[i, j] * v_alpha[i, j])
                lk[pix] = last[i, j]
                k_end = max(k_end, last[i, j] + 1)
        for k in range(tile_offsets[t], k_end):
            p = packed[ranks[k]]
            mx, my = p[MX], p[MY]
            ca, cbb, cc, op = p[CA], p[CB], p[CC], p[OP]
            cr, cg, cbl, cz = p[CR], p[CG], p[CBL], p[DZ]
            s_mx = np.float32(0.0)
            s_my = np.float32(0.0)
            s_a = np.float32(0.0)
            s_b = np.float32(0.0)
            s_c = np.float32(0.0)
            s_o = np.float32(0.0)
            s_r = np.float32(0.0)
            s_g = np.float32(0.0)
            s_bl = np.float32(0.0)
            s_z = np.float32(0.0)
            i0, i1 = _rows(p, y0, y1)
            for i in range(i0, i1 + 1):
                dy = np.float32(i + 0.5) - my
                j0, j1 = _cols(p, dy, x0, x1)
                base = (i - y0) * TILE - x0
                for j in range(j0, j1 + 1):
                    pix = base + j
                    if k > lk[pix]:
                        continue
                    dx = np.float32(j + 0.5) - mx
                    q = ca * dx * dx + np.float32(2.0) * cbb * dx * dy + cc * dy * dy
                    if q > q_max:
                        continue
                    gauss = math.exp(np.float32(-0.5) * q)
                    raw = op * gauss
                    alpha = min(a_max, raw)
                    if alpha < a_min:
                        continue
                    tp = T[pix]
                    w = alpha * tp
                    f = cr * gr[pix] + cg * gg[pix] + cbl * gb[pix] + cz * gd[pix]
                    r = rest[pix] - w * f
                    rest[pix] = r
                    T[pix] = tp * (one - alpha)
                    s_r += w * gr[pix]
                    s_g += w * gg[pix]
                    s_bl += w * gb[pix]
                    s_z += w * gd[pix]
                    if raw < a_max:
                        v_al = tp * f - r / (one - alpha)
                        s_o += v_al * gauss
                        v_q = np.float32(-0.5) * alpha * v_al
                        s_a += v_q * dx * dx
                        s_b += v_q * np.float32(2.0) * dx * dy
                        s_c += v_q * dy * dy
                        s_mx -= v_q * np.float32(2.0) * (ca * dx + cbb * dy)
                        s_my -= v_q * np.float32(2.0) * (cbb * dx + cc * dy)
            out = slot_grads[k]
            out[0] = s_mx
            out[1] = s_my
            out[2] = s_a
            out[3] = s_b
            out[4] = s_c
            out[5] = s_o
            out[6] = s_r
            out[7] = s_g
            out[8] = s_bl
            out[9] = s_z
        for k in range(k_end, tile_offsets[t + 1]):
            for c in range(NGRAD):
                slot_grads[k, c] = 0.0


@njit(cache=True, parallel=True)
def reduce_slots(order, rank_offsets, isect_of, slot_grads, n, v_means2d, v_conics, v_opacities,
                 v_colors, v_depths):
    """Sum each splat's per-tile gradient slots into per-Gaussian gradients (original order)."""
    v_means2d[:] = 0.0
    v_conics[:] = 0.0
    v_opacities[:] = 0.0
    v_colors[:] = 0.0
    v_depths[:] = 0.0
    for r in prange(order.shape[0]):
        acc = np.zeros(NGRAD, np.float64)
        for m in range(rank_offsets[r], rank_offsets[r + 1]):
            s = isect_of[m]
            for c in range(NGRAD):
                acc[c] += slot_grads[s, c]
        g = order[r]
        v_means2d[g, 0] = acc[0]
        v_means2d[g, 1] = acc[1]
        v_conics[g, 0] = acc[2]
        v_conics[g, 1] = acc[3]
        v_conics[g, 2] = acc[4]
        v_opacities[g] = acc[5]
        v_colors[g, 0] = acc[6]
        v_colors[g, 1] = acc[7]
        v_colors[g, 2] = acc[8]
        v_depths[g] = acc[9]
