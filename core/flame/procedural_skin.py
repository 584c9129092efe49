"""The skin of the procedural head: a latitude–longitude grid of rays shaped by the implicit head.

Each grid vertex is a ray (from the head's centre for the cranium and face, sliding down the
neck axis below the chin) intersected with the implicit head of ``procedural_sdf``. Rows and
columns are denser on the face. The eye and mouth openings are slits along one grid row, cut by
doubling the row's vertices and pulling the two copies apart, so lid and lip rims are clean grid
lines. UVs follow the grid.
"""

from __future__ import annotations

import numpy as np

from .procedural_sdf import hair_volume, march_rays
from .procedural_uv import SKIN_UV_BOTTOM

N_HALF_COLUMNS = 38  # columns from the front midline to the back midline
HEAD_ROWS = 58  # rows from the crown to the last ray from the centre
NECK_ROWS = 8  # rows sliding down the neck
NECK_BOTTOM = -0.20

EYE_ROW_ANGLE = 78.0  # polar angle (degrees) of the eye slit
MOUTH_ROW_ANGLE = 123.0  # polar angle of the lip seam
EYE_CORNERS_DEG = (14.0, 33.0)  # azimuths of the inner and outer eye corners (+x eye)
MOUTH_CORNER_DEG = 16.0


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
