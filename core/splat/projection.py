"""EWA projection of 3D Gaussians to screen-space ellipses, and its hand-written backward.

Per Gaussian: world mean -> camera (OpenCV axes), covariance ``R S S^T R^T`` -> ``J W Σ W^T J^T +
0.3 I`` with the perspective Jacobian ``J`` (its ``x/z``, ``y/z`` clamped to 1.3x the view as in
3DGS, which keeps far off-screen Gaussians tame). Maths in float64, results float32.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .. import numba_locator  # noqa: F401  (the kernels' cache filed by code: before they are defined)

NEAR = 0.01  # Gaussians with camera depth z <= NEAR are culled
FAR = 1e8  # ... and those with z >= FAR: depth-weighted sums and their gradients stay finite
BLUR = 0.3  # px², added to the 2D covariance (anti-aliasing floor of 3DGS)
MAX_RADIUS = 1 << 30
# px from the image centre beyond which a projected mean is culled: float32 pixel offsets lose
# their precision out there, and the raster kernels' loop bounds must stay exact integers
MAX_OFFSET = 1e6


@njit(cache=True, inline="always")
def _quat_rotation(qw, qx, qy, qz):
    """Rotation matrix of a normalised wxyz quaternion (as 9 scalars, row major)."""
    return (
        1.0 - 2.0 * (qy * qy + qz * qz), 2.0 * (qx * qy - qw * qz), 2.0 * (qx * qz + qw * qy),
        2.0 * (qx * qy + qw * qz), 1.0 - 2.0 * (qx * qx + qz * qz), 2.0 * (qy * qz - qw * qx),
        2.0 * (qx * qz - qw * qy), 2.0 * (qy * qz + qw * qx), 1.0 - 2.0 * (qx * qx + qy * qy),
    )


@njit(cache=True, inline="always")
def _limits(K, width, height):
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    return (
        (width - cx) / fx + 0.3 * width / fx, cx / fx + 0.3 * width / fx,
        (height - cy) / fy + 0.3 * height / fy, cy / fy + 0.3 * height / fy,
    )


@njit(cache=True, parallel=True, nogil=True)
def project_forward(means, quats, scales, viewmat, K, width, height,
                    means2d, conics, depths, cov2d, radii):
    """Fill ``means2d (N,2)``, ``conics (N,3)``, ``depths``, ``cov2d (N,3) f64``, ``radii``.

    ``radii`` is the 3-sigma screen radius ``ceil(3 sqrt(λmax))``; 0 marks a culled Gaussian (behind
    the near plane or non-finite), whose other outputs are zero.
    """
    n = means.shape[0]
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    lxp, lxn, lyp, lyn = _limits(K, width, height)
    V = viewmat
    for g in prange(n):
        means2d[g, 0] = 0.0
        means2d[g, 1] = 0.0
        conics[g, 0] = 0.0
        conics[g, 1] = 0.0
        conics[g, 2] = 0.0
        depths[g] = 0.0
        cov2d[g, 0] = 0.0
        cov2d[g, 1] = 0.0
        cov2d[g, 2] = 0.0
        radii[g] = 0
        mx, my, mz = np.float64(means[g, 0]), np.float64(means[g, 1]), np.float64(means[g, 2])
        tx = V[0, 0] * mx + V[0, 1] * my + V[0, 2] * mz + V[0, 3]
        ty = V[1, 0] * mx + V[1, 1] * my + V[1, 2] * mz + V[1, 3]
        tz = V[2, 0] * mx + V[2, 1] * my + V[2, 2] * mz + V[2, 3]
        if not (NEAR < tz < FAR) or not math.isfinite(tx) or not math.isfinite(ty) or not math.isfinite(tz):
            continue
        qw, qx, qy, qz = (np.float64(quats[g, 0]), np.float64(quats[g, 1]),
                          np.float64(quats[g, 2]), np.float64(quats[g, 3]))
        qn = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        inv = 1.0 / max(qn, 1e-12)
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = _quat_rotation(qw * inv, qx * inv, qy * inv, qz * inv)
        s0, s1, s2 = np.float64(scales[g, 0]), np.float64(scales[g, 1]), np.float64(scales[g, 2])
        # M = R S, Σ = M M^T
        m00, m01, m02 = r00 * s0, r01 * s1, r02 * s2
        m10, m11, m12 = r10 * s0, r11 * s1, r12 * s2
        m20, m21, m22 = r20 * s0, r21 * s1, r22 * s2
        c00 = m00 * m00 + m01 * m01 + m02 * m02
        c01 = m00 * m10 + m01 * m11 + m02 * m12
        c02 = m00 * m20 + m01 * m21 + m02 * m22
        c11 = m10 * m10 + m11 * m11 + m12 * m12
        c12 = m10 * m20 + m11 * m21 + m12 * m22
        c22 = m20 * m20 + m21 * m21 + m22 * m22
        # rows of J W (J = [[fx/z, 0, -fx u/z], [0, fy/z, -fy v/z]], u, v clamped x/z, y/z)
        u = min(max(tx / tz, -lxn), lxp)
        v = min(max(ty / tz, -lyn), lyp)
        j00, j02 = fx / tz, -fx * u / tz
        j11, j12 = fy / tz, -fy * v / tz
        a0 = j00 * V[0, 0] + j02 * V[2, 0]
        a1 = j00 * V[0, 1] + j02 * V[2, 1]
        a2 = j00 * V[0, 2] + j02 * V[2, 2]
        b0 = j11 * V[1, 0] + j12 * V[2, 0]
        b1 = j11 * V[1, 1] + j12 * V[2, 1]
        b2 = j11 * V[1, 2] + j12 * V[2, 2]
        ca0 = c00 * a0 + c01 * a1 + c02 * a2
        ca1 = c01 * a0 + c11 * a1 + c12 * a2
        ca2 = c02 * a0 + c12 * a1 + c22 * a2
        sxx = a0 * ca0 + a1 * ca1 + a2 * ca2 + BLUR
        sxy = b0 * ca0 + b1 * ca1 + b2 * ca2
        syy = (b0 * (c00 * b0 + c01 * b1 + c02 * b2) + b1 * (c01 * b0 + c11 * b1 + c12 * b2)
               + b2 * (c02 * b0 + c12 * b1 + c22 * b2) + BLUR)
        det = sxx * syy - sxy * sxy
        if not (det > 0.0) or not math.isfinite(det):
            continue
        px = fx * tx / tz + cx
        py = fy * ty / tz + cy
        if not (abs(px - 0.5 * width) < MAX_OFFSET and abs(py - 0.5 * height) < MAX_OFFSET):
            continue
        mid = 0.5 * (sxx + syy)
        lam = mid + math.sqrt(max(mid * mid - det, 0.0))
        means2d[g, 0] = px
        means2d[g, 1] = py
        conics[g, 0] = syy / det
        conics[g, 1] = -sxy / det
        conics[g, 2] = sxx / det
        depths[g] = tz
        cov2d[g, 0] = sxx
        cov2d[g, 1] = sxy
        cov2d[g, 2] = syy
        radii[g] = np.int32(math.ceil(min(3.0 * math.sqrt(lam), MAX_RADIUS)))


@njit(cache=True, parallel=True, nogil=True)
def project_backward(means, quats, scales, viewmat, K, width, height, radii,
                     v_means2d, v_conics, v_depths, v_means, v_quats, v_scales):
    """Chain the gradients of ``means2d, conics, depths`` back to ``means, quats, scales``."""
    n = means.shape[0]
    fx, fy = K[0, 0], K[1, 1]
    lxp, lxn, lyp, lyn = _limits(K, width, height)
    V = viewmat
    for g in prange(n):
        for k in range(3):
            v_means[g, k] = 0.0
            v_scales[g, k] = 0.0
            v_quats[g, k] = 0.0
        v_quats[g, 3] = 0.0
        if radii[g] <= 0:
            continue
        mx, my, mz = np.float64(means[g, 0]), np.float64(means[g, 1]), np.float64(means[g, 2])
        tx = V[0, 0] * mx + V[0, 1] * my + V[0, 2] * mz + V[0, 3]
        ty = V[1, 0] * mx + V[1, 1] * my + V[1, 2] * mz + V[1, 3]
        tz = V[2, 0] * mx + V[2, 1] * my + V[2, 2] * mz + V[2, 3]
        qw0, qx0, qy0, qz0 = (np.float64(quats[g, 0]), np.float64(quats[g, 1]),
                              np.float64(quats[g, 2]), np.float64(quats[g, 3]))
        qn = math.sqrt(qw0 * qw0 + qx0 * qx0 + qy0 * qy0 + qz0 * qz0)
        inv = 1.0 / max(qn, 1e-12)
        qw, qx, qy, qz = qw0 * inv, qx0 * inv, qy0 * inv, qz0 * inv
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = _quat_rotation(qw, qx, qy, qz)
        s0, s1, s2 = np.float64(scales[g, 0]), np.float64(scales[g, 1]), np.float64(scales[g, 2])
        m00, m01, m02 = r00 * s0, r01 * s1, r02 * s2
        m10, m11, m12 = r10 * s0, r11 * s1, r12 * s2
        m20, m21, m22 = r20 * s0, r21 * s1, r22 * s2
        c00 = m00 * m00 + m01 * m01 + m02 * m02
        c01 = m00 * m10 + m01 * m11 + m02 * m12
        c02 = m00 * m20 + m01 * m21 + m02 * m22
        c11 = m10 * m10 + m11 * m11 + m12 * m12
        c12 = m10 * m20 + m11 * m21 + m12 * m22
        c22 = m20 * m20 + m21 * m21 + m22 * m22
        rx, ry = tx / tz, ty / tz
        u = min(max(rx, -lxn), lxp)
        v = min(max(ry, -lyn), lyp)
        j00, j02 = fx / tz, -fx * u / tz
        j11, j12 = fy / tz, -fy * v / tz
        a0 = j00 * V[0, 0] + j02 * V[2, 0]
        a1 = j00 * V[0, 1] + j02 * V[2, 1]
        a2 = j00 * V[0, 2] + j02 * V[2, 2]
        b0 = j11 * V[1, 0] + j12 * V[2, 0]
        b1 = j11 * V[1, 1] + j12 * V[2, 1]
        b2 = j11 * V[1, 2] + j12 * V[2, 2]
        ca0 = c00 * a0 + c01 * a1 + c02 * a2
        ca1 = c01 * a0 + c11 * a1 + c12 * a2
        ca2 = c02 * a0 + c12 * a1 + c22 * a2
        cb0 = c00 * b0 + c01 * b1 + c02 * b2
        cb1 = c01 * b0 + c11 * b1 + c12 * b2
        cb2 = c02 * b0 + c12 * b1 + c22 * b2
        sxx = a0 * ca0 + a1 * ca1 + a2 * ca2 + BLUR
        sxy = b0 * ca0 + b1 * ca1 + b2 * ca2
        syy = b0 * cb0 + b1 * cb1 + b2 * cb2 + BLUR
        det = sxx * syy - sxy * sxy
        pa, pb, pc = syy / det, -sxy / det, sxx / det  # conic P = Σ2^-1
        # dL/dP as a symmetric matrix (b appears twice in P)
        ga, gb, gc = np.float64(v_conics[g, 0]), 0.5 * np.float64(v_conics[g, 1]), np.float64(v_conics[g, 2])
        # H = dL/dΣ2 = -P G P
        t00, t01 = pa * ga + pb * gb, pa * gb + pb * gc
        t10, t11 = pb * ga + pc * gb, pb * gb + pc * gc
        h00 = -(t00 * pa + t01 * pb)
        h01 = -(t00 * pb + t01 * pc)
        h11 = -(t10 * pb + t11 * pc)
        # Σ2 = A C A^T with A = J W (rows a, b): dL/dC = A^T H A, dL/dA = 2 H A C
        ha0, ha1, ha2 = h00 * a0 + h01 * b0, h00 * a1 + h01 * b1, h00 * a2 + h01 * b2
        hb0, hb1, hb2 = h01 * a0 + h11 * b0, h01 * a1 + h11 * b1, h01 * a2 + h11 * b2
        g00 = a0 * ha0 + b0 * hb0
        g01 = a0 * ha1 + b0 * hb1
        g02 = a0 * ha2 + b0 * hb2
        g11 = a1 * ha1 + b1 * hb1
        g12 = a1 * ha2 + b1 * hb2
        g22 = a2 * ha2 + b2 * hb2
        # dL/dA rows (A C is (ca, cb) rows)
        da0 = 2.0 * (h00 * ca0 + h01 * cb0)
        da1 = 2.0 * (h00 * ca1 + h01 * cb1)
        da2 = 2.0 * (h00 * ca2 + h01 * cb2)
        db0 = 2.0 * (h01 * ca0 + h11 * cb0)
        db1 = 2.0 * (h01 * ca1 + h11 * cb1)
        db2 = 2.0 * (h01 * ca2 + h11 * cb2)
        # A = J W -> dL/dJ = dL/dA W^T (only the 4 non-constant entries of J)
        gj00 = da0 * V[0, 0] + da1 * V[0, 1] + da2 * V[0, 2]
        gj02 = da0 * V[2, 0] + da1 * V[2, 1] + da2 * V[2, 2]
        gj11 = db0 * V[1, 0] + db1 * V[1, 1] + db2 * V[1, 2]
        gj12 = db0 * V[2, 0] + db1 * V[2, 1] + db2 * V[2, 2]
        iz = 1.0 / tz
        iz2 = iz * iz
        vx, vy = np.float64(v_means2d[g, 0]), np.float64(v_means2d[g, 1])
        gtx = vx * fx * iz
        gty = vy * fy * iz
        gtz = -(vx * fx * tx + vy * fy * ty) * iz2 + np.float64(v_depths[g])
        gtz += -gj00 * fx * iz2 - gj11 * fy * iz2
        if rx == u:  # j02 = -fx x / z^2
            gtx += -gj02 * fx * iz2
            gtz += 2.0 * gj02 * fx * tx * iz2 * iz
        else:  # j02 = -fx u / z with u clamped
            gtz += gj02 * fx * u * iz2
        if ry == v:
            gty += -gj12 * fy * iz2
            gtz += 2.0 * gj12 * fy * ty * iz2 * iz
        else:
            gtz += gj12 * fy * v * iz2
        for k in range(3):
            v_means[g, k] = V[0, k] * gtx + V[1, k] * gty + V[2, k] * gtz
        # Σ = M M^T: dL/dM = 2 G M (G symmetric)
        dm00 = 2.0 * (g00 * m00 + g01 * m10 + g02 * m20)
        dm01 = 2.0 * (g00 * m01 + g01 * m11 + g02 * m21)
        dm02 = 2.0 * (g00 * m02 + g01 * m12 + g02 * m22)
        dm10 = 2.0 * (g01 * m00 + g11 * m10 + g12 * m20)
        dm11 = 2.0 * (g01 * m01 + g11 * m11 + g12 * m21)
        dm12 = 2.0 * (g01 * m02 + g11 * m12 + g12 * m22)
        dm20 = 2.0 * (g02 * m00 + g12 * m10 + g22 * m20)
        dm21 = 2.0 * (g02 * m01 + g12 * m11 + g22 * m21)
        dm22 = 2.0 * (g02 * m02 + g12 * m12 + g22 * m22)
        v_scales[g, 0] = r00 * dm00 + r10 * dm10 + r20 * dm20
        v_scales[g, 1] = r01 * dm01 + r11 * dm11 + r21 * dm21
        v_scales[g, 2] = r02 * dm02 + r12 * dm12 + r22 * dm22
        G00, G01, G02 = dm00 * s0, dm01 * s1, dm02 * s2
        G10, G11, G12 = dm10 * s0, dm11 * s1, dm12 * s2
        G20, G21, G22 = dm20 * s0, dm21 * s1, dm22 * s2
        dw = 2.0 * (-qz * G01 + qy * G02 + qz * G10 - qx * G12 - qy * G20 + qx * G21)
        dx = 2.0 * (qy * G01 + qz * G02 + qy * G10 - 2.0 * qx * G11 - qw * G12 + qz * G20
                    + qw * G21 - 2.0 * qx * G22)
        dy = 2.0 * (-2.0 * qy * G00 + qx * G01 + qw * G02 + qx * G10 + qz * G12 - qw * G20
                    + qz * G21 - 2.0 * qy * G22)
        dz = 2.0 * (-2.0 * qz * G00 - qw * G01 + qx * G02 + qw * G10 - 2.0 * qz * G11 + qy * G12
                    + qx * G20 + qy * G21)
        if qn > 1e-12:  # through the normalisation q / |q|
            dot = dw * qw + dx * qx + dy * qy + dz * qz
            v_quats[g, 0] = (dw - qw * dot) * inv
            v_quats[g, 1] = (dx - qx * dot) * inv
            v_quats[g, 2] = (dy - qy * dot) * inv
            v_quats[g, 3] = (dz - qz * dot) * inv
