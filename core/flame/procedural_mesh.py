"""Topology and rest geometry of the procedural head.

The skin is a latitude–longitude grid: each grid vertex is a ray (from the head's
centre for the cranium and face, sliding down the neck axis below the chin) that
is intersected with the implicit head of ``procedural_sdf``. Rows and columns are
denser on the face. The eye and mouth openings are slits along one grid
row, cut by doubling the row's vertices and pulling the two copies apart, so lid
and lip rims are clean grid lines. An inner mouth bag closes the mouth, a short
lining runs from each eye opening into the eyeball, and the eyeballs are separate
UV spheres (the ears come from ``procedural_ear``). UVs follow the grid, so texture work can be
done per grid cell.
"""

from __future__ import annotations

import copy
import dataclasses
import functools

import numpy as np

from .procedural_ear import build_ear
from .procedural_sdf import EYE_CENTRE, EYE_RADIUS, hair_volume, march_rays

N_HALF_COLUMNS = 38  # columns from the front midline to the back midline
HEAD_ROWS = 58  # rows from the crown to the last ray from the centre
NECK_ROWS = 8  # rows sliding down the neck
NECK_BOTTOM = -0.20

EYE_ROW_ANGLE = 78.0  # polar angle (degrees) of the eye slit
MOUTH_ROW_ANGLE = 123.0  # polar angle of the lip seam
EYE_CORNERS_DEG = (14.0, 33.0)  # azimuths of the inner and outer eye corners (+x eye)
MOUTH_CORNER_DEG = 16.0

SKIN_UV_BOTTOM = 0.25  # the skin fills v in [0.25, 1]; eyes, mouth, lid lining and ears share the strip below
EYE_UV_BOXES = ((0.0, 0.0, 0.25), (0.25, 0.0, 0.25))  # (u0, v0, size): +x eye, −x eye
MOUTH_UV_BOX = (0.5, 0.0, 0.25, 0.2)  # (u0, v0, width, height)
LID_LINING_UV_BOX = (0.5, 0.2, 0.25, 0.05)  # the lining inside both eye openings
EAR_UV_BOXES = ((0.75, 0.125, 0.25), (0.75, 0.0, 0.25))  # (u0, v0, width); height is width / 2

EYEBALL_RINGS = np.array([0.1, 0.2, 0.3, 0.4, 0.47, 0.53, 0.62, 0.8, 1.05, 1.4, 1.85, 2.35, 2.8])
EYEBALL_SEGMENTS = 20
IRIS_ANGLE = 0.52  # angular radius of the iris on the eyeball
EYE_UV_POWER = 0.6


@dataclasses.dataclass
class HeadMesh:
    """Rest geometry plus the bookkeeping later stages need (regions, rims, grid)."""

    vertices: np.ndarray  # (V,3)
    faces: np.ndarray  # (F,3)
    vt: np.ndarray
    ft: np.ndarray
    part: np.ndarray  # (V,) 0 skin, 1 mouth bag, 2 eyeball +x, 3 eyeball −x, 4 lid lining, 5 ear +x, 6 ear −x
    grid_rows: int  # skin rows below the pole
    grid_columns: int
    grid_index: np.ndarray  # (rows+1, columns) vertex id of each skin grid vertex (upper copy on slits)
    upper_lid_rims: list  # per eye: vertex ids of the upper rim (inner → outer corner, corners included)
    lower_lid_rims: list
    upper_lip_rim: np.ndarray  # vertex ids, corner to corner
    lower_lip_rim: np.ndarray
    mouth_bag_ring: np.ndarray  # (V,) ring number inside the mouth, 0 elsewhere
    mouth_bag_lower: np.ndarray  # (V,) 1 for the lower half of the bag (moves with the jaw)
    eye_row: int
    mouth_row: int
    skin_row: np.ndarray  # (V,) grid row of skin vertices (0 = crown), −1 elsewhere
    skin_col: np.ndarray  # (V,) grid column, −1 elsewhere
    is_lower_copy: np.ndarray  # (V,) the lower copy of a slit row vertex
    eye_columns: tuple  # ((c0, c1) of the +x eye, (c0, c1) of the −x eye)
    mouth_columns: tuple


