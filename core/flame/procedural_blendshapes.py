"""Identity and expression blendshapes of the procedural head, as smooth analytic fields.

Identity components are global-ish proportions scaled like FLAME's PCA (a unit
coefficient is one standard deviation, a few millimetres). Expression components
are localized on the face: zero on the back of the head, the neck and the eyeballs;
a coefficient of 1 is a clear expression and 2 a strong one.
"""

from __future__ import annotations

import numpy as np

from .procedural_ear import EAR_ORIGIN
from .procedural_mesh import HeadMesh
from .procedural_rig import jaw_weight, lower_lip_side, smoothstep
from .procedural_sdf import EAR_CENTRE, EYE_CENTRE

SHAPE_NAMES = (
    "head_width", "head_length", "head_height", "face_length", "jaw_width", "nose_size",
    "nose_length", "cheekbones", "brow_ridge", "lip_fullness", "ear_size", "chin_projection",
    "eye_spacing", "face_width", "forehead_slope", "mouth_width", "neck_thickness",
    "face_fullness", "nose_width", "eye_height",
)
EXPRESSION_NAMES = (
    "smile_left", "smile_right", "lip_pucker", "lip_press", "lip_funnel", "mouth_stretch",
    "upper_lip_raise", "lower_lip_depress", "brow_raise_left", "brow_raise_right", "brow_frown",
    "blink_left", "blink_right", "squint", "cheek_puff", "nose_wrinkle", "jaw_forward",
    "mouth_left", "mouth_right", "eye_wide",
)
MOUTH_CORNER = np.array([0.025, -0.061, 0.087])
MOUTH_CENTRE = np.array([0.0, -0.063, 0.098])


def blob(p, centre, radii):
    """Smooth Gaussian falloff around a centre with per-axis radii."""
    return np.exp(-np.sum(((p - centre) / radii) ** 2, axis=-1))


def mirror(point):
    """The point on the other side of the face."""
    return point * np.array([-1.0, 1.0, 1.0])


def both_sides(p, centre, radii):
    """A blob and its mirror image."""
    return blob(p, centre, radii) + blob(p, mirror(centre), radii)


def _vec(field, direction):
    """A scalar falloff times a fixed displacement vector → (V,3)."""
    return field[:, None] * np.asarray(direction, dtype=float)[None, :]


# --- identity ----------------------------------------------------------------------------

def _eye_rigid(mesh: HeadMesh, v: np.ndarray, displacement: np.ndarray) -> np.ndarray:
    """Let the region around each eye, and the eyeball itself, move as one piece."""
    out = displacement.copy()
    for k, sign in enumerate((1.0, -1.0)):
        centre = EYE_CENTRE * np.array([sign, 1.0, 1.0])
        idx = np.argmin(np.linalg.norm(v - centre, axis=1) + 1e3 * (mesh.part != 2 + k))
        centre_disp = displacement[idx]
        near = blob(v, centre + np.array([0.0, 0.0, 0.012]), np.array([0.024, 0.018, 0.02]))[:, None]
        out = out * (1.0 - near) + centre_disp[None] * near
        out[mesh.part == 2 + k] = centre_disp
    return out


