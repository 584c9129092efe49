"""Tile rasterization kernels: front-to-back alpha compositing and its backward.

One tile (16x16 pixels) per parallel task. Each splat of a tile's list visits only the tile rows
its ellipse reaches, all of them as one SIMD loop over that run of the tile's row-major pixels (a
loop per row cost more in its setup than in its 16 lanes). The backward walks the same lists in the same order, rebuilding each pixel's
transmittance exactly as the forward did, and takes the light behind a splat as the pixel total
minus what is in front of it; each (tile, splat) pair writes its own gradient slot, so no two
threads ever write the same memory.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange, types
from numba.extending import intrinsic

from .. import numba_locator  # noqa: F401  (the kernels' cache filed by code: before they are defined)
from .tiles import ALPHA_MIN, MAX_HALF, SIGMAS, TILE, margin, support_q

T_MIN = 1e-4  # a pixel stops once its transmittance would fall below this
ALPHA_MAX = 0.99
NPACK = 16  # one 64-byte line per splat (11 fields used)

# packed per-splat record (float32, one 64-byte line), in depth-rank order
MX, MY, CA, CB, CC, OP, CR, CG, CBL, DZ, EY = range(11)


@njit(cache=True, parallel=True, nogil=True)
def pack(order, means2d, conics, cov2d, opacities, colors, depths):
    """Gather the per-splat data the kernels read, in depth order, as contiguous float32 rows."""
    n = order.shape[0]
    out = np.zeros((n, NPACK), np.float32)
    for r in prange(n):
        g = order[r]
        syy = cov2d[g, 2]
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
        out[r, EY] = min(math.sqrt(qm * syy), MAX_HALF)
    return out


@intrinsic
def _flag(typingctx, flags):
    """``flags[0]`` (an int32 array) read as an atomic load, which the compiler may not hoist out of
    a loop: another thread sets it while the kernel runs (``cancel.py``)."""
    def codegen(context, builder, signature, args):
        array = context.make_array(signature.args[0])(context, builder, args[0])
        return builder.load_atomic(array.data, "monotonic", 4)

    return types.int32(flags), codegen


@njit(cache=True, inline="always")
def _rows(p, y0, y1):
    my, ey = p[MY], p[EY]
    i0 = max(int(math.ceil(max(my - ey, y0 - 1.0) - 0.5)), y0)
    i1 = min(int(math.floor(min(my + ey, y1 + 1.0) - 0.5)), y1)
    return i0, i1


# exp(y) on [-0.575, 0]: Chebyshev fit of degree 5, in the power basis
_E = (0.9999999582467122, 0.9999969257410755, 0.49994596178781514, 0.1662847374307232,
      0.040387940230233656, 0.006271040356487318)


@njit(cache=True, inline="always", fastmath=True)
def _exp_neg(x):
    """exp(x) for x in [-4.6, 0] (the only range where a splat counts), branch-free so loops
    vectorise without a vector math library: a fitted polynomial for exp(x/8), squared 3 times
    (relative error below 2e-6 in float32)."""
    y = max(x, np.float32(-4.6)) * np.float32(0.125)
    e = np.float32(_E[0]) + y * (np.float32(_E[1]) + y * (np.float32(_E[2]) + y * (
        np.float32(_E[3]) + y * (np.float32(_E[4]) + y * np.float32(_E[5])))))
    e = e * e
    e = e * e
    return e * e


@njit(cache=True, parallel=True, fastmath=True, nogil=True)
def forward(packed, ranks, tile_offsets, tile_queue, tiles_x, width, height, background,
            rgb, depth, trans, last, cancel):
    """Composite every tile; writes ``rgb (H,W,3)``, ``depth``, final transmittance ``trans`` and
    ``last`` (the slot of the last splat that counted in each pixel, -1 if none).

    A splat visits the tile rows its ellipse reaches and tests all their pixels exactly (pixels
    outside its support fail the tests) in one branch-free loop that vectorises: per-pixel state,
    and each lane's column and row, live in one buffer at fixed offsets, indices are unsigned,
    and a stopped pixel (or one outside the image) keeps its transmittance with a negative sign. Once ``cancel[0]`` is set, each tile stops
    within 64 splats and the tiles not started are skipped (the caller then discards the
    image; see ``cancel.py``).
    """
    q_max = np.float32(SIGMAS * SIGMAS)
    a_min = np.float32(ALPHA_MIN)
    a_max = np.float32(ALPHA_MAX)
    t_min = np.float32(T_MIN)
    one = np.float32(1.0)
    zero = np.float32(0.0)
    half = np.float32(0.5)
    n = np.uint64(TILE * TILE)
    n2, n3, n4, n5 = n + n, n + n + n, n * np.uint64(4), n * np.uint64(5)
    n6, n7 = n * np.uint64(6), n * np.uint64(7)
    for qi in prange(tile_queue.shape[0]):
        if _flag(cancel) != 0:
            continue
        t = tile_queue[qi]
        ty, tx = t // tiles_x, t % tiles_x
        x0, y0 = tx * TILE, ty * TILE
        x1, y1 = min(x0 + TILE, width) - 1, min(y0 + TILE, height) - 1
        row_len = x1 - x0 + 1
        # T, r, g, b, depth, last (tile-local index, as float32: exact below 2^24), each lane's
        # column and row in the tile; lanes outside the image are stopped from the start
        st = np.zeros(8 * TILE * TILE, np.float32)
        st[5 * TILE * TILE:6 * TILE * TILE] = -1.0
        for m in range(TILE * TILE):
            inside = (m % TILE < row_len) & (m // TILE <= y1 - y0)
            st[m] = 1.0 if inside else -1.0
            st[6 * TILE * TILE + m] = np.float32(m % TILE)
            st[7 * TILE * TILE + m] = np.float32(m // TILE)
        n_live = row_len * (y1 - y0 + 1)
        k0 = tile_offsets[t]
        for k in range(k0, tile_offsets[t + 1]):
            p = packed[ranks[k]]
            mx, my = p[MX], p[MY]
            ca, c2b, cc, op = p[CA], np.float32(2.0) * p[CB], p[CC], p[OP]
            r_, g_, b_, z_ = p[CR], p[CG], p[CBL], p[DZ]
            kf = np.float32(k - k0)
            i0, i1 = _rows(p, y0, y1)
            fx0 = np.float32(x0) + half - mx
            fy0 = np.float32(y0) + half - my
            stops = 0
            for pu in range((i0 - y0) * TILE, (i1 - y0 + 1) * TILE):
                pix = np.uint64(pu)
                dx = fx0 + st[n6 + pix]
                dy = fy0 + st[n7 + pix]
                q = (ca * dx + c2b * dy) * dx + cc * dy * dy
                alpha = min(a_max, op * _exp_neg(np.float32(-0.5) * q))
                tp = st[pix]
                t_next = tp * (one - alpha)
                ok = (q <= q_max) & (alpha >= a_min) & (tp > zero)
                stop = ok & (t_next < t_min)
                use = ok & (t_next >= t_min)
                w = alpha * tp if use else zero
                st[n + pix] += w * r_
                st[n2 + pix] += w * g_
                st[n3 + pix] += w * b_
                st[n4 + pix] += w * z_
                st[pix] = t_next if use else (-tp if stop else tp)
                st[n5 + pix] = max(st[n5 + pix], kf if use else zero - one)
                stops += np.int32(1) if stop else np.int32(0)
            n_live -= stops
            if n_live == 0 or ((k & 63) == 0 and _flag(cancel) != 0):
                break
        for i in range(y0, y1 + 1):
            for j in range(x0, x1 + 1):
                pix = np.uint64((i - y0) * TILE + (j - x0))
                tf = abs(st[pix])
                rgb[i, j, 0] = st[n + pix] + tf * background[0]
                rgb[i, j, 1] = st[n2 + pix] + tf * background[1]
                rgb[i, j, 2] = st[n3 + pix] + tf * background[2]
                depth[i, j] = st[n4 + pix]
                trans[i, j] = tf
                lf = st[n5 + pix]
                last[i, j] = np.int32(k0 + np.int64(lf)) if lf >= zero else np.int32(-1)


NGRAD = 10  # per-slot gradient: mean2d x, y, conic a, b, c, opacity, colour r, g, b, depth


@njit(cache=True, parallel=True, fastmath=True, nogil=True)
def backward(packed, ranks, tile_offsets, tile_queue, tiles_x, width, height,
             rgb, depth, trans, last, v_rgb, v_alpha, v_depth, slot_grads, cancel):
    """Per-slot gradients of the splats' 2D mean, conic, opacity, colour and depth.

    Front to back like the forward: with ``S`` the pixel's total (colour and depth dotted with
    their gradients, minus the alpha term) and ``R_i = S - Σ_{j<=i} w_j f_j`` what lies behind
    splat ``i``, ``dL/dalpha_i = T_i f_i - R_i / (1 - alpha_i)``. A pixel drops out after the
    last splat that counted in it (saved by the forward), the tile after the last of its pixels'.
    The rows a splat reaches are one loop, as in the forward, so its ten sums are reduced once
    per (tile, splat) pair. Stops as the forward does once ``cancel[0]`` is set.
    """
    q_max = np.float32(SIGMAS * SIGMAS)
    a_min = np.float32(ALPHA_MIN)
    a_max = np.float32(ALPHA_MAX)
    one = np.float32(1.0)
    zero = np.float32(0.0)
    half = np.float32(0.5)
    two = np.float32(2.0)
    nh = np.float32(-0.5)
    n = np.uint64(TILE * TILE)
    n2, n3, n4, n5, n6 = n + n, n + n + n, n * np.uint64(4), n * np.uint64(5), n * np.uint64(6)
    n7, n8 = n * np.uint64(7), n * np.uint64(8)
    for qi in prange(tile_queue.shape[0]):
        if _flag(cancel) != 0:
            continue
        t = tile_queue[qi]
        ty, tx = t // tiles_x, t % tiles_x
        x0, y0 = tx * TILE, ty * TILE
        x1, y1 = min(x0 + TILE, width) - 1, min(y0 + TILE, height) - 1
        k0 = tile_offsets[t]
        # T, rest, dL/dr, dL/dg, dL/db, dL/ddepth, last (tile-local, float32), each lane's column
        # and row in the tile
        st = np.zeros(9 * TILE * TILE, np.float32)
        st[:TILE * TILE] = 1.0
        st[6 * TILE * TILE:7 * TILE * TILE] = -1.0
        for m in range(TILE * TILE):
            st[7 * TILE * TILE + m] = np.float32(m % TILE)
            st[8 * TILE * TILE + m] = np.float32(m // TILE)
        k_end = k0
        for i in range(y0, y1 + 1):
            for j in range(x0, x1 + 1):
                pix = np.uint64((i - y0) * TILE + (j - x0))
                st[n2 + pix] = v_rgb[i, j, 0]
                st[n3 + pix] = v_rgb[i, j, 1]
                st[n4 + pix] = v_rgb[i, j, 2]
                st[n5 + pix] = v_depth[i, j]
                st[n + pix] = (rgb[i, j, 0] * v_rgb[i, j, 0] + rgb[i, j, 1] * v_rgb[i, j, 1]
                               + rgb[i, j, 2] * v_rgb[i, j, 2] + depth[i, j] * v_depth[i, j]
                               - trans[i, j] * v_alpha[i, j])
                if last[i, j] >= 0:
                    lf = np.float32(last[i, j] - k0)
                    st[n6 + pix] = lf
                k_end = max(k_end, last[i, j] + 1)
        for k in range(k0, k_end):
            if (k & 63) == 0 and _flag(cancel) != 0:
                break
            p = packed[ranks[k]]
            mx, my = p[MX], p[MY]
            ca, cbb, cc, op = p[CA], p[CB], p[CC], p[OP]
            cr, cg, cbl, cz = p[CR], p[CG], p[CBL], p[DZ]
            kf = np.float32(k - k0)
            s_q = zero
            s_qy = zero
            s_qyy = zero
            s_qx = zero
            s_qxy = zero
            s_qxx = zero
            s_r = zero
            s_g = zero
            s_bl = zero
            s_z = zero
            i0, i1 = _rows(p, y0, y1)
            fx0 = np.float32(x0) + half - mx
            fy0 = np.float32(y0) + half - my
            # the rows i0..i1 are one run of the tile's row-major state: one loop over all their
            # lanes (lanes right of the image have no last splat and count nowhere), so the sums
            # are reduced once per (tile, splat) pair
            for pu in range((i0 - y0) * TILE, (i1 - y0 + 1) * TILE):
                pix = np.uint64(pu)
                dx = fx0 + st[n7 + pix]
                dy = fy0 + st[n8 + pix]
                q = (ca * dx + two * cbb * dy) * dx + cc * dy * dy
                alpha = min(a_max, op * _exp_neg(nh * q))
                ok = (q <= q_max) & (alpha >= a_min) & (kf <= st[n6 + pix])
                tp = st[pix]
                gr = st[n2 + pix]
                gg = st[n3 + pix]
                gb = st[n4 + pix]
                gd = st[n5 + pix]
                w = alpha * tp if ok else zero
                f = cr * gr + cg * gg + cbl * gb + cz * gd
                r = st[n + pix] - w * f
                st[n + pix] = r
                st[pix] = tp * (one - alpha) if ok else tp
                s_r += w * gr
                s_g += w * gg
                s_bl += w * gb
                s_z += w * gd
                v_al = tp * f - r / (one - alpha)
                v_q = nh * alpha * v_al if ok & (alpha < a_max) else zero
                v_qx = v_q * dx
                v_qy = v_q * dy
                s_q += v_q
                s_qx += v_qx
                s_qy += v_qy
                s_qxx += v_qx * dx
                s_qxy += v_qx * dy
                s_qyy += v_qy * dy
            out = slot_grads[k]
            # dq/dmean = -2 (conic · d); dalpha/dopacity = gauss = alpha / op where it is not clamped
            out[0] = -two * (ca * s_qx + cbb * s_qy)
            out[1] = -two * (cbb * s_qx + cc * s_qy)
            out[2] = s_qxx
            out[3] = two * s_qxy
            out[4] = s_qyy
            out[5] = np.float32(-2.0) * s_q / op
            out[6] = s_r
            out[7] = s_g
            out[8] = s_bl
            out[9] = s_z
        for k in range(k_end, tile_offsets[t + 1]):
            for c in range(NGRAD):
                slot_grads[k, c] = 0.0


@njit(cache=True, parallel=True, nogil=True)
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