def _density_samples(count: int, lo: float, hi: float, density) -> np.ndarray:
    """count+1 samples from lo to hi spaced inversely to ``density``."""
    x = np.linspace(lo, hi, 4001)
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (density(x[1:]) + density(x[:-1])) * np.diff(x))])
    return np.interp(np.linspace(0.0, cdf[-1], count + 1), cdf, x)


def _bump(x, centre, half_width):
    return np.clip(1.0 - ((x - centre) / half_width) ** 2, 0.0, None) ** 2


def _snap(samples: np.ndarray, targets: list[float]) -> tuple[np.ndarray, list[int]]:
    """Move the samples nearest to each target onto it with a monotone piecewise-linear remap."""
    picks = [int(np.argmin(np.abs(samples - t))) for t in targets]
    knots_from = np.concatenate([[samples[0]], samples[picks], [samples[-1]]])
    knots_to = np.concatenate([[samples[0]], targets, [samples[-1]]])
    order = np.argsort(knots_from)
    return np.interp(samples, knots_from[order], knots_to[order]), picks


def column_azimuths() -> tuple[np.ndarray, dict]:
    """Azimuths (radians, 0 = front, +π/2 = +x) of all columns, symmetric about the midline."""
    def density(phi):
        deg = np.degrees(phi)
        return 0.4 + 2.0 * _bump(deg, 0.0, 75.0) ** 0.5 + 1.0 * _bump(deg, 0.0, 18.0) + 0.3 * _bump(deg, 92.0, 26.0)

    half = np.degrees(_density_samples(N_HALF_COLUMNS, 0.0, np.pi, density))
    half, picks = _snap(half, [EYE_CORNERS_DEG[0], EYE_CORNERS_DEG[1]])
    mouth = int(np.argmin(np.abs(half - MOUTH_CORNER_DEG)))
    if mouth in picks:
        mouth += 1
    # Columns run from the back (−π) over the −x side, the front and +x back to the back.
    phis = np.radians(np.concatenate([-half[::-1], half[1:-1]]))
    centre = N_HALF_COLUMNS
    columns = {
        "front": centre,
        "eye_plus": (centre + picks[0], centre + picks[1]),
        "eye_minus": (centre - picks[1], centre - picks[0]),
        "mouth": (centre - mouth, centre + mouth),
    }
    return phis, columns


def row_parameters() -> tuple[np.ndarray, int, int]:
    """Row parameters: s in [0,1] along the head rays (θ = s·θ_end), then 1+t for the neck rows."""
    def density(s):
        deg = 150.0 * s
        return 0.7 + 2.6 * _bump(deg, 105.0, 60.0) ** 0.5

    s = _density_samples(HEAD_ROWS, 0.0, 1.0, density)
    s, (eye_row, mouth_row) = _snap(s, [EYE_ROW_ANGLE / 150.0, MOUTH_ROW_ANGLE / 150.0])
    t = np.linspace(0.0, 1.0, NECK_ROWS + 1)[1:]
    return np.concatenate([s, 1.0 + t]), eye_row, mouth_row


def head_ray_end(phi):
    """Polar angle (degrees) where the rays from the centre stop: lower in front (under the chin)."""
    return 135.0 + 15.0 * np.tanh(2.2 * np.cos(phi)) / np.tanh(2.2)


def skin_rays(row_param: np.ndarray, theta_offset: np.ndarray, phi: np.ndarray):
    """Ray origins and directions for skin vertices given row parameter and azimuth."""
    end = head_ray_end(phi)
    neck = row_param > 1.0
    t = np.clip(row_param - 1.0, 0.0, 1.0)
    theta = np.where(neck, end + (90.0 - end) * t**2, row_param * end) + theta_offset
    th = np.radians(theta)
    directions = np.stack([np.sin(th) * np.sin(phi), np.cos(th), np.sin(th) * np.cos(phi)], axis=-1)
    origins = np.zeros_like(directions)
    origins[:, 1] = np.where(neck, NECK_BOTTOM * t, 0.0)
    return origins, directions, theta


def _slit_profile(tau, peak, power=0.8):
    """Opening of a slit along its length: 0 at both corners, 1 at ``peak``."""
    tau = np.clip(tau, 0.0, 1.0)
    exponent = np.log(0.5) / np.log(peak)
    return np.sin(np.pi * tau**exponent) ** power