def shape_components(mesh: HeadMesh, v: np.ndarray) -> np.ndarray:
    """(V,3,20) identity blendshapes of the base head ``v``; unit coefficient ≈ one std."""
    x, y, z = v.T
    ax = np.abs(x)
    sx = np.sign(x)
    zero = np.zeros_like(x)
    neck_fade = smoothstep(y, -0.16, -0.09)  # the neck bottom stays put
    face = smoothstep(z, 0.02, 0.07)
    lower_face = smoothstep(-y, 0.02, 0.06) * smoothstep(z, -0.03, 0.02)
    nose_c = np.array([0.0, -0.015, 0.105])
    nose = blob(v, nose_c, np.array([0.018, 0.03, 0.025])) * face
    lips = blob(v, MOUTH_CENTRE, np.array([0.03, 0.014, 0.02])) * face
    ears = both_sides(v, EAR_CENTRE + np.array([0.01, 0.0, 0.0]), np.array([0.02, 0.035, 0.025]))
    chin = blob(v, np.array([0.0, -0.098, 0.085]), np.array([0.025, 0.02, 0.025]))
    cheek = both_sides(v, np.array([0.047, -0.002, 0.06]), np.array([0.018, 0.016, 0.02]))
    brow = both_sides(v, np.array([0.025, 0.035, 0.08]), np.array([0.025, 0.012, 0.02]))
    cranium = smoothstep(y, -0.03, 0.03)

    comps = [
        np.stack([0.005 * x / 0.075 * neck_fade, zero, zero], 1),  # head_width
        np.stack([zero, zero, 0.006 * (z + 0.01) / 0.1 * cranium], 1),  # head_length
        np.stack([zero, 0.005 * np.clip(y, 0, None) / 0.12, zero], 1),  # head_height
        np.stack([zero, -0.006 * lower_face * smoothstep(-y, 0.03, 0.1) * (1 - 0.5 * smoothstep(-y, 0.11, 0.14)),
                  0.001 * lower_face], 1),  # face_length
        np.stack([0.004 * sx * lower_face * smoothstep(ax, 0.02, 0.05), zero, zero], 1),  # jaw_width
        (v - nose_c) * (0.12 * nose)[:, None],  # nose_size
        np.stack([zero, -0.0015 * nose, 0.0035 * nose * smoothstep(z, 0.09, 0.11)], 1),  # nose_length
        np.stack([0.0025 * sx * cheek, 0.0005 * cheek, 0.002 * cheek], 1),  # cheekbones
        _vec(brow * face, (0.0, 0.0005, 0.0025)),  # brow_ridge
        np.stack([zero, 0.0015 * lips * np.sign(y + 0.063), 0.002 * lips], 1),  # lip_fullness
        (v - EAR_CENTRE * np.stack([sx, np.ones_like(x), np.ones_like(x)], 1)) * (0.1 * ears)[:, None],  # ear_size
        _vec(chin, (0.0, -0.001, 0.004)),  # chin_projection
        np.stack([0.0025 * sx * both_sides(v, EYE_CENTRE, np.array([0.02, 0.02, 0.03])), zero, zero], 1),  # eye_spacing
        np.stack([0.004 * x / 0.07 * face * smoothstep(-y, -0.03, 0.03), zero, zero], 1),  # face_width
        np.stack([zero, zero, 0.004 * smoothstep(y, 0.04, 0.1) * smoothstep(z, 0.0, 0.06)], 1),  # forehead_slope
        np.stack([0.003 * x / 0.025 * lips, zero, zero], 1),  # mouth_width
        np.stack([0.004 * x / 0.056 * (1 - neck_fade * 0.7) * smoothstep(-y, 0.08, 0.12), zero,
                  0.004 * (z + 0.015) / 0.056 * smoothstep(-y, 0.08, 0.12)], 1),  # neck_thickness
        np.stack([0.003 * sx * both_sides(v, np.array([0.045, -0.045, 0.055]), np.array([0.02, 0.025, 0.03])),
                  zero, 0.0015 * both_sides(v, np.array([0.045, -0.045, 0.055]), np.array([0.02, 0.025, 0.03]))], 1),  # face_fullness
        np.stack([0.0025 * x / 0.015 * blob(v, np.array([0.0, -0.03, 0.1]), np.array([0.02, 0.012, 0.02])), zero, zero], 1),  # nose_width
        np.stack([zero, 0.002 * both_sides(v, EYE_CENTRE, np.array([0.02, 0.02, 0.03])), zero], 1),  # eye_height
    ]
    for k, sign in enumerate((1.0, -1.0)):
        ear = mesh.part == 5 + k
        comps[SHAPE_NAMES.index("ear_size")][ear] = 0.08 * (v[ear] - EAR_ORIGIN * np.array([sign, 1.0, 1.0]))
    dirs = np.stack([_eye_rigid(mesh, v, c) for c in comps], axis=2)
    return dirs


# --- expressions -------------------------------------------------------------------------

