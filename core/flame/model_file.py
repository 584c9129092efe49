"""FLAME-format model files (``.pkl`` as released, or ``.npz`` with the same keys), validated.

Keys: ``v_template (V,3)``, ``f (F,3)``, ``shapedirs (V,3,n_shape+n_expr)``,
``posedirs (V,3,9·(J−1))``, ``J_regressor (J,V)``, ``weights (V,J)``,
``kintree_table (2,J)``. Our own files add ``n_shape``/``n_expr``, names of the
components, and UVs with a texture (``vt``, ``ft``, ``texture``).
"""

from __future__ import annotations

import dataclasses
import os
import pathlib

import numpy as np

from ..errors import ModelFileError
from ..io.files import check_regular_file
from ..io.npz import load_npz, save_npz
from .safe_pickle import load_model_pickle, save_model_pickle

REQUIRED_KEYS = ("v_template", "f", "shapedirs", "posedirs", "J_regressor", "weights", "kintree_table")
# The official FLAME 2020/2023 files hold 300 shape then 100 expression components.
OFFICIAL_SHAPE_COUNT = 300
OFFICIAL_EXPR_COUNT = 100


@dataclasses.dataclass
class ModelArrays:
    """A validated head model: float64 arrays, ``faces`` int64, component counts resolved."""

    v_template: np.ndarray  # (V,3)
    faces: np.ndarray  # (F,3)
    shapedirs: np.ndarray  # (V,3,n_shape)
    exprdirs: np.ndarray  # (V,3,n_expr)
    posedirs: np.ndarray  # (V,3,9·(J−1))
    J_regressor: np.ndarray  # (J,V)
    weights: np.ndarray  # (V,J)
    parents: np.ndarray  # (J,) parent index, −1 for the root
    shape_names: list[str]
    expression_names: list[str]
    vt: np.ndarray | None = None  # (VT,2) UVs, v up
    ft: np.ndarray | None = None  # (F,3) UV index per triangle corner
    texture: np.ndarray | None = None  # (H,W,3) uint8

    @property
    def n_shape(self) -> int:
        return self.shapedirs.shape[2]

    @property
    def n_expr(self) -> int:
        return self.exprdirs.shape[2]


def read_model_file(path: str | os.PathLike, n_shape: int | None = None, n_expr: int | None = None) -> ModelArrays:
    """Load and validate a FLAME-format ``.pkl`` or ``.npz``.

    ``n_shape``/``n_expr`` select how many components to use; by default all of them.
    The split of ``shapedirs`` into shape and expression parts is read from the file
    (``n_shape`` key), else taken as FLAME's 300 + 100, else must be given.
    """
    path = pathlib.Path(path)
    check_regular_file(path, ModelFileError)
    raw = load_npz(path) if path.suffix == ".npz" else load_model_pickle(path)
    return _validate(path, raw, n_shape, n_expr)


def _array(path, raw, key, ndim, dtype_kind="f"):
    if key not in raw:
        raise ModelFileError(path, key, f"missing (a FLAME model needs {', '.join(REQUIRED_KEYS)})")
    try:
        value = np.asarray(raw[key])
    except Exception as error:
        raise ModelFileError(path, key, f"not an array ({error})") from None
    if value.ndim != ndim or value.dtype.kind not in ("iu" if dtype_kind == "i" else "fiu"):
        raise ModelFileError(path, key, f"expected a {ndim}-D numeric array, found shape {value.shape} dtype {value.dtype}")
    if value.dtype.kind == "f" and not np.all(np.isfinite(value)):
        raise ModelFileError(path, key, "contains NaN or inf")
    return value


def _expect_shape(path, key, value, shape):
    if any(want is not None and got != want for got, want in zip(value.shape, shape)):
        readable = "(" + ", ".join("*" if n is None else str(n) for n in shape) + ")"
        raise ModelFileError(path, key, f"expected shape {readable}, found {value.shape}")


def _scalar_int(path, raw, key):
    if key not in raw:
        return None
    try:
        return int(np.asarray(raw[key]).reshape(()))
    except Exception:
        raise ModelFileError(path, key, "expected a single integer") from None


def _names(raw, key, count, prefix):
    names = [str(n) for n in np.asarray(raw[key]).reshape(-1)] if key in raw else []
    return (names + [f"{prefix}{i:03d}" for i in range(len(names), count)])[:count]


