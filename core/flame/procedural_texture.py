"""The colour texture of the procedural head, painted from seeded noise.

Skin texels know where they lie on the head (the skin UVs are the mesh grid), so
features are placed in 3D (lips, brows, hairline, ears) and detail is added in
texture space (pores, freckles, hair strands). Eyeballs and the inner mouth have
their own boxes in the bottom strip of the atlas.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.ndimage import gaussian_filter, zoom

from .procedural_ear import ear_relief
from .procedural_inner import EYE_UV_POWER, IRIS_ANGLE
from .procedural_mesh import HeadMesh
from .procedural_rig import smoothstep
from .procedural_sdf import EAR_CENTRE, EYE_CENTRE, hairline_height
from .procedural_skin import MOUTH_ROW_ANGLE
from .procedural_uv import EAR_UV_BOXES, EYE_UV_BOXES, LID_LINING_UV_BOX, MOUTH_UV_BOX, SKIN_UV_BOTTOM

TEXTURE_SIZE = 1024

SKIN_TONES = np.array([
    [0.93, 0.76, 0.65], [0.87, 0.67, 0.54], [0.80, 0.59, 0.45], [0.68, 0.48, 0.35],
    [0.55, 0.37, 0.26], [0.40, 0.26, 0.18],
])
HAIR_COLOURS = np.array([
    [0.06, 0.05, 0.045], [0.17, 0.11, 0.07], [0.32, 0.20, 0.11], [0.62, 0.47, 0.27],
    [0.45, 0.20, 0.09], [0.55, 0.54, 0.52],
])
IRIS_COLOURS = np.array([
    [0.30, 0.17, 0.08], [0.42, 0.30, 0.13], [0.28, 0.42, 0.28], [0.30, 0.45, 0.62], [0.42, 0.46, 0.50],
])


@dataclasses.dataclass
class Look:
    """Per-subject colouring choices."""

    skin: np.ndarray
    hair: np.ndarray
    iris: np.ndarray
    freckles: float  # how many freckles, 0..1
    lips: np.ndarray
    recession: float = 0.0  # how far the hairline is lifted at the temples (metres)


def subject_look(subject: int) -> Look:
    """Skin tone, hair and iris colour, freckle amount for a subject (subject 0 is fixed)."""
    if subject == 0:
        skin = np.array([0.86, 0.66, 0.53])
        return Look(skin, HAIR_COLOURS[2], IRIS_COLOURS[1], 0.4, np.array([0.70, 0.33, 0.32]), 0.004)
    rng = np.random.default_rng([7919, subject])
    skin = SKIN_TONES[rng.integers(len(SKIN_TONES))] * rng.uniform(0.95, 1.05, 3)
    hair = HAIR_COLOURS[rng.integers(len(HAIR_COLOURS))] * rng.uniform(0.85, 1.15)
    iris = IRIS_COLOURS[rng.integers(len(IRIS_COLOURS))] * rng.uniform(0.85, 1.15, 3)
    freckles = float(rng.uniform(0.0, 1.0) ** 2)
    lips = skin * np.array([0.85, 0.52, 0.55]) * rng.uniform(0.9, 1.05)
    recession = float(rng.uniform(-0.004, 0.018))
    return Look(np.clip(skin, 0, 1), np.clip(hair, 0, 1), np.clip(iris, 0, 1), freckles, np.clip(lips, 0, 1),
                recession)


def noise(rng, shape, sigma, anisotropy=(1.0, 1.0)):
    """Zero-mean, unit-variance smooth noise; ``anisotropy`` stretches it along (rows, cols).

    Broad patterns are drawn on a coarser grid and enlarged, which is much faster and
    looks the same.
    """
    sigmas = np.array([sigma * anisotropy[0], sigma * anisotropy[1]])
    step = max(1, int(sigmas.min() // 3))
    coarse = (-(-shape[0] // step), -(-shape[1] // step))
    field = gaussian_filter(rng.standard_normal(coarse), sigmas / step, mode="wrap")
    if step > 1:
        field = zoom(field, step, order=1, mode="grid-wrap", grid_mode=True)[: shape[0], : shape[1]]
    return field / (field.std() + 1e-12)


def mix(base, colour, amount):
    return base * (1.0 - amount[..., None]) + np.asarray(colour) * amount[..., None]


def skin_texel_positions(mesh: HeadMesh, vertices: np.ndarray, height: int, width: int):
    """3D point and grid coordinates under every texel of the skin region."""
    rows, cols = mesh.grid_rows, mesh.grid_columns
    grid = vertices[mesh.grid_index]  # (rows+1, cols, 3)
    grid = np.concatenate([grid, grid[:, :1]], axis=1)
    py = np.arange(height) + 0.5
    px = np.arange(width) + 0.5
    gi = np.clip(py / height * rows, 0.0, rows - 1e-9)  # the skin box spans all grid rows
    gj = np.clip(px / width * cols, 0.0, cols - 1e-9)
    i0, j0 = np.floor(gi).astype(int), np.floor(gj).astype(int)
    fi, fj = (gi - i0)[:, None, None], (gj - j0)[None, :, None]
    p = (grid[i0][:, j0] * (1 - fi) * (1 - fj) + grid[i0 + 1][:, j0] * fi * (1 - fj)
         + grid[i0][:, j0 + 1] * (1 - fi) * fj + grid[i0 + 1][:, j0 + 1] * fi * fj)
    return p, gi, gj


def around_head(field, mesh, vertices, gj):
    """Resample a texture-space pattern so its columns are evenly spaced around the head.

    Skin UV columns are denser on the face; patterns that must look the same size
    everywhere (hair strands) are drawn in azimuth and looked up per texel column.
    """
    ring = vertices[mesh.grid_index[mesh.grid_rows // 3]]
    azimuth = np.unwrap(np.arctan2(ring[:, 0], ring[:, 2]))
    azimuth = np.concatenate([azimuth, [azimuth[0] + 2.0 * np.pi]])
    along = np.interp(gj, np.arange(len(azimuth)), azimuth)
    columns = ((along - azimuth[0]) / (2.0 * np.pi) * field.shape[1]).astype(int) % field.shape[1]
    return field[:, columns]


def skin_folds(p):
    """Soft darkening along the folds a face has at rest: lid creases, nasolabial folds,
    faint forehead lines and the corners of the mouth."""
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    ax = np.abs(x)
    eye = np.stack([ax, y, z], -1) - EYE_CENTRE
    from_eye = np.linalg.norm(eye, axis=-1)
    lid_crease = np.exp(-(((from_eye - 0.0163) / 0.0012) ** 2)) * (eye[..., 1] > 0.003) * (eye[..., 2] > 0.0)
    under_eye = np.exp(-(((from_eye - 0.0175) / 0.003) ** 2)) * (eye[..., 1] < -0.004) * (eye[..., 2] > 0.0)
    # The nasolabial fold runs from beside the nose wing down to past the mouth corner.
    t = np.clip((-0.034 - y) / 0.036, 0.0, 1.0)
    fold_x = 0.022 + 0.011 * t
    nasolabial = np.exp(-(((ax - fold_x) / 0.0018) ** 2)) * (y < -0.032) * (y > -0.072) * (z > 0.06)
    forehead = sum(np.exp(-(((y - h - 0.004 * (x / 0.03) ** 2) / 0.0012) ** 2)) for h in (0.056, 0.066, 0.076))
    forehead = forehead * np.exp(-((x / 0.035) ** 4)) * (z > 0.05)
    return 0.16 * lid_crease + 0.07 * under_eye + 0.12 * nasolabial + 0.05 * forehead


def paint_skin(mesh, vertices, look, rng, height, width):
    p, gi, gj = skin_texel_positions(mesh, vertices, height, width)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    ax = np.abs(x)
    shape = (height, width)
    colour = np.broadcast_to(look.skin, shape + (3,)).copy()
    # Broad tone variation, then pores (fine, high contrast) and mottling.
    colour *= (1.0 + 0.05 * noise(rng, shape, 24.0))[..., None]
    colour *= (1.0 + 0.035 * noise(rng, shape, 5.0))[..., None]
    colour *= (1.0 + 0.05 * noise(rng, shape, 0.7))[..., None]
    pores = rng.random(shape) < 0.05
    colour[pores] *= 0.9
    # Rosy cheeks and nose (the ears, painted in their own boxes, are redder too).
    red = np.array([0.80, 0.38, 0.36])
    rosy = (np.exp(-(((ax - 0.045) / 0.018) ** 2) - ((y + 0.02) / 0.02) ** 2) * (z > 0.03) * 0.18
            + np.exp(-((x / 0.012) ** 2) - ((y + 0.025) / 0.012) ** 2) * (z > 0.09) * 0.15)
    colour = mix(colour, look.skin * red / red.max() * 1.05, np.clip(rosy, 0, 1))
    # Freckles on the nose and cheeks.
    dens = np.exp(-((y + 0.01) / 0.03) ** 2) * np.exp(-((ax - 0.02) / 0.04) ** 2) * (z > 0.04)
    spots = gaussian_filter((rng.random(shape) < 0.004 * look.freckles * dens).astype(float), 1.0) * 6.0
    colour = mix(colour, look.skin * np.array([0.62, 0.42, 0.30]) / 0.9, np.clip(spots, 0, 0.8))
    # Lips: two vermilion bands around the seam, narrowing to the corners.
    r = np.linalg.norm(p, axis=-1)
    theta = np.degrees(np.arctan2(np.hypot(x, z), y))
    below = np.radians(theta - MOUTH_ROW_ANGLE) * r
    width_lip = np.clip(1.0 - (x / 0.027) ** 2, 0.0, 1.0) ** 0.5
    cupid = 0.0012 * np.exp(-((ax - 0.006) / 0.004) ** 2) - 0.0009 * np.exp(-(x / 0.003) ** 2)
    upper = smoothstep(below, -(0.0085 + cupid) * width_lip - 0.0008, -(0.0085 + cupid) * width_lip + 0.0008)
    lower = 1.0 - smoothstep(below, 0.0105 * width_lip - 0.001, 0.0105 * width_lip + 0.001)
    lip = upper * lower * (width_lip > 0) * (z > 0.06)
    lip_colour = look.lips * (1.0 + 0.09 * noise(rng, shape, 1.0, (1.5, 0.3)))[..., None]  # fine vertical lines
    colour = colour * (1 - lip[..., None]) + lip_colour * lip[..., None]
    colour *= (1.0 - 0.35 * np.exp(-((below / 0.0009) ** 2)) * (width_lip > 0) * (z > 0.06))[..., None]
    # Nostrils.
    nostril = np.exp(-(((ax - 0.0068) / 0.004) ** 2) - ((y + 0.0405) / 0.003) ** 2 - ((z - 0.1035) / 0.006) ** 2)
    colour *= (1.0 - 0.6 * np.clip(1.5 * nostril, 0, 1) * smoothstep(-y, 0.038, 0.041))[..., None]
    # Eyebrows: an arch of short hair strokes above each eye.
    arch = 0.031 + 0.007 * np.clip(1.0 - ((ax - 0.03) / 0.026) ** 2, 0, 1)
    thickness = 0.0062 * np.clip(1.2 - (ax - 0.012) / 0.05, 0.3, 1.0)
    brow = (np.exp(-(((y - arch) / thickness) ** 4)) * smoothstep(ax, 0.008, 0.014)
            * (1.0 - smoothstep(ax, 0.05, 0.058)) * (z > 0.05))
    strokes = np.clip(1.6 * noise(rng, shape, 1.0, (0.5, 5.0)) - 0.2, 0, 1)
    brow_colour = look.hair * 0.75
    colour = mix(colour, brow_colour, np.clip(brow * (0.25 + 0.8 * strokes), 0, 1))
    colour *= (1.0 - skin_folds(p))[..., None]
    # Eyelash lines along the lid rims (rows just above / below the eye slit).
    for c0, c1 in mesh.eye_columns:
        across = ((gj > c0 + 0.3) & (gj < c1 - 0.3))[None, :]
        upper_lash = across & ((gi > mesh.eye_row - 0.9) & (gi <= mesh.eye_row + 0.02))[:, None]
        lower_lash = across & ((gi >= mesh.eye_row) & (gi < mesh.eye_row + 0.45))[:, None]
        colour[upper_lash] = colour[upper_lash] * 0.2 + 0.02
        colour[lower_lash] = colour[lower_lash] * 0.55
    # Scalp hair: strands run along the grid columns, from the crown downwards; near the
    # hairline the strands thin out one by one instead of stopping at a hard edge.
    strands = around_head(noise(rng, shape, 1.0, (14.0, 0.9)), mesh, vertices, gj)
    clumps = around_head(noise(rng, shape, 6.0, (4.0, 1.0)), mesh, vertices, gj)
    edge = hairline_height(p, look.recession) + 0.002 * noise(rng, shape, 4.0)
    coverage = (y - edge) / 0.008 + 0.5 * np.clip(strands, -2, 2)
    hair = smoothstep(coverage, -0.6, 0.6)
    ear_gap = np.exp(-np.sum(((np.stack([ax, y, z], -1) - EAR_CENTRE) / np.array([0.03, 0.045, 0.032])) ** 2, axis=-1))
    hair = hair * (1.0 - ear_gap)
    hair_colour = look.hair * (1.0 + 0.35 * np.clip(strands, -2, 2)[..., None] + 0.08 * clumps[..., None])
    colour = colour * (1 - hair[..., None]) + np.clip(hair_colour, 0, 1) * hair[..., None]
    return np.clip(colour, 0, 1)


def paint_eye(look, rng, size):
    """An eyeball box: azimuthal map of the sphere around its front (iris at the centre)."""
    c = (np.arange(size) + 0.5) / size - 0.5
    yy, xx = np.meshgrid(-c, c, indexing="ij")
    theta = np.pi * (np.hypot(xx, yy) / (0.5 * 0.96)) ** (1.0 / EYE_UV_POWER)
    angle = np.arctan2(yy, xx)
    sclera = np.array([0.93, 0.91, 0.88]) * (1 + 0.02 * noise(rng, (size, size), 3.0))[..., None]
    veins = np.clip(noise(rng, (size, size), 0.8, (1.0, 1.0)) - 2.2, 0, 1) * smoothstep(theta, 0.9, 1.6)
    colour = mix(sclera, [0.75, 0.3, 0.3], 0.6 * veins)
    radial = noise(rng, (1, 720), 1.5)[0]
    fibres = radial[((angle + np.pi) / (2 * np.pi) * 720).astype(int) % 720]
    iris_colour = look.iris * (1.0 + 0.28 * fibres[..., None]) * (0.75 + 0.5 * (theta / IRIS_ANGLE))[..., None]
    iris = 1.0 - smoothstep(theta, IRIS_ANGLE - 0.03, IRIS_ANGLE + 0.01)
    colour = mix(colour, np.clip(iris_colour, 0, 1), iris)
    limbus = np.exp(-(((theta - IRIS_ANGLE) / 0.04) ** 2))
    colour = mix(colour, [0.05, 0.04, 0.04], 0.6 * limbus)
    pupil = 1.0 - smoothstep(theta, 0.14, 0.17)
    colour = mix(colour, [0.01, 0.01, 0.012], pupil)
    return np.clip(colour, 0, 1)


def paint_mouth(mesh, look, rng, height, width):
    """Inner mouth box: lip lining, a row of teeth above and below, dark cavity, tongue."""
    n_rings = int(mesh.mouth_bag_ring.max())
    loop = len(mesh.upper_lip_rim) + len(mesh.lower_lip_rim) - 2
    v = 1.0 - (np.arange(height) + 0.5) / height
    u = (np.arange(width) + 0.5) / width
    ring = np.clip((0.98 - v) / 0.96 * n_rings, 0, n_rings)  # 0 at the lips, growing inwards
    l = np.clip((u - 0.02) / 0.96 * loop, 0, loop)
    R, L = np.meshgrid(ring, l, indexing="ij")
    lower = L > len(mesh.upper_lip_rim) - 1
    pink = np.array([0.75, 0.38, 0.38]) * look.lips / look.lips.max()
    colour = np.broadcast_to(pink, (height, width, 3)).copy()
    teeth_band = smoothstep(R, 1.3, 1.6) * (1.0 - smoothstep(R, 2.8, 3.1))
    gaps = 1.0 - 0.5 * np.exp(-((((L * 1.6) % 1.0) - 0.5) / 0.06) ** 2)
    teeth = np.array([0.92, 0.89, 0.80]) * gaps[..., None]
    colour = mix(colour, np.clip(teeth, 0, 1), teeth_band)
    cavity = smoothstep(R, 3.0, 3.6)
    tongue = np.array([0.62, 0.25, 0.27])
    dark = np.where(lower[..., None], tongue, np.array([0.22, 0.07, 0.08]))
    colour = colour * (1 - cavity[..., None]) + dark * cavity[..., None]
    colour *= (1.0 + 0.06 * noise(rng, (height, width), 1.0))[..., None]
    return np.clip(colour, 0, 1)


def paint_ear(look, rng, height, width):
    """An ear box: the front disc (with its bowl and rim shaded in) and the back disc."""
    colour = np.broadcast_to(look.skin * np.array([1.0, 0.86, 0.84]), (height, width, 3)).copy()
    radius = 0.46 * height
    yy, xx = np.meshgrid(np.arange(height) + 0.5, np.arange(width) + 0.5, indexing="ij")
    for centre_x, is_front in ((0.5 * height, True), (1.5 * height, False)):
        du, dv = (xx - centre_x) / radius, (height - yy - 0.5 * height) / radius
        rho = np.clip(np.hypot(du, dv), 0.0, 1.0)
        psi = np.arctan2(dv, du)
        if is_front:
            relief = ear_relief(rho, psi) - 0.0022 * np.sqrt(np.clip(1.0 - rho**2, 0.0, None))
            shade = np.clip(1.0 + 60.0 * relief, 0.6, 1.12)
        else:
            shade = 0.95 + 0.0 * rho
        disc = np.hypot(du, dv) <= 1.02
        colour[disc] *= shade[disc][:, None]
    colour *= (1.0 + 0.04 * noise(rng, (height, width), 2.0))[..., None]
    colour *= (1.0 + 0.04 * noise(rng, (height, width), 0.7))[..., None]
    return np.clip(colour, 0, 1)


def paint_texture(mesh: HeadMesh, vertices: np.ndarray, look: Look, rng: np.random.Generator,
                  size: int = TEXTURE_SIZE) -> np.ndarray:
    """The full (size, size, 3) uint8 texture atlas."""
    image = np.zeros((size, size, 3))
    skin_rows = int(round(size * (1.0 - SKIN_UV_BOTTOM)))
    image[:skin_rows] = paint_skin(mesh, vertices, look, rng, skin_rows, size)
    for u0, v0, box in EYE_UV_BOXES:
        s = int(round(box * size))
        top = size - int(round((v0 + box) * size))
        left = int(round(u0 * size))
        image[top:top + s, left:left + s] = paint_eye(look, rng, s)
    u0, v0, w, h = MOUTH_UV_BOX
    top, left = size - int(round((v0 + h) * size)), int(round(u0 * size))
    hh, ww = int(round(h * size)), int(round(w * size))
    image[top:top + hh, left:left + ww] = paint_mouth(mesh, look, rng, hh, ww)
    for u0, v0, w in EAR_UV_BOXES:
        hh, ww = int(round(0.5 * w * size)), int(round(w * size))
        top, left = size - int(round(v0 * size)) - hh, int(round(u0 * size))
        image[top:top + hh, left:left + ww] = paint_ear(look, rng, hh, ww)
    u0, v0, w, h = LID_LINING_UV_BOX
    top, left = size - int(round((v0 + h) * size)), int(round(u0 * size))
    lining = look.skin * np.array([0.78, 0.64, 0.62])
    image[top:top + int(round(h * size)), left:left + int(round(w * size))] = lining
    return (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