def lip_offset(theta_deg, phi, radius):
    """Radial relief of the lips around the seam row: two rolls with a groove between them."""
    v = np.radians(theta_deg - MOUTH_ROW_ANGLE) * radius  # metres below the seam
    x = radius * np.sin(np.radians(theta_deg)) * np.sin(phi)
    width = np.clip(1.0 - (x / 0.027) ** 2, 0.0, None) ** 0.6 * (np.cos(phi) > 0.5)
    upper = 0.0055 * _bump(v, -0.0042, 0.0060)
    lower = 0.0058 * _bump(v, 0.0052, 0.0070)
    groove = 0.0022 * np.exp(-((v / 0.0016) ** 2))
    philtrum = 0.0008 * np.exp(-((x / 0.004) ** 2)) * _bump(v, -0.012, 0.006)
    return width * (upper + lower - groove) - philtrum * (np.abs(x) < 0.01)


def _lid_warp(theta, row_angle, opening, above, reach=9.0):
    """Shift polar angles near a slit so the rim copies separate by ``opening`` degrees."""
    distance = (row_angle - theta) if above else (theta - row_angle)
    x = np.clip(distance / reach, 0.0, 1.0)
    falloff = np.where(distance >= 0, (1.0 - x) ** 2, 0.0)
    return (-1.0 if above else 1.0) * opening * falloff


def _even_near_crown(phis, col_of, row_param):
    """Column azimuths per vertex: face-dense columns spread out evenly towards the crown.

    All columns meet at the crown; keeping them evenly spaced there avoids needle-thin
    triangles where the dense face columns would otherwise converge.
    """
    even = -np.pi + 2.0 * np.pi * np.arange(len(phis)) / len(phis)
    even = even - even[np.argmin(np.abs(phis))]  # the front midline stays a column
    blend = 1.0 - np.clip((row_param * 150.0 - 12.0) / 30.0, 0.0, 1.0)
    blend = blend * blend * (3.0 - 2.0 * blend)
    return phis[col_of] * (1.0 - blend) + even[col_of] * blend


def _relax_jaw_angle(vertices, faces, iterations=2, rate=0.5):
    """Smooth the skin below and behind the jaw angle.

    The rays there graze the skin between jaw and neck, so neighbouring rays land a
    little unevenly; a few local averaging steps remove the resulting sawtooth.
    """
    x, y, z = vertices.T
    region = (np.clip((np.abs(x) - 0.03) / 0.015, 0.0, 1.0) * np.clip((-0.02 - y) / 0.015, 0.0, 1.0)
              * np.clip((-0.15 - y) / -0.02, 0.0, 1.0) * np.clip((0.06 - z) / 0.02, 0.0, 1.0))
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    edges = np.concatenate([edges, edges[:, ::-1]])
    count = np.bincount(edges[:, 0], minlength=len(vertices))
    out = vertices.copy()
    step = (rate * region)[:, None]
    for _ in range(iterations):
        mean = np.zeros_like(out)
        np.add.at(mean, edges[:, 0], out[edges[:, 1]])
        mean /= np.maximum(count, 1)[:, None]
        out += step * (mean - out)
    return out


