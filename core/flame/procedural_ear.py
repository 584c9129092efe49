"""Ears of the procedural head: closed shells standing out from the sides of the head.

An ear is a thin pillow with a rolled rim (helix), a ridge inside it (antihelix)
and a hollow bowl (concha), built on a polar grid in the ear's own plane. Its
front edge sinks into the head skin; its back edge stands off the head.
"""

from __future__ import annotations

import numpy as np

EAR_RINGS = np.array([0.25, 0.47, 0.63, 0.76, 0.87, 0.95, 1.0])  # the last ring is the shared rim
EAR_SEGMENTS = 20
EAR_ORIGIN = np.array([0.077, -0.006, -0.013])  # centre of the +x ear in its plane
EAR_HALF_HEIGHT = 0.031
CONCHA = np.array([0.004, -0.006])  # (forward, up) of the bowl from the centre


def ear_frame(sign: float):
    """(forward, up, normal) unit vectors of an ear; the normal faces out and slightly forward."""
    normal = np.array([np.cos(np.radians(25.0)) * sign, 0.0, np.sin(np.radians(25.0))])
    up = np.array([0.0, np.cos(np.radians(14.0)), -np.sin(np.radians(14.0))])
    up = up - (up @ normal) * normal
    up /= np.linalg.norm(up)
    forward = np.cross(normal, up) * sign
    return forward, up, normal


def ear_outline(psi):
    """In-plane (forward, up) outline: rounder and wider at the top, narrower lobe."""
    half_width = 0.0150 + 0.0035 * np.sin(psi)
    return np.stack([half_width * np.cos(psi), EAR_HALF_HEIGHT * np.sin(psi)], axis=-1)


def ear_relief(rho, psi):
    """Height of the front surface above the ear plane: rim roll, inner ridge, bowl."""
    planar = rho[..., None] * ear_outline(psi)
    edge = np.sqrt(np.clip(1.0 - rho**2, 0.0, None))
    helix = 0.0024 * np.exp(-(((rho - 0.87) / 0.07) ** 2))
    upper_back = np.clip(0.5 + 0.5 * np.sin(psi) - 0.3 * np.cos(psi), 0.0, 1.0)
    antihelix = 0.0016 * np.exp(-(((rho - 0.6) / 0.09) ** 2)) * upper_back
    bowl = 0.0045 * np.exp(-np.sum(((planar - CONCHA) / np.array([0.0075, 0.009])) ** 2, axis=-1))
    return 0.0022 * edge + (helix + antihelix - bowl) * np.sqrt(edge)


def ear_back(rho):
    """Depth of the back surface below the ear plane (thicker in the middle)."""
    edge = np.sqrt(np.clip(1.0 - rho**2, 0.0, None))
    return -0.0022 * edge - 0.0045 * (1.0 - rho**2) ** 2


def build_ear(sign: float, first_id: int, first_uv: int, uv_box):
    """Vertices, faces, UVs and per-face UV ids of one ear (sign +1: the +x ear).

    The UV box holds the front disc in its left half and the back disc in its right half.
    """
    forward, up, normal = ear_frame(sign)
    origin = EAR_ORIGIN * np.array([sign, 1.0, 1.0])
    psi = 2.0 * np.pi * np.arange(EAR_SEGMENTS) / EAR_SEGMENTS
    rho = np.repeat(EAR_RINGS, EAR_SEGMENTS)
    ang = np.tile(psi, len(EAR_RINGS))
    planar = rho[:, None] * ear_outline(ang)

    def place(plane, height):
        return origin + plane[:, :1] * forward + plane[:, 1:] * up + height[:, None] * normal

    front = place(planar, ear_relief(rho, ang))
    inner = rho < 1.0
    back = place(planar[inner], ear_back(rho[inner]))
    front_centre = origin + ear_relief(np.zeros(1), np.zeros(1))[0] * normal
    back_centre = origin + ear_back(np.zeros(1))[0] * normal
    vertices = np.concatenate([[front_centre], front, [back_centre], back])

    n_rings, seg = len(EAR_RINGS), EAR_SEGMENTS
    f_centre, b_centre = 0, 1 + n_rings * seg

    def f_id(r, s):
        return 1 + r * seg + s % seg

    def b_id(r, s):
        return f_id(n_rings - 1, s) if r == n_rings - 1 else b_centre + 1 + r * seg + s % seg

    # Mirroring the ear flips handedness; swap corner order on the −x side.
    def tri(a, b, c):
        return (a, b, c) if sign > 0 else (a, c, b)

    faces, uv_faces = [], []
    u0, v0, size = uv_box  # a box of width size and height size / 2
    half = 0.5 * size

    def disc_uv(cx, r, a):
        return (cx + 0.46 * half * r * np.cos(a), v0 + half + 0.46 * half * r * np.sin(a))

    front_uv = [disc_uv(u0 + 0.5 * half, 0.0, 0.0)] + [disc_uv(u0 + 0.5 * half, r, a) for r, a in zip(rho, ang)]
    back_uv = [disc_uv(u0 + 1.5 * half, 0.0, 0.0)] + [disc_uv(u0 + 1.5 * half, r, a) for r, a in zip(rho, ang)]
    uv = np.array(front_uv + back_uv)

    def fu(r, s):  # front-disc UV id; ring −1 is the centre
        return first_uv + (0 if r < 0 else 1 + r * seg + s % seg)

    def bu(r, s):
        return fu(r, s) + len(front_uv)

    for s in range(seg):
        faces.append(tri(f_centre, f_id(0, s + 1), f_id(0, s)))
        uv_faces.append(tri(fu(-1, 0), fu(0, s + 1), fu(0, s)))
        faces.append(tri(b_centre, b_id(0, s), b_id(0, s + 1)))
        uv_faces.append(tri(bu(-1, 0), bu(0, s), bu(0, s + 1)))
    for r in range(n_rings - 1):
        for s in range(seg):
            faces += [tri(f_id(r, s), f_id(r, s + 1), f_id(r + 1, s + 1)), tri(f_id(r, s), f_id(r + 1, s + 1), f_id(r + 1, s))]
            uv_faces += [tri(fu(r, s), fu(r, s + 1), fu(r + 1, s + 1)), tri(fu(r, s), fu(r + 1, s + 1), fu(r + 1, s))]
            faces += [tri(b_id(r, s), b_id(r + 1, s + 1), b_id(r, s + 1)), tri(b_id(r, s), b_id(r + 1, s), b_id(r + 1, s + 1))]
            uv_faces += [tri(bu(r, s), bu(r + 1, s + 1), bu(r, s + 1)), tri(bu(r, s), bu(r + 1, s), bu(r + 1, s + 1))]
    return vertices, np.array(faces) + first_id, uv, np.array(uv_faces)
