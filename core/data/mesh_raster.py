"""numba kernels of the reference mesh renderer: clip, set up, bin, rasterize, shade.

The stages are deliberately plain (a z-buffer rasterizer, deferred shading) and share no code
with the Gaussian splat engine: this renderer produces the ground truth that engine is scored
against. Screen coordinates are pixels with pixel (i, j) centred at (j + 0.5, i + 0.5).

Parallelism: the image is cut into horizontal bands of ``BAND`` rows; triangles are binned to
the bands their bounding box touches, and each thread owns whole bands, so no two threads ever
write the same z-buffer entry.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .. import numba_locator  # noqa: F401  (the kernels' cache filed by code: before they are defined)

BAND = 16  # rows per band (in supersampled pixels)


@nb.njit(cache=True)
def clip_near(cam, uv, nrm, near):
    """Clip triangles (F,3,3 camera-space points) against the plane ``z = near``.

    ``uv`` (F,3,2) and world normals ``nrm`` (F,3,3) are carried along. A triangle with one
    vertex behind the plane becomes two triangles, with two behind one triangle, with three
    behind none. Returns the clipped arrays and ``src`` (the source face of each output).
    """
    nf = cam.shape[0]
    out_p = np.empty((2 * nf, 3, 3))
    out_uv = np.empty((2 * nf, 3, 2))
    out_n = np.empty((2 * nf, 3, 3))
    src = np.empty(2 * nf, np.int64)
    poly_p = np.empty((4, 3))
    poly_uv = np.empty((4, 2))
    poly_n = np.empty((4, 3))
    count = 0
    for f in range(nf):
        inside = 0
        for k in range(3):
            if cam[f, k, 2] >= near:
                inside += 1
        if inside == 0:
            continue
        if inside == 3:
            out_p[count] = cam[f]
            out_uv[count] = uv[f]
            out_n[count] = nrm[f]
            src[count] = f
            count += 1
            continue
        # Sutherland-Hodgman against one plane: at most 4 vertices result.
        m = 0
        for k in range(3):
            a = k
            b = (k + 1) % 3
            za = cam[f, a, 2]
            zb = cam[f, b, 2]
            a_in = za >= near
            b_in = zb >= near
            if a_in:
                poly_p[m] = cam[f, a]
                poly_uv[m] = uv[f, a]
                poly_n[m] = nrm[f, a]
                m += 1
            if a_in != b_in:
                s = (near - za) / (zb - za)
                for c in range(3):
                    poly_p[m, c] = cam[f, a, c] + s * (cam[f, b, c] - cam[f, a, c])
                    poly_n[m, c] = nrm[f, a, c] + s * (nrm[f, b, c] - nrm[f, a, c])
                for c in range(2):
                    poly_uv[m, c] = uv[f, a, c] + s * (uv[f, b, c] - uv[f, a, c])
                poly_p[m, 2] = near
                m += 1
        for t in range(1, m - 1):
            out_p[count, 0] = poly_p[0]
            out_p[count, 1] = poly_p[t]
            out_p[count, 2] = poly_p[t + 1]
            out_uv[count, 0] = poly_uv[0]
            out_uv[count, 1] = poly_uv[t]
            out_uv[count, 2] = poly_uv[t + 1]
            out_n[count, 0] = poly_n[0]
            out_n[count, 1] = poly_n[t]
            out_n[count, 2] = poly_n[t + 1]
            src[count] = f
            count += 1
    return out_p[:count], out_uv[:count], out_n[:count], src[:count]


@nb.njit(cache=True, parallel=True)
def setup_triangles(cam, fx, fy, cx, cy, width, height, cull_back):
    """Project clipped triangles to screen; returns screen xy (T,3,2), 1/z (T,3), bbox (T,4), flip (T,).

    ``bbox`` holds inclusive pixel ranges ``x0, x1, y0, y1`` of candidate pixel centres, with
    ``x1 < x0`` marking a triangle that is culled (off screen, degenerate, or back-facing when
    ``cull_back``). ``flip`` is True for triangles seen from their back side (clockwise on
    screen for counter-clockwise-outward winding); their shading normal is negated.
    """
    nt = cam.shape[0]
    xy = np.empty((nt, 3, 2))
    iz = np.empty((nt, 3))
    bbox = np.empty((nt, 4), np.int64)
    flip = np.zeros(nt, np.bool_)
    for t in nb.prange(nt):
        for k in range(3):
            z = cam[t, k, 2]
            iz[t, k] = 1.0 / z
            xy[t, k, 0] = fx * cam[t, k, 0] / z + cx
            xy[t, k, 1] = fy * cam[t, k, 1] / z + cy
        # Signed area on screen; y points down, so counter-clockwise in 3D (seen from the
        # front) is negative here.
        area = (xy[t, 1, 0] - xy[t, 0, 0]) * (xy[t, 2, 1] - xy[t, 0, 1]) - (xy[t, 2, 0] - xy[t, 0, 0]) * (
            xy[t, 1, 1] - xy[t, 0, 1]
        )
        back = area > 0.0
        flip[t] = back
        xmin = min(xy[t, 0, 0], xy[t, 1, 0], xy[t, 2, 0])
        xmax = max(xy[t, 0, 0], xy[t, 1, 0], xy[t, 2, 0])
        ymin = min(xy[t, 0, 1], xy[t, 1, 1], xy[t, 2, 1])
        ymax = max(xy[t, 0, 1], xy[t, 1, 1], xy[t, 2, 1])
        x0 = max(0.0, math.ceil(xmin - 0.5))
        x1 = min(width - 1.0, math.floor(xmax - 0.5))
        y0 = max(0.0, math.ceil(ymin - 0.5))
        y1 = min(height - 1.0, math.floor(ymax - 0.5))
        if area == 0.0 or (cull_back and back) or not (x0 <= x1 and y0 <= y1):
            bbox[t, 0] = 0
            bbox[t, 1] = -1
            bbox[t, 2] = 0
            bbox[t, 3] = -1
        else:
            bbox[t, 0] = int(x0)
            bbox[t, 1] = int(x1)
            bbox[t, 2] = int(y0)
            bbox[t, 3] = int(y1)
    return xy, iz, bbox, flip


@nb.njit(cache=True)
def bin_to_bands(bbox, n_bands):
    """CSR lists of the triangles touching each band: ``(start (n_bands+1,), tris)``."""
    nt = bbox.shape[0]
    counts = np.zeros(n_bands + 1, np.int64)
    for t in range(nt):
        if bbox[t, 1] < bbox[t, 0]:
            continue
        for b in range(bbox[t, 2] // BAND, bbox[t, 3] // BAND + 1):
            counts[b + 1] += 1
    for b in range(n_bands):
        counts[b + 1] += counts[b]
    tris = np.empty(counts[n_bands], np.int64)
    fill = counts[:n_bands].copy()
    for t in range(nt):
        if bbox[t, 1] < bbox[t, 0]:
            continue
        for b in range(bbox[t, 2] // BAND, bbox[t, 3] // BAND + 1):
            tris[fill[b]] = t
            fill[b] += 1
    return counts, tris


@nb.njit(cache=True, parallel=True)
def rasterize(xy, iz, bbox, start, tris, width, height):
    """Z-buffer visibility: per pixel the nearest triangle id (-1: none) and its
    perspective-correct barycentrics ``(b1, b2)`` (``b0 = 1 - b1 - b2``)."""
    tri_id = np.full((height, width), -1, np.int32)
    bary = np.zeros((height, width, 2), np.float32)
    n_bands = start.shape[0] - 1
    for band in nb.prange(n_bands):
        r0 = band * BAND
        r1 = min(height, r0 + BAND)
        zbuf = np.zeros((r1 - r0, width))  # stores 1/z; larger is nearer; 0 is "far away"
        for k in range(start[band], start[band + 1]):
            t = tris[k]
            ax = xy[t, 0, 0]
            ay = xy[t, 0, 1]
            bx = xy[t, 1, 0]
            by = xy[t, 1, 1]
            qx = xy[t, 2, 0]
            qy = xy[t, 2, 1]
            area = (bx - ax) * (qy - ay) - (qx - ax) * (by - ay)
            inv_area = 1.0 / area
            iz0 = iz[t, 0]
            iz1 = iz[t, 1]
            iz2 = iz[t, 2]
            y_lo = max(r0, bbox[t, 2])
            y_hi = min(r1 - 1, bbox[t, 3])
            for i in range(y_lo, y_hi + 1):
                py = i + 0.5
                for j in range(bbox[t, 0], bbox[t, 1] + 1):
                    px = j + 0.5
                    l1 = ((px - ax) * (qy - ay) - (qx - ax) * (py - ay)) * inv_area
                    l2 = ((bx - ax) * (py - ay) - (px - ax) * (by - ay)) * inv_area
                    l0 = 1.0 - l1 - l2
                    if l0 < 0.0 or l1 < 0.0 or l2 < 0.0:
                        continue
                    w0 = l0 * iz0
                    w1 = l1 * iz1
                    w2 = l2 * iz2
                    inv_z = w0 + w1 + w2
                    if inv_z <= zbuf[i - r0, j]:
                        continue
                    zbuf[i - r0, j] = inv_z
                    tri_id[i, j] = t
                    bary[i, j, 0] = w1 / inv_z
                    bary[i, j, 1] = w2 / inv_z
    return tri_id, bary


@nb.njit(cache=True, inline="always")
def _sample_bilinear(tex, u, v, c):
    """Bilinear lookup of channel ``c``, clamp-to-edge; ``(u, v)`` in OBJ convention (v up)."""
    ht = tex.shape[0]
    wt = tex.shape[1]
    x = min(max(u * wt - 0.5, 0.0), wt - 1.0)
    y = min(max((1.0 - v) * ht - 0.5, 0.0), ht - 1.0)
    x0 = int(x)
    y0 = int(y)
    x1 = min(x0 + 1, wt - 1)
    y1 = min(y0 + 1, ht - 1)
    fx = x - x0
    fy = y - y0
    top = tex[y0, x0, c] * (1.0 - fx) + tex[y0, x1, c] * fx
    bot = tex[y1, x0, c] * (1.0 - fx) + tex[y1, x1, c] * fx
    return top * (1.0 - fy) + bot * fy


@nb.njit(cache=True, parallel=True)
def shade(tri_id, bary, uv, nrm, flip, tex, light_dirs, light_gains, ambient, background):
    """Deferred shading of the visible samples; background where nothing is visible.

    colour = texel * (ambient + sum_k gain_k * max(0, n . l_k)), clipped to [0, 1], where ``n``
    is the interpolated world normal, turned to face the camera on back-facing triangles.
    Returns RGB (H,W,3) float32 and coverage (H,W) float32 (1 where a triangle is visible).
    """
    height, width = tri_id.shape
    rgb = np.empty((height, width, 3), np.float32)
    cover = np.zeros((height, width), np.float32)
    n_lights = light_dirs.shape[0]
    for i in nb.prange(height):
        for j in range(width):
            t = tri_id[i, j]
            if t < 0:
                for c in range(3):
                    rgb[i, j, c] = background[c]
                continue
            b1 = bary[i, j, 0]
            b2 = bary[i, j, 1]
            b0 = 1.0 - b1 - b2
            u = b0 * uv[t, 0, 0] + b1 * uv[t, 1, 0] + b2 * uv[t, 2, 0]
            v = b0 * uv[t, 0, 1] + b1 * uv[t, 1, 1] + b2 * uv[t, 2, 1]
            nx = b0 * nrm[t, 0, 0] + b1 * nrm[t, 1, 0] + b2 * nrm[t, 2, 0]
            ny = b0 * nrm[t, 0, 1] + b1 * nrm[t, 1, 1] + b2 * nrm[t, 2, 1]
            nz = b0 * nrm[t, 0, 2] + b1 * nrm[t, 1, 2] + b2 * nrm[t, 2, 2]
            norm = math.sqrt(nx * nx + ny * ny + nz * nz)
            if norm > 0.0:
                nx /= norm
                ny /= norm
                nz /= norm
            if flip[t]:
                nx = -nx
                ny = -ny
                nz = -nz
            light = ambient
            for k in range(n_lights):
                d = nx * light_dirs[k, 0] + ny * light_dirs[k, 1] + nz * light_dirs[k, 2]
                if d > 0.0:
                    light += light_gains[k] * d
            for c in range(3):
                rgb[i, j, c] = min(max(_sample_bilinear(tex, u, v, c) * light, 0.0), 1.0)
            cover[i, j] = 1.0
    return rgb, cover


@nb.njit(cache=True, parallel=True)
def box_downsample(rgb, cover, s):
    """Average ``s x s`` blocks: supersampled RGB/coverage -> final RGB (h,w,3) and alpha (h,w)."""
    h = rgb.shape[0] // s
    w = rgb.shape[1] // s
    out = np.empty((h, w, 3), np.float32)
    alpha = np.empty((h, w), np.float32)
    inv = 1.0 / (s * s)
    for i in nb.prange(h):
        for j in range(w):
            a = 0.0
            r = 0.0
            g = 0.0
            b = 0.0
            for di in range(s):
                for dj in range(s):
                    y = i * s + di
                    x = j * s + dj
                    a += cover[y, x]
                    r += rgb[y, x, 0]
                    g += rgb[y, x, 1]
                    b += rgb[y, x, 2]
            alpha[i, j] = a * inv
            out[i, j, 0] = r * inv
            out[i, j, 1] = g * inv
            out[i, j, 2] = b * inv
    return out, alpha
