"""Facial landmarks on the head model: 68 points in the iBUG-300W order that face-landmark
detectors (and VHAP's tracker) use, each fixed to a triangle of the mesh by barycentric weights.

A landmark *embedding* is ``(faces (L,), barycentric (L,3), ibug (L,))``: which triangle holds each
landmark, where in it, and which of the 68 iBUG points it is. Three sources:

- the procedural head: built here from its rims and grid (every capture of this project);
- VHAP's ``landmark_embedding_with_eyes.npy`` (the ``full_lmk_*`` pair: 68 points, then two eyes);
- FLAME's ``flame_static_embedding.pkl`` (``lmk_face_idx``, ``lmk_b_coords``: iBUG points 17–67),
  or an ``.npz`` with the keys of either.

The jaw contour (iBUG 0–16) of a detector follows the face's silhouette, which is no fixed point of
the mesh, so solvers use the 51 points from 17 on by default (as FLAME's static embedding does).
"""

from __future__ import annotations

import dataclasses
import functools
import os
import pathlib

import numpy as np

from ..errors import InputError, UnsafePickleError
from ..io.npz import load_npz
from ..io.restricted_pickle import NUMPY_ARRAY_GLOBALS, restricted_load
from .safe_pickle import latin1_encode

IBUG_COUNT = 68
STATIC_IBUG = np.arange(17, IBUG_COUNT)  # the points that are fixed on the face (not the jaw contour)
EMBEDDING_FILES = ("landmark_embedding_with_eyes.npy", "flame_static_embedding.pkl")  # looked for beside a model


@dataclasses.dataclass(frozen=True)
class LandmarkEmbedding:
    faces: np.ndarray  # (L,) triangle index
    barycentric: np.ndarray  # (L,3) weights of the triangle's corners
    ibug: np.ndarray  # (L,) iBUG-68 index of each landmark

    def positions(self, vertices, faces):
        """Landmarks of posed ``vertices`` (…,V,3) of a mesh with triangles ``faces`` (F,3) → (…,L,3);
        numpy or torch, whichever ``vertices`` is."""
        corners = vertices[..., faces[self.faces], :]  # (…,L,3,3)
        weights = self.barycentric if isinstance(vertices, np.ndarray) else _as_torch(self.barycentric, vertices)
        return (corners * weights[..., None]).sum(-2)

    def subset(self, ibug: np.ndarray) -> "LandmarkEmbedding":
        keep = np.isin(self.ibug, ibug)
        return LandmarkEmbedding(self.faces[keep], self.barycentric[keep], self.ibug[keep])

    def check(self, n_faces: int, source) -> "LandmarkEmbedding":
        if len(self.faces) == 0:
            raise InputError(source, "landmarks", "no landmarks")
        if self.faces.min() < 0 or self.faces.max() >= n_faces:
            raise InputError(source, "faces", f"triangle indices must lie in [0, {n_faces}) (another mesh's embedding?)")
        if not np.all(np.isfinite(self.barycentric)) or np.abs(self.barycentric.sum(1) - 1).max() > 1e-3:
            raise InputError(source, "barycentric", "weights must be finite and sum to 1 per landmark")
        return self


def _as_torch(array: np.ndarray, like):
    import torch

    return torch.as_tensor(array, dtype=like.dtype, device=like.device)


# -- the procedural head ------------------------------------------------------------------------