def _lid_rotation(mesh: HeadMesh, v: np.ndarray, eye: int, upper: bool, reach_rows: int = 7):
    """Displacement that swings a lid about the eye's x axis onto the opposite rim.

    Each lid column turns by the angle between its two rim vertices, fading over
    ``reach_rows`` rows away from the rim; the rim itself lands exactly on the other
    rim, so the eye is closed at a coefficient of 1 (``upper``: the upper lid moves).
    """
    sign = 1.0 if eye == 0 else -1.0
    centre = EYE_CENTRE * np.array([sign, 1.0, 1.0])
    c0, c1 = mesh.eye_columns[eye]
    upper_rim, lower_rim = mesh.upper_lid_rims[eye], mesh.lower_lid_rims[eye]
    u, l = v[upper_rim] - centre, v[lower_rim] - centre
    gap = np.arctan2(u[:, 1], u[:, 2]) - np.arctan2(l[:, 1], l[:, 2])  # elevation difference per column
    displacement = np.zeros_like(v)
    row, col = mesh.skin_row, mesh.skin_col
    in_cols = (col >= c0) & (col <= c1) & (mesh.part == 0)
    if upper:
        side = in_cols & (row <= mesh.eye_row) & (row > mesh.eye_row - reach_rows) & ~mesh.is_lower_copy
        distance = mesh.eye_row - row
    else:
        side = in_cols & (((row == mesh.eye_row) & mesh.is_lower_copy) | (row > mesh.eye_row)) & (row < mesh.eye_row + reach_rows)
        distance = row - mesh.eye_row
    ids = np.flatnonzero(side)
    falloff = (1.0 - distance[ids] / reach_rows) ** 1.5
    angle = gap[col[ids] - c0] * falloff * (1.0 if upper else -1.0)
    q = v[ids] - centre
    # A positive turn about +x lowers a point in front of the centre.
    rotated = np.stack([q[:, 0], q[:, 1] * np.cos(angle) - q[:, 2] * np.sin(angle),
                        q[:, 1] * np.sin(angle) + q[:, 2] * np.cos(angle)], axis=1)
    displacement[ids] = rotated - q
    # Rims meet exactly; corners are shared and do not move.
    rim_from, rim_to = (upper_rim, lower_rim) if upper else (lower_rim, upper_rim)
    displacement[rim_from] = v[rim_to] - v[rim_from]
    return displacement


