"""The head rig: a FLAME head as Blender shows it (shape keys, pose key, custom properties).

Blender's relative shape keys plus one "pose" shape key give exactly the core's FLAME evaluation
(pose correctives, skinning); this module computes those keys and names the head object's
custom properties.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib

import numpy as np

from ..errors import InputError
from .axes import flame_to_blender, image_pixels
from .file_cache import CACHE_LOCK, file_version

#: Object custom properties that hold the pose, with their sizes (FLAME's parameter names).
POSE_PROPERTIES = {
    "rotation": ("mogaface_rotation", 3),
    "neck_pose": ("mogaface_neck_pose", 3),
    "jaw_pose": ("mogaface_jaw_pose", 3),
    "eyes_pose": ("mogaface_eyes_pose", 6),
    "translation": ("mogaface_translation", 3),
}
MODEL_PATH_PROPERTY = "mogaface_model_path"
SHAPE_PROPERTY = "mogaface_shape"
STATIC_OFFSET_PROPERTY = "mogaface_static_offset"
POSE_KEY_NAME = "MoGaFace pose"
EXPRESSION_SLIDER_RANGE = 10.0
AVATAR_PATH_PROPERTY = "mogaface_avatar_path"

_model_cache: dict = {}


def load_head_model(path, n_vertices: int | None = None):
    """The :class:`~mogaface.core.flame.numpy_model.NumpyFlame` of ``path``, cached per file.

    numpy, not torch: importing and posing heads in Blender needs no torch. The cache key
    includes the file's size and modification time, so an edited file reloads.
    ``n_vertices``: a tracking's vertex count (5143 on FLAME adds its teeth, see ``flame.teeth``).
    """
    from ..flame.numpy_model import NumpyFlame

    path, key = file_version(path, "head model")
    key = key + (n_vertices,)
    with CACHE_LOCK:
        model = _model_cache.get(key)
        if model is None:
            model = NumpyFlame.load(path, n_vertices=n_vertices)
            for old in [k for k in _model_cache if k[0] == key[0] and k[-1] == n_vertices]:
                del _model_cache[old]
            _model_cache[key] = model
    return model


def identity_vertex_count(path) -> int | None:
    """The vertex count of an ``.npz``'s ``static_offset`` (None without one)."""
    from ..io.npz import load_npz

    offset = load_npz(path).get("static_offset")
    return None if offset is None or np.ndim(offset) < 2 else int(np.shape(offset)[-2])


def read_identity(path, n_shape: int, n_vertices: int) -> tuple[np.ndarray, np.ndarray | None]:
    """``shape`` (fitted to ``n_shape``) and ``static_offset`` (or None) from an ``.npz``.

    Any file with a ``shape`` array works: a ``flame_param`` timestep, the canonical file, or
    one holding only the identity.
    """
    from ..io.npz import load_npz

    params = load_npz(path)
    if "shape" not in params:
        raise InputError(path, "shape", f"missing (the file has {sorted(params)})")
    shape = np.asarray(params["shape"])
    if shape.ndim == 2 and shape.shape[0] == 1:
        shape = shape[0]
    if shape.ndim != 1 or shape.dtype.kind not in "fiu" or not np.isfinite(shape).all():
        raise InputError(path, "shape", f"expected a finite (n,) or (1, n) array, found {shape.shape} {shape.dtype}")
    offset = params.get("static_offset")
    if offset is not None:
        offset = np.asarray(offset, np.float64)
        offset = offset[0] if offset.ndim == 3 and offset.shape[0] == 1 else offset
        if offset.shape != (n_vertices, 3) or not np.isfinite(offset).all():
            problem = f"expected shape ({n_vertices}, 3) for this head, found {offset.shape}"
            raise InputError(path, "static_offset", problem)
    return fit_components(shape, n_shape), offset


def fit_components(values, count: int) -> np.ndarray:
    """Coefficients ``(…, n)`` padded with zeros or cut to ``count`` (FLAME uses the leading ones)."""
    values = np.asarray(values, dtype=np.float64)
    if values.shape[-1] >= count:
        return values[..., :count].copy()
    pad = [(0, 0)] * (values.ndim - 1) + [(0, count - values.shape[-1])]
    return np.pad(values, pad)