@functools.lru_cache(maxsize=1)
def procedural_embedding() -> LandmarkEmbedding:
    """The 68 iBUG points on the procedural head (its subjects share one topology): eyes and lips on
    their rims, brows, nose and jaw at the skin vertices nearest their directions from the head's
    centre. Subject's right is −x, so iBUG 0 (the left of a frontal image) lies at −x."""
    from .procedural_mesh import build_mesh

    mesh = build_mesh()
    vertex = np.zeros(IBUG_COUNT, np.int64)
    side = np.linspace(-1.0, 1.0, 17)
    jaw = [(95.0 + 45.0 * (1.0 - abs(s) ** 1.6), 78.0 * s) for s in side]
    brows = [(66.0, a) for a in (-40, -33, -26, -19, -12, 12, 19, 26, 33, 40)]
    nose = [(t, 0.0) for t in (80, 88, 96, 104)] + [(108.0, a) for a in (-9.0, -4.5, 0.0, 4.5, 9.0)]
    vertex[0:17] = _nearest_skin(mesh, jaw)
    vertex[17:27] = _nearest_skin(mesh, brows)
    vertex[27:36] = _nearest_skin(mesh, nose)
    plus_eye, minus_eye = 0, 1
    upper = [_from_inner(mesh, rim) for rim in mesh.upper_lid_rims]
    lower = [_from_inner(mesh, rim) for rim in mesh.lower_lid_rims]
    vertex[36:42] = [_along(upper[minus_eye], f) for f in (1, 2 / 3, 1 / 3, 0)] + [_along(lower[minus_eye], f) for f in (1 / 3, 2 / 3)]
    vertex[42:48] = [_along(upper[plus_eye], f) for f in (0, 1 / 3, 2 / 3, 1)] + [_along(lower[plus_eye], f) for f in (2 / 3, 1 / 3)]
    upper_lip, lower_lip = _from_minus_x(mesh, mesh.upper_lip_rim), _from_minus_x(mesh, mesh.lower_lip_rim)
    outer_upper = _nearest_skin(mesh, [(119.0, a) for a in (-12, -6, 0, 6, 12)])
    outer_lower = _nearest_skin(mesh, [(128.0, a) for a in (12, 6, 0, -6, -12)])
    vertex[48:60] = [upper_lip[0], *outer_upper, upper_lip[-1], *outer_lower]
    vertex[60:68] = ([upper_lip[0]] + [_along(upper_lip, f) for f in (0.25, 0.5, 0.75)] + [upper_lip[-1]]
                     + [_along(lower_lip, f) for f in (0.75, 0.5, 0.25)])
    return _at_vertices(mesh.faces, vertex)


def model_landmarks(faces: np.ndarray) -> LandmarkEmbedding | None:
    """The embedding of a model with the procedural head's triangles, else None (a FLAME model
    needs its embedding file)."""
    from .procedural_mesh import build_mesh

    own = build_mesh().faces
    return procedural_embedding() if faces.shape == own.shape and np.array_equal(faces, own) else None


def head_landmarks(head_file, faces: np.ndarray) -> LandmarkEmbedding | None:
    """The embedding of the head model in ``head_file``: the procedural head's own, or an
    embedding file beside the model under the name VHAP or FLAME ship it with
    (:data:`EMBEDDING_FILES`: VHAP's ``asset/flame`` holds ``flame2023.pkl`` beside
    ``landmark_embedding_with_eyes.npy``; FLAME's download, ``flame_static_embedding.pkl``); else None."""
    own = model_landmarks(faces)
    if own is not None:
        return own
    folder = pathlib.Path(head_file).parent
    for name in EMBEDDING_FILES:
        if (folder / name).is_file():
            return read_embedding(folder / name)
    return None


def _nearest_skin(mesh, directions) -> list[int]:
    """Skin vertices of the head (not the neck) nearest each (polar, azimuth) direction in degrees."""
    skin = np.where((mesh.part == 0) & (mesh.vertices[:, 1] > -0.09))[0]
    unit = mesh.vertices[skin] / np.linalg.norm(mesh.vertices[skin], axis=1, keepdims=True)
    picked = []
    for theta, phi in directions:
        t, p = np.radians(theta), np.radians(phi)
        target = np.array([np.sin(t) * np.sin(p), np.cos(t), np.sin(t) * np.cos(p)])
        picked.append(int(skin[np.argmax(unit @ target)]))
    return picked


def _along(rim, fraction: float) -> int:
    return int(rim[int(round(fraction * (len(rim) - 1)))])


def _from_inner(mesh, rim) -> np.ndarray:
    """An eye's rim from its inner corner (nearest the midline) to its outer one."""
    rim = np.asarray(rim)
    return rim if abs(mesh.vertices[rim[0], 0]) < abs(mesh.vertices[rim[-1], 0]) else rim[::-1]


def _from_minus_x(mesh, rim) -> np.ndarray:
    rim = np.asarray(rim)
    return rim if mesh.vertices[rim[0], 0] < mesh.vertices[rim[-1], 0] else rim[::-1]


def _at_vertices(faces: np.ndarray, vertex: np.ndarray) -> LandmarkEmbedding:
    """Each landmark exactly at a vertex: a triangle that uses it, weight one on that corner."""
    triangle = np.zeros(len(vertex), np.int64)
    weights = np.zeros((len(vertex), 3))
    for k, v in enumerate(vertex):
        f, corner = np.argwhere(faces == v)[0]
        triangle[k], weights[k, corner] = f, 1.0
    return LandmarkEmbedding(triangle, weights, np.arange(len(vertex)))