def expression_components(mesh: HeadMesh, v: np.ndarray) -> np.ndarray:
    """(V,3,n_expr) expression blendshapes in the order of ``EXPRESSION_NAMES``."""
    x, y, z = v.T
    sx = np.sign(x)
    lower = lower_lip_side(mesh)
    upper = 1.0 - lower
    lips = blob(v, MOUTH_CENTRE, np.array([0.032, 0.016, 0.03]))
    across = np.clip(1.0 - (x / 0.027) ** 2, 0.0, None)  # 1 mid-mouth, 0 at the corners
    near_seam = np.exp(-(((y - MOUTH_CENTRE[1]) / 0.007) ** 2))
    jaw = jaw_weight(mesh, v)

    def corner(side):
        return blob(v, MOUTH_CORNER * np.array([side, 1, 1]), np.array([0.02, 0.018, 0.025]))

    def cheek(side):
        return blob(v, np.array([0.036 * side, -0.03, 0.072]), np.array([0.022, 0.02, 0.03]))

    above_lids = smoothstep(y, EYE_CENTRE[1] + 0.008, EYE_CENTRE[1] + 0.018)

    def brow(side):
        return above_lids * (blob(v, np.array([0.03 * side, 0.036, 0.08]), np.array([0.024, 0.02, 0.04]))
                             + 0.5 * blob(v, np.array([0.03 * side, 0.06, 0.08]), np.array([0.03, 0.03, 0.04])))

    def smile(side):
        c, ch = corner(side), cheek(side)
        return np.stack([0.004 * side * c, 0.006 * c + 0.0025 * ch, -0.0025 * c + 0.0015 * ch], 1)

    inner_brow = both_sides(v, np.array([0.014, 0.033, 0.088]), np.array([0.014, 0.014, 0.03]))
    puff = both_sides(v, np.array([0.042, -0.048, 0.06]), np.array([0.018, 0.02, 0.025]))
    nose_side = both_sides(v, np.array([0.014, -0.026, 0.095]), np.array([0.012, 0.012, 0.02]))
    bridge = blob(v, np.array([0.0, 0.01, 0.09]), np.array([0.012, 0.012, 0.02]))
    upper_lip = blob(v, np.array([0.0, -0.054, 0.098]), np.array([0.026, 0.012, 0.03])) * upper
    lower_lip = blob(v, np.array([0.0, -0.074, 0.096]), np.array([0.026, 0.014, 0.03])) * lower
    squint_cheek = both_sides(v, np.array([0.034, -0.004, 0.074]), np.array([0.018, 0.012, 0.025]))

    comps = [
        smile(1.0),  # smile_left (+x is the subject's left)
        smile(-1.0),  # smile_right
        np.stack([-0.35 * x * lips, np.zeros_like(x), 0.006 * lips * (0.4 + 0.6 * near_seam)], 1),  # lip_pucker
        np.stack([np.zeros_like(x), -0.25 * (y - MOUTH_CENTRE[1]) * lips, -0.0025 * lips * near_seam], 1),  # lip_press
        np.stack([-0.15 * x * lips, 0.0025 * across * near_seam * (upper - lower) * lips,
                  0.004 * lips], 1),  # lip_funnel
        np.stack([0.005 * sx * (corner(1) + corner(-1)), -0.002 * (corner(1) + corner(-1)) - 0.0015 * lower_lip,
                  -0.001 * (corner(1) + corner(-1))], 1),  # mouth_stretch
        _vec(upper_lip * (0.4 + 0.6 * across), (0.0, 0.0045, 0.001)),  # upper_lip_raise
        _vec(lower_lip * (0.4 + 0.6 * across), (0.0, -0.0045, 0.001)),  # lower_lip_depress
        _vec(brow(1.0), (0.0, 0.005, 0.0005)),  # brow_raise_left
        _vec(brow(-1.0), (0.0, 0.005, 0.0005)),  # brow_raise_right
        np.stack([-0.003 * sx * inner_brow, -0.003 * inner_brow, 0.001 * inner_brow], 1),  # brow_frown
        _lid_rotation(mesh, v, 0, upper=True),  # blink_left
        _lid_rotation(mesh, v, 1, upper=True),  # blink_right
        0.35 * (_lid_rotation(mesh, v, 0, upper=False) + _lid_rotation(mesh, v, 1, upper=False))
        + _vec(squint_cheek, (0.0, 0.002, 0.0005)),  # squint
        np.stack([0.005 * sx * puff, 0.0005 * puff, 0.002 * puff], 1),  # cheek_puff
        _vec(nose_side, (0.0, 0.003, -0.0005)) + _vec(bridge, (0.0, 0.0015, -0.0008))
        + _vec(upper_lip, (0.0, 0.0015, 0.0)),  # nose_wrinkle
        _vec(jaw, (0.0, 0.0, 0.005)),  # jaw_forward
        _vec(lips * (0.5 + 0.5 * np.clip(across, 0, 1)), (0.005, 0.0, 0.0)),  # mouth_left
        _vec(lips * (0.5 + 0.5 * np.clip(across, 0, 1)), (-0.005, 0.0, 0.0)),  # mouth_right
        -0.3 * (_lid_rotation(mesh, v, 0, upper=True) + _lid_rotation(mesh, v, 1, upper=True)),  # eye_wide
    ]
    dirs = np.stack(comps, axis=2)
    # Expressions live on the face: nothing behind the ears, on the neck, or on the eyeballs.
    face = smoothstep(z, -0.015, 0.02) * smoothstep(y, -0.15, -0.115)
    dirs *= face[:, None, None]
    dirs[np.isin(mesh.part, (2, 3, 5, 6))] = 0.0  # eyeballs and ears
    return dirs