def _validate(path, raw, n_shape, n_expr) -> ModelArrays:
    v_template = _array(path, raw, "v_template", 2).astype(np.float64)
    _expect_shape(path, "v_template", v_template, (None, 3))
    n_vertices = v_template.shape[0]

    faces = _array(path, raw, "f", 2, "i").astype(np.int64)
    _expect_shape(path, "f", faces, (None, 3))
    if len(faces) == 0 or n_vertices == 0:
        raise ModelFileError(path, "f" if n_vertices else "v_template", "a head model needs vertices and faces (found none)")
    if faces.min() < 0 or faces.max() >= n_vertices:
        raise ModelFileError(path, "f", f"vertex indices must lie in [0, {n_vertices})")

    kintree = _array(path, raw, "kintree_table", 2, "i").astype(np.int64)
    _expect_shape(path, "kintree_table", kintree, (2, None))
    n_joints = kintree.shape[1]
    parents = _parents_from_kintree(path, kintree)

    dirs = _array(path, raw, "shapedirs", 3).astype(np.float64)
    _expect_shape(path, "shapedirs", dirs, (n_vertices, 3, None))
    posedirs = _array(path, raw, "posedirs", 3).astype(np.float64)
    _expect_shape(path, "posedirs", posedirs, (n_vertices, 3, 9 * (n_joints - 1)))
    regressor = _array(path, raw, "J_regressor", 2).astype(np.float64)
    _expect_shape(path, "J_regressor", regressor, (n_joints, n_vertices))
    weights = _array(path, raw, "weights", 2).astype(np.float64)
    _expect_shape(path, "weights", weights, (n_vertices, n_joints))

    file_shape, file_expr = _component_split(path, raw, dirs.shape[2])
    n_shape = file_shape if n_shape is None else n_shape
    n_expr = file_expr if n_expr is None else n_expr
    if not 0 <= n_shape <= file_shape:
        raise ModelFileError(path, "shapedirs", f"asked for {n_shape} shape components, the file has {file_shape}")
    if not 0 <= n_expr <= file_expr:
        raise ModelFileError(path, "shapedirs", f"asked for {n_expr} expression components, the file has {file_expr}")

    vt, ft, texture = _uv_and_texture(path, raw, faces)
    return ModelArrays(
        v_template=v_template,
        faces=faces,
        shapedirs=dirs[:, :, :n_shape],
        exprdirs=dirs[:, :, file_shape : file_shape + n_expr],
        posedirs=posedirs,
        J_regressor=regressor,
        weights=weights,
        parents=parents,
        shape_names=_names(raw, "shape_names", n_shape, "shape"),
        expression_names=_names(raw, "expression_names", n_expr, "expr"),
        vt=vt,
        ft=ft,
        texture=texture,
    )


def _parents_from_kintree(path, kintree):
    order = kintree[1]
    if not np.array_equal(order, np.arange(len(order))):
        raise ModelFileError(path, "kintree_table", "second row must list the joints 0..J-1 in order")
    parents = kintree[0].copy()
    parents[0] = -1  # the root's parent is stored as 2**32 - 1 (or -1)
    for joint in range(1, len(parents)):
        if not 0 <= parents[joint] < joint:
            raise ModelFileError(path, "kintree_table", f"joint {joint} must have an earlier joint as parent")
    return parents


def _component_split(path, raw, total):
    stored = _scalar_int(path, raw, "n_shape")
    if stored is not None:
        if not 0 <= stored <= total:
            raise ModelFileError(path, "n_shape", f"must lie in [0, {total}] (shapedirs has {total} components)")
        return stored, total - stored
    if total == OFFICIAL_SHAPE_COUNT + OFFICIAL_EXPR_COUNT:
        return OFFICIAL_SHAPE_COUNT, OFFICIAL_EXPR_COUNT
    raise ModelFileError(
        path,
        "shapedirs",
        f"has {total} components and the file does not say how many are shape (key 'n_shape'); "
        "give n_shape explicitly",
    )


def _uv_and_texture(path, raw, faces):
    if "vt" not in raw and "ft" not in raw:
        return None, None, None
    vt = _array(path, raw, "vt", 2).astype(np.float64)
    _expect_shape(path, "vt", vt, (None, 2))
    ft = _array(path, raw, "ft", 2, "i").astype(np.int64)
    _expect_shape(path, "ft", ft, faces.shape)
    if ft.size and (ft.min() < 0 or ft.max() >= len(vt)):
        raise ModelFileError(path, "ft", f"UV indices must lie in [0, {len(vt)})")
    texture = None
    if "texture" in raw:
        texture = np.asarray(raw["texture"])
        if texture.ndim != 3 or texture.shape[2] != 3 or texture.dtype != np.uint8:
            raise ModelFileError(path, "texture", f"expected (H,W,3) uint8, found {texture.shape} {texture.dtype}")
    return vt, ft, texture


def write_model_file(path: str | os.PathLike, model: dict, chumpy_keys: tuple[str, ...] = ()) -> None:
    """Write a model dict (the keys above) as ``.pkl`` (official layout) or ``.npz``, by suffix."""
    path = pathlib.Path(path)
    missing = [k for k in REQUIRED_KEYS if k not in model]
    if missing:
        raise ModelFileError(path, missing[0], "missing from the model to write")
    if path.suffix == ".npz":
        save_npz(path, model)
    elif path.suffix == ".pkl":
        save_model_pickle(path, model, chumpy_keys=chumpy_keys)
    else:
        raise ModelFileError(path, None, "expected a .pkl or .npz file name")
