"""The procedural head's parts inside its openings: the mouth bag, the eye lid linings, the eyeballs."""

from __future__ import annotations

import numpy as np

from .procedural_sdf import EYE_RADIUS
from .procedural_uv import MOUTH_UV_BOX

EYEBALL_RINGS = np.array([0.1, 0.2, 0.3, 0.4, 0.47, 0.53, 0.62, 0.8, 1.05, 1.4, 1.85, 2.35, 2.8])
EYEBALL_SEGMENTS = 20
IRIS_ANGLE = 0.52  # angular radius of the iris on the eyeball
EYE_UV_POWER = 0.6


def build_mouth_bag(vertices, upper_rim, lower_rim):
    """A closed pouch behind the lips: rings stepping back from the lip rims to a back cap.

    Returns new vertices, faces (indices into the joint array), ring numbers and a
    lower-half flag per new vertex, and UVs for the bag's own texture box.
    """
    loop = np.concatenate([upper_rim, lower_rim[-2:0:-1]])
    n = len(loop)
    is_lower = np.concatenate([np.zeros(len(upper_rim), bool), np.ones(n - len(upper_rim), bool)])
    is_lower_f = is_lower.astype(float)
    is_lower_f[0] = is_lower_f[len(upper_rim) - 1] = 0.5
    rim = vertices[loop]
    centre = rim.mean(axis=0)
    half_width = np.abs(rim[:, 0] - centre[0]).max()
    lateral = np.clip(1.0 - ((rim[:, 0] - centre[0]) / half_width) ** 2, 0.0, None) ** 0.5
    side = np.where(is_lower, -1.0, 1.0)
    side[0] = side[len(upper_rim) - 1] = 0.0
    # (depth, height, width scale) of each ring: lip lining, the biting edge of the teeth,
    # the teeth's front, then the cavity. The biting edges reach a little past the lip
    # seam, so teeth show when the mouth opens (the rows overlap, hidden, when it is closed).
    # At the corners the rings only step back and inwards, so no triangle collapses.
    profile = [(0.0025, 0.0008, 0.97), (0.005, -0.0018, 0.95), (0.009, 0.008, 0.97),
               (0.02, 0.014, 1.05), (0.034, 0.014, 0.95), (0.045, 0.009, 0.65)]
    rings = [loop]
    new_points, ring_no, lower_flag = [], [], []
    next_id = len(vertices)
    for k, (depth, height, scale) in enumerate(profile, start=1):
        point = rim.copy()
        point[:, 0] = centre[0] + (rim[:, 0] - centre[0]) * scale
        point[:, 1] = rim[:, 1] + side * height * (0.35 + 0.65 * lateral)
        point[:, 2] = rim[:, 2] - depth - 0.004 * (1.0 - lateral)
        ids = np.arange(next_id, next_id + n)
        next_id += n
        rings.append(ids)
        new_points.append(point)
        ring_no += [k] * n
        lower_flag.append(is_lower_f)
    back = centre + np.array([0.0, 0.0, -profile[-1][0] - 0.008])
    back_id = next_id
    new_points.append(back[None])
    ring_no.append(len(profile) + 1)
    lower_flag.append(np.array([0.5]))

    faces = []
    for k in range(len(rings) - 1):
        outer, inner = rings[k], rings[k + 1]
        for l in range(n):
            a, b = outer[l], outer[(l + 1) % n]
            c, d = inner[(l + 1) % n], inner[l]
            faces += [(a, c, b), (a, d, c)]
    last = rings[-1]
    for l in range(n):
        faces.append((last[l], back_id, last[(l + 1) % n]))

    # UVs: rings run across the box's height, the loop along its width.
    u0, v0, w, h = MOUTH_UV_BOX
    n_rings = len(rings)
    vt, ft = [], []
    for k in range(n_rings + 1):
        for l in range(n + 1):
            vt.append((u0 + w * (0.02 + 0.96 * l / n), v0 + h * (0.98 - 0.96 * k / n_rings)))

    def uv(k, l):
        return k * (n + 1) + l
    for k in range(n_rings - 1):
        for l in range(n):
            ft += [(uv(k, l), uv(k + 1, l + 1), uv(k, l + 1)), (uv(k, l), uv(k + 1, l), uv(k + 1, l + 1))]
    for l in range(n):
        ft.append((uv(n_rings - 1, l), uv(n_rings, l), uv(n_rings - 1, l + 1)))
    return (np.concatenate(new_points), np.array(faces), np.array(ring_no), np.concatenate(lower_flag),
            np.array(vt), np.array(ft), loop)