def build_skin(phis, columns, rows, eye_row, mouth_row):
    """Skin vertices (with slit copies), faces and UVs."""
    n_cols = len(phis)
    n_rows = len(rows) - 1
    # Grid vertex parameters, row 0 is the crown pole.
    row_of = np.concatenate([[0], np.repeat(np.arange(1, n_rows + 1), n_cols)])
    col_of = np.concatenate([[0], np.tile(np.arange(n_cols), n_rows)])
    grid_index = np.zeros((n_rows + 1, n_cols), dtype=np.int64)
    grid_index[1:] = 1 + np.arange(n_rows * n_cols).reshape(n_rows, n_cols)

    # Lower copies on the slit rows (corners are shared).
    slits = []
    for key, row, upper_open, lower_open, peaks in (
        ("eye_plus", eye_row, 4.6, 3.2, (0.42, 0.58)),
        ("eye_minus", eye_row, 4.6, 3.2, (0.58, 0.42)),
        ("mouth", mouth_row, 0.18, 0.18, (0.5, 0.5)),
    ):
        c0, c1 = columns[key]
        slits.append((key, row, c0, c1, upper_open, lower_open, peaks))
    lower_copy = {}
    extra_rows, extra_cols = [], []
    next_id = 1 + n_rows * n_cols
    for key, row, c0, c1, *_ in slits:
        for j in range(c0 + 1, c1):
            lower_copy[(row, j)] = next_id
            extra_rows.append(row)
            extra_cols.append(j)
            next_id += 1
    row_of = np.concatenate([row_of, extra_rows])
    col_of = np.concatenate([col_of, extra_cols])
    is_lower_copy = np.zeros(len(row_of), dtype=bool)
    is_lower_copy[1 + n_rows * n_cols:] = True

    param = rows[row_of]
    phi = _even_near_crown(phis, col_of, rows[row_of])
    _, _, base_theta = skin_rays(param, np.zeros(len(param)), phi)
    offset = np.zeros(len(param))
    for key, row, c0, c1, upper_open, lower_open, peaks in slits:
        in_cols = (col_of > c0) & (col_of < c1)
        tau = (phi - phis[c0]) / (phis[c1] - phis[c0])
        row_theta = rows[row] * head_ray_end(phi)
        up = upper_open * _slit_profile(tau, peaks[0])
        down = lower_open * _slit_profile(tau, peaks[1])
        on_row = row_of == row
        above = in_cols & ((row_of < row) | (on_row & ~is_lower_copy))
        below = in_cols & ((row_of > row) | (on_row & is_lower_copy))
        offset += np.where(above, _lid_warp(base_theta, row_theta, up, True), 0.0)
        offset += np.where(below, _lid_warp(base_theta, row_theta, down, False), 0.0)
    offset[0] = 0.0

    origins, directions, theta = skin_rays(param, offset, phi)
    origins[0], directions[0] = 0.0, np.array([0.0, 1.0, 0.0])
    distance = march_rays(origins, directions)
    face_rays = param <= 1.0
    distance = distance + np.where(face_rays, lip_offset(theta, phi, distance), 0.0)
    distance = distance + hair_volume(origins + distance[:, None] * directions)
    vertices = origins + distance[:, None] * directions

    faces, face_uv = [], []
    uv_cols = n_cols + 1

    def uv_id(i, j):
        return i * uv_cols + j

    def top_id(i, j):
        return lower_copy.get((i, j % n_cols), grid_index[i, j % n_cols])

    for j in range(n_cols):
        # Crown fan: its own pole UV per column.
        faces.append((0, grid_index[1, j], grid_index[1, (j + 1) % n_cols]))
        face_uv.append((uv_id(0, j), uv_id(1, j), uv_id(1, j + 1)))
    for i in range(1, n_rows):
        for j in range(n_cols):
            a, b = top_id(i, j), top_id(i, j + 1)
            c, d = grid_index[i + 1, (j + 1) % n_cols], grid_index[i + 1, j]
            faces += [(a, d, c), (a, c, b)]
            ua, ub, uc, ud = uv_id(i, j), uv_id(i, j + 1), uv_id(i + 1, j + 1), uv_id(i + 1, j)
            face_uv += [(ua, ud, uc), (ua, uc, ub)]
    vertices = _relax_jaw_angle(vertices, np.array(faces))
    uu, vv = np.meshgrid(np.arange(uv_cols) / n_cols, np.arange(n_rows + 1) / n_rows)
    uu[0] = np.minimum((np.arange(uv_cols) + 0.5) / n_cols, 1.0)
    vt = np.stack([uu.ravel(), 1.0 - (1.0 - SKIN_UV_BOTTOM) * vv.ravel()], axis=-1)

    rims = {}
    for key, row, c0, c1, *_ in slits:
        cols = np.arange(c0, c1 + 1)
        upper = grid_index[row, cols]
        lower = np.array([grid_index[row, c0]] + [lower_copy[(row, j)] for j in cols[1:-1]] + [grid_index[row, c1]])
        rims[key] = (upper, lower)
    skin_row = np.where(np.arange(len(row_of)) == 0, 0, row_of)
    return vertices, np.array(faces), vt, np.array(face_uv), grid_index, rims, (skin_row, col_of, is_lower_copy)


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


def build_mesh() -> HeadMesh:
    """The base head mesh (a fresh copy; the geometry is built once per process)."""
    return copy.deepcopy(_build_mesh_once())