@dataclasses.dataclass
class HeadRig:
    """A FLAME head as Blender shows it: shape keys for expressions, a pose key for the rest.

    Blender's relative shape keys give ``basis + Σ wₖ (keyₖ − basis)``. The basis is the
    identity's neutral head, key k adds expression component k, and the pose key (weight 1)
    adds ``posed − unposed``: the pose correctives, skinning and translation that FLAME
    applies on top of the blend shapes. Blender's blend then equals the core's evaluation.
    All positions are in Blender world axes (see :func:`flame_to_blender`).
    """

    model: object  # NumpyFlame
    shape: np.ndarray
    static_offset: np.ndarray | None = None

    def __post_init__(self):
        self.shape = fit_components(self.shape, self.model.n_shape)

    def neutral(self) -> np.ndarray:
        """The identity's head without expression or pose, FLAME axes ``(V,3)``."""
        arrays = self.model.arrays
        out = arrays.v_template + arrays.shapedirs @ self.shape
        return out if self.static_offset is None else out + self.static_offset

    def basis(self) -> np.ndarray:
        return flame_to_blender(self.neutral())

    def expression_keys(self) -> np.ndarray:
        """``(n_expr, V, 3)``: the basis plus one expression component each (Blender axes)."""
        exprdirs = np.moveaxis(self.model.arrays.exprdirs, 2, 0)
        return self.basis()[None] + flame_to_blender(exprdirs)

    def evaluate(self, expr, pose: dict) -> np.ndarray:
        """The core's FLAME evaluation for this identity, FLAME axes ``(V,3)`` float64."""
        return self.model(shape=self.shape, expr=fit_components(expr, self.model.n_expr),
                          static_offset=self.static_offset, **pose)

    def pose_key(self, expr, pose: dict) -> np.ndarray:
        """The pose shape key for expression weights ``expr`` and ``pose`` (Blender axes)."""
        expr = fit_components(expr, self.model.n_expr)
        unposed = self.neutral() + self.model.arrays.exprdirs @ expr
        return self.basis() + flame_to_blender(self.evaluate(expr, pose) - unposed)


def zero_pose() -> dict:
    """Every pose parameter at rest (FLAME names)."""
    return {name: np.zeros(size) for name, (_, size) in POSE_PROPERTIES.items()}


@dataclasses.dataclass
class HeadImport:
    """What Blender needs to build a head object: mesh, UVs, texture, shape keys, rig."""

    name: str
    model_path: str
    rig: HeadRig
    faces: np.ndarray  # (F,3) vertex indices, the model's triangle order
    basis: np.ndarray  # (V,3) Blender axes
    expression_keys: np.ndarray  # (n_expr,V,3)
    expression_names: list
    pose_key: np.ndarray  # (V,3) at the rest pose
    loop_uvs: np.ndarray | None  # (3F,2) one UV per triangle corner
    texture_pixels: np.ndarray | None  # flat RGBA float32, Blender row order
    texture_size: tuple[int, int] | None  # (width, height)


def head_import(path, shape_file=None) -> HeadImport:
    """Load a FLAME-format head (and optionally the identity of a ``flame_param`` npz) for Blender."""
    model = load_head_model(path, identity_vertex_count(shape_file) if shape_file else None)
    arrays = model.arrays
    if shape_file:
        shape, offset = read_identity(shape_file, model.n_shape, model.n_vertices)
    else:
        shape, offset = np.zeros(model.n_shape), None
    rig = HeadRig(model, shape, offset)
    uvs = None if arrays.vt is None else arrays.vt[arrays.ft].reshape(-1, 2)
    texture = arrays.texture
    return HeadImport(
        name=pathlib.Path(path).stem,
        model_path=os.fspath(pathlib.Path(path).expanduser().resolve()),
        rig=rig,
        faces=np.asarray(arrays.faces, np.int64),
        basis=rig.basis(),
        expression_keys=rig.expression_keys(),
        expression_names=list(model.expression_names),
        pose_key=rig.pose_key(np.zeros(model.n_expr), zero_pose()),
        loop_uvs=uvs,
        texture_pixels=None if texture is None else image_pixels(texture),
        texture_size=None if texture is None else (texture.shape[1], texture.shape[0]),
    )



def head_flame_params(shape, static_offset, expr, pose: dict, n_shape: int, n_expr: int) -> dict:
    """One timestep's FLAME parameters (numpy, unbatched) from a head's identity and rig values.

    ``expr`` and ``pose`` are what a head object shows at a frame (its shape-key values and
    pose properties, i.e. what the keyframes give); counts are fitted to the model rendered.
    """
    params = {"shape": fit_components(shape, n_shape), "expr": fit_components(expr, n_expr)}
    for name, (_, size) in POSE_PROPERTIES.items():
        value = np.asarray(pose.get(name, np.zeros(size)), np.float64).reshape(-1)
        if value.shape != (size,):
            raise InputError(None, name, f"expected {size} values, found {value.shape[0]}")
        params[name] = value
    if static_offset is not None:
        params["static_offset"] = np.asarray(static_offset, np.float64).reshape(-1, 3)
    return params
