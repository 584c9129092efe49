"""``RUN/refiner.pt``: the refiner's spec, cameras, matrices and how it was trained; written
atomically, read ``weights_only`` and checked (format, version, spec, shapes, finite values)
before use."""

from __future__ import annotations

import os
import pathlib

import torch

from ..errors import InputError
from ..io.atomic import atomic_path
from ..io.torch_file import check_format, load_torch_state, save_torch_state
from .groups import scale_vector
from .model import SPEC_KEYS, LinearRefiner

REFINER_FILE = "refiner.pt"
REFINER_FORMAT = "mogaface-refiner"
# 1 was a convolutional network, 2 had no full-size curvature: files of either are refused by the version check
REFINER_VERSION = 3
_LIMITS = {"grid": (2, 128), "render_limit": (8, 4096), "n_expr": (1, 400), "prior": (1e-6, 1e6), "gap_rank": (0, 64),
           "full_size_steps": (0, 16), "damping": (1e-12, 1e6)}
_NUMBERS = ("prior", "damping")
_MAX_CAMERAS = 1024


def save_refiner(refiner: LinearRefiner, path: str | os.PathLike, trained: dict | None = None) -> None:
    state = {"format": REFINER_FORMAT, "version": REFINER_VERSION, "spec": dict(refiner.spec),
             "cameras": list(refiner.camera_ids), "trained": dict(trained or {}), "state": refiner.tensors()}
    with atomic_path(pathlib.Path(path)) as tmp:
        save_torch_state(state, tmp)


def _checked_spec(spec, source) -> dict:
    if not isinstance(spec, dict):
        raise InputError(source, "spec", "expected a table of the refiner's sizes")
    for key in SPEC_KEYS:
        value = spec.get(key)
        low, high = _LIMITS[key]
        kinds = (int, float) if key in _NUMBERS else (int,)
        if not isinstance(value, kinds) or isinstance(value, bool) or not low <= value <= high:
            raise InputError(source, f"spec.{key}", f"expected {'a number' if key in _NUMBERS else 'an integer'} "
                                                    f"in [{low:g}, {high:g}], got {value!r}")
    return {k: spec[k] for k in SPEC_KEYS}


def _checked_cameras(cameras, source) -> list[str]:
    if (not isinstance(cameras, list) or not 1 <= len(cameras) <= _MAX_CAMERAS
            or not all(isinstance(c, str) and c for c in cameras) or len(set(cameras)) != len(cameras)):
        raise InputError(source, "cameras", f"expected a list of 1 to {_MAX_CAMERAS} distinct camera names")
    return cameras


def _earlier_version(state) -> bool:
    version = state.get("version") if isinstance(state, dict) and state.get("format") == REFINER_FORMAT else None
    return isinstance(version, int) and 1 <= version < REFINER_VERSION


def is_outdated(path: str | os.PathLike) -> bool:
    """Whether ``path`` holds a refiner of an earlier version (to be trained again, not read)."""
    return _earlier_version(load_torch_state(path, "refiner file"))


def load_refiner(path: str | os.PathLike, n_expr: int | None = None) -> tuple[LinearRefiner, dict]:
    """``(refiner, how it was trained)``; ``n_expr``: the avatar's expression count it must match."""
    state = load_torch_state(path, "refiner file")
    if _earlier_version(state):
        raise InputError(path, "version", f"written by an earlier refiner (version {state['version']}, this one reads "
                                          f"{REFINER_VERSION}): run 'train-refiner RUN' again")
    check_format(state, path, REFINER_FORMAT, REFINER_VERSION)
    spec = _checked_spec(state.get("spec"), path)
    if n_expr is not None and spec["n_expr"] != n_expr:
        raise InputError(path, "spec.n_expr", f"the refiner reads {spec['n_expr']} expression coefficients, "
                                              f"the avatar has {n_expr}")
    cameras = _checked_cameras(state.get("cameras"), path)
    tensors = state.get("state")
    if not isinstance(tensors, dict):
        raise InputError(path, "state", "expected a table of tensors")
    features, count = 3 * spec["grid"] ** 2, len(scale_vector(spec["n_expr"]))
    shapes = {"forward": (len(cameras), features, count), "residual": (len(cameras), features),
              "gap_mean": (len(cameras), features), "gap_var": (len(cameras), features),
              "gap_basis": (len(cameras), spec["gap_rank"], features), "curvature": (len(cameras), count, count)}
    for key, shape in shapes.items():
        value = tensors.get(key)
        if not isinstance(value, torch.Tensor) or not value.is_floating_point():
            raise InputError(path, f"state.{key}", "missing or not a floating-point tensor")
        if tuple(value.shape) != shape:
            raise InputError(path, f"state.{key}", f"expected shape {shape}, got {tuple(value.shape)}")
        if not bool(torch.isfinite(value).all()):
            raise InputError(path, f"state.{key}", "holds NaN or infinite values")
    for key in ("residual", "gap_var"):
        if bool((tensors[key] < 0).any()) or (key == "residual" and not bool((tensors[key] > 0).all())):
            raise InputError(path, f"state.{key}", "a variance must be positive")
    if bool((torch.diagonal(tensors["curvature"], dim1=-2, dim2=-1) < 0).any()):
        raise InputError(path, "state.curvature", "a mean JᵀJ has no negative diagonal")
    extra = sorted(set(tensors) - set(shapes))
    if extra:
        raise InputError(path, f"state.{extra[0]}", "not a part of this refiner")
    trained = state.get("trained") if isinstance(state.get("trained"), dict) else {}
    return LinearRefiner(spec, cameras, *(tensors[k] for k in shapes)), trained