@functools.lru_cache(maxsize=1)
def _build_mesh_once() -> HeadMesh:
    """Assemble skin, mouth bag and eyeballs into one mesh with UVs."""
    phis, columns = column_azimuths()
    rows, eye_row, mouth_row = row_parameters()
    skin_v, skin_f, skin_vt, skin_ft, grid_index, rims, grid_info = build_skin(phis, columns, rows, eye_row, mouth_row)
    upper_lip, lower_lip = rims["mouth"]
    bag_v, bag_f, bag_ring, bag_lower, bag_vt, bag_ft, loop = build_mouth_bag(skin_v, upper_lip, lower_lip)

    vertices = [skin_v, bag_v]
    faces = [skin_f, bag_f]
    vts = [skin_vt, bag_vt]
    # The rim ring of the bag is made of skin vertices; bag faces use the bag's own UVs.
    fts = [skin_ft, bag_ft + len(skin_vt)]
    part = [np.zeros(len(skin_v), np.int64), np.ones(len(bag_v), np.int64)]
    n_v = len(skin_v) + len(bag_v)
    n_vt = len(skin_vt) + len(bag_vt)
    for k, (key, sign) in enumerate((("eye_plus", 1.0), ("eye_minus", -1.0))):
        centre = EYE_CENTRE * np.array([sign, 1.0, 1.0])
        u0, v0, w, h = LID_LINING_UV_BOX
        box = (u0 + 0.5 * w * k, v0, 0.5 * w, h)
        lv, lf, lvt, lft = build_lid_lining(skin_v, rims[key][0], rims[key][1], centre, n_v, box)
        vertices.append(lv)
        faces.append(lf)
        vts.append(lvt)
        fts.append(lft + n_vt)
        part.append(np.full(len(lv), 4, np.int64))
        n_v += len(lv)
        n_vt += len(lvt)
    for k, sign in enumerate((1.0, -1.0)):
        centre = EYE_CENTRE * np.array([sign, 1.0, 1.0])
        ev, ef, evt, eft = build_eyeball(centre, EYE_UV_BOXES[k])
        vertices.append(ev)
        faces.append(ef + n_v)
        vts.append(evt)
        fts.append(eft + n_vt)
        part.append(np.full(len(ev), 2 + k, np.int64))
        n_v += len(ev)
        n_vt += len(evt)

    for k, sign in enumerate((1.0, -1.0)):
        av, af, avt, aft = build_ear(sign, n_v, n_vt, EAR_UV_BOXES[k])
        vertices.append(av)
        faces.append(af)
        vts.append(avt)
        fts.append(aft)
        part.append(np.full(len(av), 5 + k, np.int64))
        n_v += len(av)
        n_vt += len(avt)

    skin_row, skin_col, lower_copy = grid_info
    n_all = n_v
    row = np.full(n_all, -1, np.int64)
    col = np.full(n_all, -1, np.int64)
    row[:len(skin_v)], col[:len(skin_v)] = skin_row, skin_col
    copy_flag = np.zeros(n_all, bool)
    copy_flag[:len(skin_v)] = lower_copy
    ring = np.zeros(n_all, np.int64)
    ring[len(skin_v):len(skin_v) + len(bag_v)] = bag_ring
    lower = np.zeros(n_all)
    lower[len(skin_v):len(skin_v) + len(bag_v)] = bag_lower
    lower[lower_lip] = 1.0
    lower[upper_lip[0]] = lower[upper_lip[-1]] = 0.5
    return HeadMesh(
        vertices=np.concatenate(vertices),
        faces=np.concatenate(faces).astype(np.int64),
        vt=np.concatenate(vts),
        ft=np.concatenate(fts).astype(np.int64),
        part=np.concatenate(part),
        grid_rows=len(rows) - 1,
        grid_columns=len(phis),
        grid_index=grid_index,
        upper_lid_rims=[rims["eye_plus"][0], rims["eye_minus"][0]],
        lower_lid_rims=[rims["eye_plus"][1], rims["eye_minus"][1]],
        upper_lip_rim=upper_lip,
        lower_lip_rim=lower_lip,
        mouth_bag_ring=ring,
        mouth_bag_lower=lower,
        eye_row=eye_row,
        mouth_row=mouth_row,
        skin_row=row,
        skin_col=col,
        is_lower_copy=copy_flag,
        eye_columns=(columns["eye_plus"], columns["eye_minus"]),
        mouth_columns=columns["mouth"],
    )