# -- files --------------------------------------------------------------------------------------

def read_embedding(path: str | os.PathLike) -> LandmarkEmbedding:
    """A landmark embedding file: VHAP's ``.npy``, FLAME's static ``.pkl``, or an ``.npz`` with
    either's keys. Pickles are read with the restricted unpickler (numpy arrays only)."""
    path = pathlib.Path(path)
    if not path.is_file():
        raise InputError(path, None, "landmark embedding file not found")
    if path.suffix == ".npz":
        entries = load_npz(path)
    elif path.suffix == ".npy":
        entries = _read_npy_dict(path)
    else:
        entries = _unpickled(path)
    if not isinstance(entries, dict):
        raise InputError(path, None, f"expected a dict of arrays, found {type(entries).__name__}")
    return _from_entries(entries, path)


def _from_entries(entries: dict, path) -> LandmarkEmbedding:
    for faces_key, bary_key, first in (("full_lmk_faces_idx", "full_lmk_bary_coords", 0),
                                       ("lmk_faces_idx", "lmk_bary_coords", None),
                                       ("lmk_face_idx", "lmk_b_coords", None)):
        if faces_key in entries and bary_key in entries:
            faces = np.asarray(entries[faces_key]).reshape(-1)
            bary = np.asarray(entries[bary_key], np.float64).reshape(-1, 3)
            if len(faces) != len(bary):
                raise InputError(path, bary_key, f"{len(bary)} weight rows for {len(faces)} triangles")
            if not np.issubdtype(faces.dtype, np.integer):
                raise InputError(path, faces_key, f"expected integer triangle indices, found {faces.dtype}")
            if first is None:  # FLAME's static embedding: the 51 points from iBUG 17 on
                first = IBUG_COUNT - len(faces)
                if first < 0:
                    raise InputError(path, faces_key, f"expected at most {IBUG_COUNT} landmarks, found {len(faces)}")
            count = min(len(faces), IBUG_COUNT - first)  # VHAP's file adds two eye points after the 68
            return LandmarkEmbedding(faces[:count].astype(np.int64), bary[:count], np.arange(first, first + count))
    raise InputError(path, None, "expected the keys full_lmk_faces_idx/full_lmk_bary_coords (VHAP), "
                                 "lmk_face_idx/lmk_b_coords (FLAME) or lmk_faces_idx/lmk_bary_coords")


def _skipped(*args, **kwargs):
    """Torch tensors in VHAP's file (its dynamic contour, unused here) are read as nothing: rebuilding
    them would run ``torch.load`` on bytes from the file."""
    return None


_EMBEDDING_GLOBALS = {
    **NUMPY_ARRAY_GLOBALS,
    "torch._utils": lambda name: _skipped if name.startswith("_rebuild_tensor") else None,
    "torch.storage": lambda name: _skipped if name == "_load_from_bytes" else None,
    "collections": lambda name: dict if name == "OrderedDict" else None,
    "_codecs": lambda name: latin1_encode if name == "encode" else None,
}


def _unpickled(path: pathlib.Path, offset: int = 0):
    """The pickle in ``path`` from byte ``offset``, by the restricted unpickler."""
    try:
        return restricted_load(path, _EMBEDDING_GLOBALS, "a landmark embedding", offset)
    except UnsafePickleError:
        raise
    except Exception as error:  # a damaged pickle raises many different types
        raise InputError(path, None, f"not a readable pickle ({type(error).__name__}: {error})") from None


def _read_npy_dict(path: pathlib.Path) -> dict:
    """An ``np.save``d dict (a 0-d object array): the header by numpy, the pickle restricted."""
    with open(path, "rb") as handle:
        try:
            version = np.lib.format.read_magic(handle)
            shape, _, dtype = np.lib.format._read_array_header(handle, version)
        except ValueError as error:
            raise InputError(path, None, f"not a .npy file ({error})") from None
        if dtype != np.dtype(object):
            raise InputError(path, None, f"expected a pickled dict in the .npy, found an array of {dtype}")
        offset = handle.tell()
    value = _unpickled(path, offset)
    array = np.asarray(value, dtype=object)
    return array.reshape(-1)[0] if array.size == 1 else value
