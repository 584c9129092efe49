"""The capture dataset layout (GaussianAvatars/VHAP): names, paths and FLAME parameter rules.

::

    transforms_train.json, transforms_val.json, transforms_test.json   one per split
    transforms.json                        every frame (written for other tools; not read)
    images/{t:05d}_{c:02d}.png             RGB, sRGB values
    fg_masks/{t:05d}_{c:02d}.png           foreground mask, grey
    flame_param/{t:05d}.npz                tracked FLAME parameters of timestep t
    canonical_flame_param.npz              the canonical (neutral) parameters

Shared by the writer (:mod:`.writer`), the reader (:mod:`.capture`) and the checks
(:mod:`.validate`), so the three agree on one set of rules. See docs/data-format.md.
"""

from __future__ import annotations

import pathlib

import numpy as np

from ..errors import CaptureError
from ..limits import MAX_PARAM_VECTOR
from .paths import resolve_capture_path

SPLITS = ("train", "val", "test")
ALL_FRAMES_FILE = "transforms.json"
CANONICAL_FILE = "canonical_flame_param.npz"


def split_file(split: str) -> str:
    return f"transforms_{split}.json"


def image_path(timestep: int, camera_index: int) -> str:
    return f"images/{timestep:05d}_{camera_index:02d}.png"


def mask_path(timestep: int, camera_index: int) -> str:
    return f"fg_masks/{timestep:05d}_{camera_index:02d}.png"


def flame_param_path(timestep: int) -> str:
    return f"flame_param/{timestep:05d}.npz"


def resolve_inside(root: pathlib.Path, relative, source, field: str) -> pathlib.Path:
    """Resolve a dataset-relative path by the rule of :mod:`.paths` (text checks only)."""
    return resolve_capture_path(root, relative, source, field)


# -- the principal point's y ------------------------------------------------------------------
# VHAP converts its OpenCV calibration to OpenGL axes with ``K[1,2] = H - K[1,2]``
# (vhap/util/camera.py, convert_camera_convention) and its exporter writes that value as
# ``cy``; its renderer's projection (``(h - 2 cy) / h`` in the OpenGL projection matrix) reads
# it from the bottom edge. So ``cy`` in this layout is measured from the image's bottom edge
# unless the split file says ``"cy_origin": "top"``. These two functions are the only place
# that converts it; inside MoGaFace ``cy`` is OpenCV's, from the top.
CY_ORIGINS = ("bottom", "top")
CY_ORIGIN_KEY = "cy_origin"


def cy_origin(doc: dict, source) -> str:
    """The convention of a split file's ``cy`` values: VHAP's ``"bottom"`` unless it says ``"top"``."""
    value = doc.get(CY_ORIGIN_KEY, "bottom")
    if value not in CY_ORIGINS:
        raise CaptureError(source, CY_ORIGIN_KEY, f"expected one of {CY_ORIGINS}, got {value!r}")
    return value


def cy_from_file(cy: float, height: int, origin: str) -> float:
    """The file's ``cy`` as OpenCV's (pixels from the top edge)."""
    return height - cy if origin == "bottom" else cy


def cy_to_file(cy: float, height: int, origin: str = "bottom") -> float:
    """OpenCV's ``cy`` as the file stores it (VHAP's: from the bottom edge)."""
    return height - cy if origin == "bottom" else cy


# FLAME parameters: name -> required length of the last axis (None: any length, set by the model).
FLAME_KEYS: dict[str, int | None] = {
    "shape": None,
    "expr": None,
    "rotation": 3,
    "neck_pose": 3,
    "jaw_pose": 3,
    "eyes_pose": 6,
    "translation": 3,
}
OPTIONAL_FLAME_KEYS = ("static_offset", "dynamic_offset")


def normalize_flame_params(arrays: dict[str, np.ndarray], source) -> dict[str, np.ndarray]:
    """Check one timestep's FLAME parameters and return them as float32, without the batch axis.

    Accepts VHAP's per-timestep arrays with a leading axis of 1 (``(1, n)``, ``(1, V, 3)``) and
    plain ones (``(n,)``, ``(V, 3)``). Returns ``(n,)`` vectors, ``static_offset (V, 3)`` and
    VHAP's per-timestep ``dynamic_offset (V, 3)`` (its tracking with ``use_dynamic_offset``).
    Keys other than the FLAME ones are ignored.
    """
    out: dict[str, np.ndarray] = {}
    for key, size in FLAME_KEYS.items():
        if key not in arrays:
            raise CaptureError(source, key, f"missing FLAME parameter (the file has {sorted(arrays)})")
        out[key] = _checked(arrays[key], key, 1, size, source)
    for key in OPTIONAL_FLAME_KEYS:
        if key in arrays:
            out[key] = _checked(arrays[key], key, 2, 3, source)
    return out


def _checked(value: np.ndarray, key: str, ndim: int, size: int | None, source) -> np.ndarray:
    array = np.asarray(value)
    if array.dtype.kind != "f":
        raise CaptureError(source, key, f"expected a float array, got dtype {array.dtype}")
    if array.ndim == ndim + 1 and array.shape[0] == 1:
        array = array[0]
    wanted = ["n"] * (ndim - 1) + [str(size) if size is not None else "n"]
    if array.ndim != ndim or (size is not None and array.shape[-1] != size) or array.size == 0:
        got = np.shape(value)
        got = f"shape {got}" + (" (a single number)" if got == () else " (no values)" if 0 in got else "")
        raise CaptureError(source, key, f"expected shape ({', '.join(wanted)}{',' * (ndim == 1)}) or "
                                        f"(1, {', '.join(wanted)}), got {got}")
    if ndim == 1 and array.shape[-1] > MAX_PARAM_VECTOR:
        raise CaptureError(source, key, f"{array.shape[-1]} coefficients; the limit is {MAX_PARAM_VECTOR}")
    if not np.isfinite(array).all():
        raise CaptureError(source, key, "contains NaN or inf")
    return array.astype(np.float32)


def batched_flame_params(params: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The VHAP per-timestep file form: a leading axis of 1 on everything but ``shape``."""
    out = {}
    for key, value in params.items():
        value = np.asarray(value, dtype=np.float32)
        out[key] = value if key == "shape" else value[None]
    return out
