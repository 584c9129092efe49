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
import posixpath

import numpy as np

from ..errors import CaptureError
from ..limits import MAX_PARAM_VECTOR

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
    """Resolve a dataset-relative path, refusing ones that could leave ``root``.

    Absolute paths, drive letters and ``..`` components are refused (checked on the text, so a
    folder that is itself a symlink inside the dataset stays allowed).
    """
    if not isinstance(relative, str) or not relative:
        raise CaptureError(source, field, f"expected a non-empty relative path string, got {relative!r}")
    text = relative.replace("\\", "/")
    parts = text.split("/")
    if posixpath.isabs(text) or (len(parts[0]) >= 2 and parts[0][1] == ":"):
        raise CaptureError(source, field, f"absolute path {relative!r}: paths must be relative to the dataset folder")
    if ".." in parts:
        raise CaptureError(source, field, f"path {relative!r} leaves the dataset folder")
    return root.joinpath(*[p for p in parts if p not in ("", ".")])


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
OPTIONAL_FLAME_KEYS = ("static_offset",)


def normalize_flame_params(arrays: dict[str, np.ndarray], source) -> dict[str, np.ndarray]:
    """Check one timestep's FLAME parameters and return them as float32, without the batch axis.

    Accepts VHAP's per-timestep arrays with a leading axis of 1 (``(1, n)``, ``(1, V, 3)``) and
    plain ones (``(n,)``, ``(V, 3)``). Returns ``(n,)`` vectors and ``static_offset (V, 3)``.
    Keys other than the FLAME ones are ignored.
    """
    out: dict[str, np.ndarray] = {}
    for key, size in FLAME_KEYS.items():
        if key not in arrays:
            raise CaptureError(source, key, f"missing FLAME parameter (the file has {sorted(arrays)})")
        out[key] = _checked(arrays[key], key, 1, size, source)
    if "static_offset" in arrays:
        out["static_offset"] = _checked(arrays["static_offset"], "static_offset", 2, 3, source)
    return out


def _checked(value: np.ndarray, key: str, ndim: int, size: int | None, source) -> np.ndarray:
    array = np.asarray(value)
    if array.dtype.kind != "f":
        raise CaptureError(source, key, f"expected a float array, got dtype {array.dtype}")
    if array.ndim == ndim + 1 and array.shape[0] == 1:
        array = array[0]
    wanted = ("n",) * (ndim - 1) + (size if size is not None else "n",)
    if array.ndim != ndim or (size is not None and array.shape[-1] != size) or array.size == 0:
        batched = "(1, " + ", ".join(map(str, wanted)) + ")"
        raise CaptureError(source, key, f"expected shape {wanted} or {batched}, got {np.shape(value)}")
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
