"""FLAME's teeth extension: the 120 vertices and 168 triangles VHAP and GaussianAvatars add.

Both tools build FLAME with ``add_teeth=True``: two rows of teeth (upper and lower), each a
thin box of 15 columns, placed behind the lips. The tracking they write then has 5143
vertices (``static_offset (1, 5143, 3)``) and their avatars bind Gaussians to 10144 faces.
This module builds the same extension on a FLAME-topology model (5023 vertices), in the
same vertex and face order, so offsets and face ids mean the same thing in both worlds:

- the 15 columns follow FLAME's outer lip rings (vertex ids below, a fact of FLAME's
  topology): each column sits at the midpoint of an upper and a lower lip vertex, all at the
  rings' mean height, moved back by 1.5 lip gaps;
- rows, in vertex order: upper root, lower root, upper edge, lower edge, then the back
  copies (one lip gap further back) of upper root, upper edge, lower root, lower edge;
  edges sit 0.1 gap above/below the middle, roots 2 gaps beyond the edges, and the lower
  row is pushed back by a further 0.4 gap;
- skinning: upper teeth follow the neck joint, lower teeth the jaw; no pose correctives,
  no expression components, identity components averaged from the two lip rings;
- faces: three quad strips per row (front, back, biting edge), 28 triangles each, whose
  diagonals mirror at the middle column.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..errors import ModelFileError

FLAME_VERTEX_COUNT = 5023
TEETH_VERTEX_COUNT = 120
COLUMNS = 15
# FLAME's outer lip rings, right to left (15 vertices each), where the teeth columns sit.
LIP_RING_UPPER = (1713, 1715, 1716, 1735, 1696, 1694, 1657, 3543, 2774, 2811, 2813, 2850, 2833, 2832, 2830)
LIP_RING_LOWER = (1576, 1577, 1773, 1774, 1795, 1802, 1865, 3503, 2948, 2905, 2898, 2881, 2880, 2713, 2712)
NECK_JOINT, JAW_JOINT = 1, 2

# Rows in vertex order: (name, upper?, height from the middle in lip gaps, depth in lip gaps).
_ROWS = (
    ("upper_root", True, 2.1, 0.0),
    ("lower_root", False, -2.1, -0.4),
    ("upper_edge", True, 0.1, 0.0),
    ("lower_edge", False, -0.1, -0.4),
    ("upper_root_back", True, 2.1, -1.0),
    ("upper_edge_back", True, 0.1, -1.0),
    ("lower_root_back", False, -2.1, -1.4),
    ("lower_edge_back", False, -0.1, -1.4),
)
_ROW = {name: i for i, (name, *_rest) in enumerate(_ROWS)}
# Strips: (row a, row b, diagonal of the right half, swap winding). See _strip.
_STRIPS = (
    ("upper_root", "upper_edge", 1, False),  # upper front
    ("upper_root_back", "upper_edge_back", 1, True),  # upper back
    ("upper_edge_back", "upper_edge", 2, True),  # upper biting edge
    ("lower_edge", "lower_root", 2, False),  # lower front
    ("lower_root_back", "lower_edge_back", 1, False),  # lower back
    ("lower_edge_back", "lower_edge", 2, False),  # lower biting edge
)


def _row_ids(name: str) -> np.ndarray:
    return np.arange(COLUMNS) + COLUMNS * _ROW[name]


def _strip(a: np.ndarray, b: np.ndarray, right_diagonal: int, swap: bool) -> list[list[int]]:
    """Two triangles per quad between rows ``a`` and ``b``; the diagonal flips at the middle."""
    faces = []
    for i in range(COLUMNS - 1):
        diagonal = right_diagonal if i < COLUMNS // 2 else 3 - right_diagonal
        if diagonal == 1:  # a[i]–b[i+1]
            pair = [[a[i], b[i + 1], b[i]], [a[i], a[i + 1], b[i + 1]]]
        else:  # a[i+1]–b[i]
            pair = [[a[i], a[i + 1], b[i]], [a[i + 1], b[i + 1], b[i]]]
        faces += [[t[0], t[2], t[1]] if swap else t for t in pair]
    return faces


def teeth_faces() -> np.ndarray:
    """The 168 teeth triangles in local vertex ids 0..119 (upper strips, then lower)."""
    faces = [f for a, b, diagonal, swap in _STRIPS for f in _strip(_row_ids(a), _row_ids(b), diagonal, swap)]
    return np.asarray(faces, dtype=np.int64)


def teeth_vertices(v_template: np.ndarray) -> np.ndarray:
    """The 120 teeth vertices ``(120, 3)`` placed behind the lips of a FLAME-topology template."""
    upper = v_template[list(LIP_RING_UPPER)]
    lower = v_template[list(LIP_RING_LOWER)]
    gap = float(np.linalg.norm(upper - lower, axis=1).mean())
    middle = 0.5 * (upper + lower)
    middle[:, 1] = middle[:, 1].mean()
    middle[:, 2] -= 1.5 * gap
    rows = [middle + gap * np.array([0.0, height, depth]) for _, _, height, depth in _ROWS]
    return np.concatenate(rows, axis=0)


def is_upper_tooth() -> np.ndarray:
    """``(120,)`` bool: which teeth vertices belong to the upper row."""
    return np.repeat([upper for _, upper, _, _ in _ROWS], COLUMNS)


def add_teeth(arrays):
    """A copy of a FLAME-topology :class:`~.model_file.ModelArrays` with the teeth appended."""
    n = arrays.v_template.shape[0]
    if n != FLAME_VERTEX_COUNT:
        raise ModelFileError(None, "v_template", f"teeth attach to FLAME's {FLAME_VERTEX_COUNT} vertices, found {n}")
    upper = is_upper_tooth()
    lips = list(LIP_RING_UPPER), list(LIP_RING_LOWER)
    shape_rows = 0.5 * (arrays.shapedirs[lips[0]] + arrays.shapedirs[lips[1]])  # (15,3,S)
    weights = np.zeros((TEETH_VERTEX_COUNT, arrays.weights.shape[1]))
    weights[upper, NECK_JOINT] = 1.0
    weights[~upper, JAW_JOINT] = 1.0
    extra = dict(
        v_template=np.concatenate([arrays.v_template, teeth_vertices(arrays.v_template)]),
        faces=np.concatenate([arrays.faces, teeth_faces() + n]),
        shapedirs=np.concatenate([arrays.shapedirs, np.tile(shape_rows, (len(_ROWS), 1, 1))]),
        exprdirs=np.concatenate([arrays.exprdirs, np.zeros((TEETH_VERTEX_COUNT, 3, arrays.n_expr))]),
        posedirs=np.concatenate([arrays.posedirs, np.zeros((TEETH_VERTEX_COUNT, 3, arrays.posedirs.shape[2]))]),
        J_regressor=np.concatenate([arrays.J_regressor, np.zeros((arrays.J_regressor.shape[0], TEETH_VERTEX_COUNT))],
                                   axis=1),
        weights=np.concatenate([arrays.weights, weights]),
    )
    if arrays.vt is not None and arrays.ft is not None:
        extra["vt"], extra["ft"] = _teeth_uvs(arrays.vt, arrays.ft)
    return dataclasses.replace(arrays, **extra)


def _teeth_uvs(vt: np.ndarray, ft: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """UVs for the teeth: a 15 x 8 grid in a thin band at the bottom of the texture."""
    u, v = np.meshgrid(np.linspace(0.62, 0.38, COLUMNS), np.linspace(0.005, 0.04, len(_ROWS)))
    uv = np.stack([u.ravel(), v.ravel()], axis=1)
    return np.concatenate([vt, uv]), np.concatenate([ft, teeth_faces() + len(vt)])


def match_tracking(arrays, n_vertices: int | None, source=None, field: str = "static_offset"):
    """The model whose vertices a tracking's offsets (``n_vertices`` rows) describe.

    Equal counts: the model as it is. FLAME's 5023 against 5143: the model with teeth (the
    tracking was made by VHAP with ``add_teeth=True``). Anything else is refused.
    """
    n = arrays.v_template.shape[0]
    if n_vertices is None or n_vertices == n:
        return arrays
    if n == FLAME_VERTEX_COUNT and n_vertices == n + TEETH_VERTEX_COUNT:
        return add_teeth(arrays)
    raise ModelFileError(
        source, field,
        f"the tracking has {n_vertices} vertices and the head model {n}; only FLAME's {FLAME_VERTEX_COUNT} "
        f"(plus {TEETH_VERTEX_COUNT} teeth: {FLAME_VERTEX_COUNT + TEETH_VERTEX_COUNT}) can be matched",
    )
