"""The implicit surface of the procedural head: smooth unions of simple solids.

Negative inside. The skin mesh is found by intersecting rays with this field, so
it only needs the right sign and smoothness, not exact distances. All lengths in
metres, FLAME axes (y up, +z front, +x the subject's left).
"""

from __future__ import annotations

import numpy as np

EYE_CENTRE = np.array([0.031, 0.017, 0.060])  # the +x eyeball; mirror for the other
EYE_RADIUS = 0.012
LID_RADIUS = 0.0134  # lids rest on a sphere slightly larger than the eyeball
EAR_CENTRE = np.array([0.074, -0.002, -0.012])


def ellipsoid(p, centre, radii):
    """Approximate signed distance to an axis-aligned ellipsoid."""
    q = (p - centre) / radii
    k0 = np.linalg.norm(q, axis=-1)
    k1 = np.linalg.norm(q / radii, axis=-1)
    return k0 * (k0 - 1.0) / np.maximum(k1, 1e-12)


def tapered_capsule(p, a, b, ra, rb):
    """Distance to a segment a→b whose radius goes from ra to rb."""
    ab = b - a
    h = np.clip(((p - a) @ ab) / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(p - a - h[..., None] * ab, axis=-1) - (ra + (rb - ra) * h)


def smooth_union(a, b, k):
    h = np.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b + (a - b) * h - k * h * (1.0 - h)


def smooth_intersect(a, b, k):
    """Keep what is inside both solids, with a rounded edge."""
    return -smooth_union(-a, -b, k)


def smooth_subtract(a, b, k):
    """Remove solid b from solid a with a rounded edge."""
    return -smooth_union(-a, b, k)


def mirrored(p):
    """Fold x so one-sided features serve both sides."""
    q = p.copy()
    q[..., 0] = np.abs(q[..., 0])
    return q


def _ear(p):
    """An ear: a flattened disc standing out from the side, with a hollow bowl."""
    q = mirrored(p) - EAR_CENTRE
    normal = np.array([0.91, 0.0, 0.41])
    up = np.array([0.0, 1.0, 0.0])
    along = np.cross(up, normal)
    local = np.stack([q @ normal, q @ up, q @ along], axis=-1)
    # Lean the top of the ear backwards a little.
    tilt = 0.25
    ly = local[..., 1] * np.cos(tilt) - local[..., 2] * np.sin(tilt)
    lz = local[..., 1] * np.sin(tilt) + local[..., 2] * np.cos(tilt)
    local = np.stack([local[..., 0] - 0.006, ly, lz], axis=-1)
    disc = ellipsoid(local, np.zeros(3), np.array([0.0075, 0.031, 0.019]))
    bowl = ellipsoid(local, np.array([0.009, -0.004, 0.003]), np.array([0.008, 0.012, 0.0095]))
    return smooth_subtract(disc, bowl, 0.003)


def _nose(p):
    """Nose: a rounded wedge for the bridge (sloping sides), a ball tip, wings and nostrils."""
    q = mirrored(p)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    t = np.clip((0.021 - y) / 0.047, 0.0, 1.0)  # 0 at the root between the eyes, 1 at the tip
    dorsum = 0.086 + 0.030 * t + 0.002 * np.sin(np.pi * t)
    half_angle = np.radians(30.0 + 16.0 * t)
    soft_x = np.sqrt(x * x + 0.0035**2)
    wedge = soft_x * np.cos(half_angle) + (z - dorsum) * np.sin(half_angle)
    wedge = smooth_intersect(wedge, y - 0.025, 0.006)  # starts below the brow
    wedge = smooth_intersect(wedge, -0.034 - y, 0.004)  # ends at the nose base
    wedge = smooth_intersect(wedge, 0.05 - z, 0.01)  # and does not reach into the head
    tip = ellipsoid(p, np.array([0.0, -0.026, 0.1115]), np.array([0.0105, 0.0095, 0.0100]))
    alae = ellipsoid(q, np.array([0.0130, -0.033, 0.0965]), np.array([0.0085, 0.0075, 0.0085]))
    base = ellipsoid(p, np.array([0.0, -0.030, 0.090]), np.array([0.016, 0.011, 0.014]))
    nose = smooth_union(smooth_union(wedge, tip, 0.012), smooth_union(alae, base, 0.006), 0.006)
    nostrils = ellipsoid(q, np.array([0.0068, -0.0405, 0.1035]), np.array([0.0036, 0.0022, 0.0060]))
    return smooth_subtract(nose, nostrils, 0.0015)


def _jaw(p):
    q = mirrored(p)
    body = tapered_capsule(q, np.array([0.052, -0.068, -0.012]), np.array([0.017, -0.096, 0.077]), 0.013, 0.014)
    chin = ellipsoid(p, np.array([0.0, -0.095, 0.085]), np.array([0.021, 0.016, 0.015]))
    lower_face = ellipsoid(p, np.array([0.0, -0.052, 0.036]), np.array([0.056, 0.048, 0.0635]))
    cheeks = ellipsoid(mirrored(p), np.array([0.037, -0.034, 0.054]), np.array([0.022, 0.024, 0.024]))
    return smooth_union(smooth_union(smooth_union(body, chin, 0.012), lower_face, 0.02), cheeks, 0.015)


def head_sdf(p: np.ndarray) -> np.ndarray:
    """Signed field of the base head (skin, closed lids, no mouth opening) at points (...,3)."""
    q = mirrored(p)
    cranium = ellipsoid(p, np.array([0.0, 0.028, -0.012]), np.array([0.0745, 0.094, 0.097]))
    midface = ellipsoid(p, np.array([0.0, -0.004, 0.030]), np.array([0.062, 0.050, 0.056]))
    neck = tapered_capsule(p, np.array([0.0, -0.26, 0.0]), np.array([0.0, -0.05, -0.022]), 0.059, 0.057)
    cheekbone = ellipsoid(q, np.array([0.046, -0.002, 0.058]), np.array([0.021, 0.013, 0.021]))
    brow = ellipsoid(q, np.array([0.022, 0.038, 0.062]), np.array([0.032, 0.0115, 0.021]))
    d = smooth_union(cranium, midface, 0.02)
    d = smooth_union(d, _jaw(p), 0.018)
    d = smooth_union(d, neck, 0.04)
    shoulders = ellipsoid(p, np.array([0.0, -0.25, -0.025]), np.array([0.09, 0.06, 0.065]))
    d = smooth_union(d, shoulders, 0.03)
    d = smooth_union(d, cheekbone, 0.012)
    d = smooth_union(d, brow, 0.014)
    socket = ellipsoid(q, EYE_CENTRE + np.array([0.0, -0.003, 0.019]), np.array([0.020, 0.0135, 0.0125]))
    d = smooth_subtract(d, socket, 0.016)
    lids = np.linalg.norm(q - EYE_CENTRE, axis=-1) - LID_RADIUS
    d = smooth_union(d, lids, 0.006)
    d = smooth_union(d, _nose(p), 0.011)
    d = smooth_union(d, ellipsoid(q, EAR_CENTRE + np.array([-0.004, -0.004, 0.0]), np.array([0.006, 0.02, 0.012])), 0.006)
    return d


def hairline_height(p, recession=0.0):
    """Height of the hairline around the head: forehead, temples, above the ears, nape.

    ``recession`` lifts the front (receding temples most).
    """
    azimuth = np.degrees(np.abs(np.arctan2(p[..., 0], p[..., 2])))
    front = np.interp(azimuth, [0, 12, 28, 45, 62, 80, 100, 125, 150, 180],
                      [0.079, 0.080, 0.084, 0.066, 0.048, 0.040, 0.036, -0.02, -0.06, -0.072])
    lift = recession * np.interp(azimuth, [0, 28, 60, 90], [0.6, 1.0, 0.5, 0.0])
    return front + lift


def hair_volume(p):
    """Outward offset of the scalp where hair grows, so the head has a haircut's outline."""
    rise = np.clip((p[..., 1] - hairline_height(p)) / 0.03, 0.0, 1.0)
    return 0.005 * rise * rise * (3.0 - 2.0 * rise)


def march_rays(origins: np.ndarray, directions: np.ndarray, r_max: float = 0.3, steps: int = 64) -> np.ndarray:
    """Distance along each ray to the outermost surface crossing, found from outside in.

    Rays start inside the head; sampling from far away inwards finds the first
    outside→inside transition, which bisection then refines.
    """
    radii = np.linspace(r_max, 0.0, steps)
    inside = np.empty((len(origins), steps), dtype=bool)
    for k, r in enumerate(radii):
        inside[:, k] = head_sdf(origins + r * directions) < 0
    first_inside = np.argmax(inside, axis=1)
    outer = radii[np.maximum(first_inside - 1, 0)]
    inner = radii[first_inside]
    for _ in range(24):
        mid = 0.5 * (outer + inner)
        is_in = head_sdf(origins + mid[:, None] * directions) < 0
        inner = np.where(is_in, mid, inner)
        outer = np.where(is_in, outer, mid)
    return 0.5 * (outer + inner)
