"""``RUN/refiner.pt``: the refiner's spec, weights and how it was trained; written atomically,
read ``weights_only`` and checked (format, version, spec, weights) before use."""

from __future__ import annotations

import os
import pathlib

import torch

from ..errors import InputError
from ..io.atomic import atomic_path
from ..io.torch_file import check_format, load_torch_state, save_torch_state
from .network import SPEC_KEYS, Refiner

REFINER_FILE = "refiner.pt"
REFINER_FORMAT = "mogaface-refiner"
REFINER_VERSION = 1
_LIMITS = {"crop": (16, 512), "width": (8, 256), "feature_dim": (8, 1024), "heads": (1, 16), "layers": (1, 8),
           "n_expr": (1, 400)}


def save_refiner(refiner: Refiner, path: str | os.PathLike, trained: dict | None = None) -> None:
    state = {"format": REFINER_FORMAT, "version": REFINER_VERSION, "spec": dict(refiner.spec),
             "trained": dict(trained or {}), "state": {k: v.detach().clone() for k, v in refiner.state_dict().items()}}
    with atomic_path(pathlib.Path(path)) as tmp:
        save_torch_state(state, tmp)


def _checked_spec(spec, source) -> dict:
    if not isinstance(spec, dict):
        raise InputError(source, "spec", "expected a table of the network's sizes")
    out = {}
    for key in SPEC_KEYS:
        value = spec.get(key)
        low, high = _LIMITS[key]
        if not isinstance(value, int) or isinstance(value, bool) or not low <= value <= high:
            raise InputError(source, f"spec.{key}", f"expected an integer in [{low}, {high}], got {value!r}")
    out.update({k: spec[k] for k in SPEC_KEYS})
    if out["width"] % 8:
        raise InputError(source, "spec.width", f"must be a multiple of 8 (group normalisation), got {out['width']}")
    if out["feature_dim"] % out["heads"]:
        raise InputError(source, "spec.heads", f"must divide feature_dim {out['feature_dim']}")
    return out


def load_refiner(path: str | os.PathLike, n_expr: int | None = None) -> tuple[Refiner, dict]:
    """``(refiner, how it was trained)``; ``n_expr``: the avatar's expression count it must match."""
    state = load_torch_state(path, "refiner file")
    check_format(state, path, REFINER_FORMAT, REFINER_VERSION)
    spec = _checked_spec(state.get("spec"), path)
    if n_expr is not None and spec["n_expr"] != n_expr:
        raise InputError(path, "spec.n_expr", f"the refiner reads {spec['n_expr']} expression coefficients, "
                                              f"the avatar has {n_expr}")
    refiner = Refiner(spec)
    weights = state.get("state")
    if not isinstance(weights, dict) or not all(isinstance(v, torch.Tensor) for v in weights.values()):
        raise InputError(path, "state", "expected a table of weight tensors")
    expected = refiner.state_dict()
    for key, value in expected.items():
        if key not in weights:
            raise InputError(path, f"state.{key}", "missing")
        if weights[key].shape != value.shape:
            raise InputError(path, f"state.{key}", f"expected shape {tuple(value.shape)}, got {tuple(weights[key].shape)}")
        if weights[key].is_floating_point() and not bool(torch.isfinite(weights[key]).all()):
            raise InputError(path, f"state.{key}", "holds NaN or infinite values")
    extra = sorted(set(weights) - set(expected))
    if extra:
        raise InputError(path, f"state.{extra[0]}", "not a weight of this network")
    refiner.load_state_dict(weights)
    refiner.eval()
    trained = state.get("trained") if isinstance(state.get("trained"), dict) else {}
    return refiner, trained
