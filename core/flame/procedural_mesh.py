"""Topology and rest geometry of the procedural head.

The skin is a latitude–longitude grid: each grid vertex is a ray (from the head's
centre for the cranium and face, sliding down the neck axis below the chin) that
is intersected with the implicit head of ``procedural_sdf``. Rows and columns are
denser on the face. The eye and mouth openings are slits along one grid
row, cut by doubling the row's vertices and pulling the two copies apart, so lid
and lip rims are clean grid lines (``procedural_skin``). An inner mouth bag closes the mouth, a
short lining runs from each eye opening into the eyeball, and the eyeballs are separate UV
spheres (``procedural_inner``; the ears come from ``procedural_ear``). UVs follow the grid, so
texture work can be done per grid cell; each part's place in the texture is ``procedural_uv``'s.
"""

from __future__ import annotations

import copy
import dataclasses
import functools

import numpy as np

from .procedural_ear import build_ear
from .procedural_inner import build_eyeball, build_lid_lining, build_mouth_bag
from .procedural_sdf import EYE_CENTRE
from .procedural_skin import build_skin, column_azimuths, row_parameters
from .procedural_uv import EAR_UV_BOXES, EYE_UV_BOXES, LID_LINING_UV_BOX


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