def build_lid_lining(vertices, upper_rim, lower_rim, centre, first_id, uv_box):
    """A strip from an eye opening's rim into the eyeball, hiding the gap at the corners."""
    loop = np.concatenate([upper_rim, lower_rim[-2:0:-1]])
    n = len(loop)
    offset = vertices[loop] - centre
    inner = centre + offset * (0.9 * EYE_RADIUS / np.linalg.norm(offset, axis=1, keepdims=True))
    ids = first_id + np.arange(n)
    faces = []
    for l in range(n):
        a, b, c, d = loop[l], loop[(l + 1) % n], ids[(l + 1) % n], ids[l]
        faces += [(a, c, b), (a, d, c)]
    u0, v0, w, h = uv_box
    vt = [(u0 + w * (0.02 + 0.96 * l / n), v0 + h * (0.9 - 0.8 * k)) for k in (0, 1) for l in range(n + 1)]
    ft = []
    for l in range(n):
        a, b, c, d = l, l + 1, n + 1 + l + 1, n + 1 + l
        ft += [(a, c, b), (a, d, c)]
    return inner, np.array(faces), np.array(vt), np.array(ft)


def build_eyeball(centre, uv_box):
    """A UV sphere around +z with a slightly bulging cornea; UVs are an azimuthal map of the front."""
    rings = EYEBALL_RINGS
    seg = EYEBALL_SEGMENTS
    psi = 2.0 * np.pi * np.arange(seg) / seg
    theta = np.repeat(rings, seg)
    az = np.tile(psi, len(rings))
    radius = EYE_RADIUS + 0.0011 * np.clip(1.0 - (theta / 0.6) ** 2, 0.0, None)
    ring_pts = np.stack([np.sin(theta) * np.cos(az), np.sin(theta) * np.sin(az), np.cos(theta)], axis=-1)
    points = np.concatenate([[[0.0, 0.0, EYE_RADIUS + 0.0011]], radius[:, None] * ring_pts,
                             [[0.0, 0.0, -EYE_RADIUS]]]) + centre
    front, back = 0, len(points) - 1

    def vid(r, s):
        return 1 + r * seg + s % seg

    faces = []
    for s in range(seg):
        faces.append((front, vid(0, s), vid(0, s + 1)))
    for r in range(len(rings) - 1):
        for s in range(seg):
            faces += [(vid(r, s), vid(r + 1, s), vid(r + 1, s + 1)), (vid(r, s), vid(r + 1, s + 1), vid(r, s + 1))]
    for s in range(seg):
        faces.append((vid(len(rings) - 1, s), back, vid(len(rings) - 1, s + 1)))

    u0, v0, size = uv_box
    half = 0.5 * size * 0.96
    cu, cv = u0 + 0.5 * size, v0 + 0.5 * size

    def uv_of(th, a):
        r = half * (th / np.pi) ** EYE_UV_POWER  # the front (iris) gets the most texels
        return (cu + r * np.cos(a), cv + r * np.sin(a))

    # Vertex UVs serve every face (the azimuthal map has no seam) except the back pole,
    # which gets one UV per fan triangle on the rim of the disc.
    vt = [uv_of(0.0, 0.0)] + [uv_of(t, a) for t, a in zip(theta, az)] + [uv_of(np.pi, 0.0)]
    ft = np.array(faces)
    first_back = len(faces) - seg
    for s in range(seg):
        vt.append(uv_of(np.pi * 0.999, psi[s] + np.pi / seg))
        ft[first_back + s, 1] = len(vt) - 1
    vt = np.array(vt)
    return points, np.array(faces), vt, ft
