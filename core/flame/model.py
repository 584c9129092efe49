"""``FlameModel``: the one FLAME evaluator (training, evaluation, export and Blender call it)."""

from __future__ import annotations

import os

import numpy as np
import torch

from ..errors import InputError
from .lbs import axis_angle_to_matrix, linear_blend_skinning
from .model_file import ModelArrays, read_model_file
from .teeth import match_tracking

# Pose parameters, in joint order after the root: (name, number of values).
POSE_PARAMETERS = (("rotation", 3), ("neck_pose", 3), ("jaw_pose", 3), ("eyes_pose", 6))
PARAMETER_NAMES = ("shape", "expr", "rotation", "neck_pose", "jaw_pose", "eyes_pose", "translation", "static_offset",
                   "dynamic_offset")
OFFSET_NAMES = ("static_offset", "dynamic_offset")


class FlameModel(torch.nn.Module):
    """A FLAME-format head model evaluated with linear blend skinning.

    ``model(shape=…, expr=…, rotation=…, neck_pose=…, jaw_pose=…, eyes_pose=…,
    translation=…, static_offset=…, dynamic_offset=…)`` takes tensors with a leading batch dimension
    (missing ones are zeros; names as in GaussianAvatars/VHAP ``flame_param/*.npz``)
    and returns vertices ``(B,V,3)``. Joints: global (``rotation``), neck, jaw, left
    eye, right eye; poses are axis-angle; ``translation`` is added last.
    Differentiable in every parameter; evaluates in the model's dtype (``.double()``
    for float64).
    """

    def __init__(self, arrays: ModelArrays, dtype: torch.dtype = torch.float32):
        super().__init__()
        if arrays.weights.shape[1] != 5:
            raise InputError(None, "kintree_table", f"expected FLAME's 5 joints, found {arrays.weights.shape[1]}")
        self.arrays = arrays
        self.parents = [int(p) for p in arrays.parents]
        self.shape_names = list(arrays.shape_names)
        self.expression_names = list(arrays.expression_names)
        self.n_shape, self.n_expr = arrays.n_shape, arrays.n_expr  # the component counts, fixed at load

        def buffer(name, value):
            self.register_buffer(name, torch.as_tensor(np.ascontiguousarray(value), dtype=dtype))

        n_vertices = arrays.v_template.shape[0]
        buffer("v_template", arrays.v_template)
        buffer("shapedirs", arrays.shapedirs)
        buffer("exprdirs", arrays.exprdirs)
        # (V,3,P) → (P,V·3) so the pose feature multiplies it directly.
        buffer("posedirs", arrays.posedirs.reshape(n_vertices * 3, -1).T)
        buffer("J_regressor", arrays.J_regressor)
        buffer("lbs_weights", arrays.weights)
        self.register_buffer("faces", torch.as_tensor(arrays.faces, dtype=torch.long))

    @classmethod
    def load(
        cls,
        path: str | os.PathLike,
        n_shape: int | None = None,
        n_expr: int | None = None,
        dtype: torch.dtype = torch.float32,
        n_vertices: int | None = None,
    ) -> "FlameModel":
        """Load a FLAME ``.pkl`` (official or ours) or ``.npz``; see ``read_model_file``.

        ``n_vertices``: the vertex count of the tracking to evaluate (its offsets' rows); 5143
        on a 5023-vertex FLAME file adds VHAP's teeth (:mod:`.teeth`).
        """
        arrays = match_tracking(read_model_file(path, n_shape=n_shape, n_expr=n_expr), n_vertices, path)
        return cls(arrays, dtype=dtype)

    def check_counts(self, params: dict, source) -> None:
        """Refuse parameters read from ``source`` (a ``flame_param`` file) with more shape or expression
        coefficients than this model has; fewer are fine (the rest are zero, as in FLAME's own code)."""
        for name, count, kind in (("shape", self.n_shape, "shape"), ("expr", self.n_expr, "expression")):
            value = params.get(name)
            found = value.shape[-1] if value is not None and len(value.shape) else 0
            if found > count:
                raise InputError(source, name, f"expected at most {count} values (the head model's {kind} "
                                               f"components), found {found}")

    @property
    def n_vertices(self) -> int:
        return self.v_template.shape[0]

    def forward(self, **params: torch.Tensor | None) -> torch.Tensor:
        return self.evaluate(**params)[0]

    def posed(self, params) -> np.ndarray:
        """(V,3) float64 vertices for one timestep's parameters given as numpy arrays (no batch axis)."""
        with torch.no_grad():
            return self(**{k: torch.as_tensor(np.asarray(v))[None] for k, v in params.items()})[0].double().numpy()

    def evaluate(self, **params: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
        """Like calling the model, but also returns the rest-pose joints ``(B,5,3)``."""
        p = self._complete(params)
        shaped = (
            self.v_template
            + torch.einsum("vck,bk->bvc", self.shapedirs, p["shape"])
            + torch.einsum("vck,bk->bvc", self.exprdirs, p["expr"])
            + p["static_offset"]
            + p["dynamic_offset"]
        )
        joints = torch.einsum("jv,bvc->bjc", self.J_regressor, shaped)
        full_pose = torch.cat([p[name] for name, _ in POSE_PARAMETERS], dim=1).reshape(-1, 5, 3)
        rotations = axis_angle_to_matrix(full_pose)
        vertices = linear_blend_skinning(shaped, rotations, joints, self.parents, self.lbs_weights, self.posedirs)
        return vertices + p["translation"][:, None, :], joints

    def _complete(self, params: dict) -> dict[str, torch.Tensor]:
        """Check names and sizes, find the batch size, fill what is missing with zeros."""
        unknown = set(params) - set(PARAMETER_NAMES)
        if unknown:
            raise InputError(None, sorted(unknown)[0], f"unknown FLAME parameter (known: {', '.join(PARAMETER_NAMES)})")
        given = {k: v for k, v in params.items() if v is not None}
        sizes = {k: int(v.shape[0]) for k, v in given.items() if v.dim() > 0}
        batch = max(sizes.values(), default=1)
        dtype, device = self.v_template.dtype, self.v_template.device
        counts = {"shape": self.n_shape, "expr": self.n_expr, "translation": 3, **dict(POSE_PARAMETERS)}
        out = {}
        for name, count in counts.items():
            value = given.get(name)
            if value is None:
                out[name] = torch.zeros(batch, count, dtype=dtype, device=device)
                continue
            value = value.to(dtype=dtype, device=device)
            if value.dim() != 2 or value.shape[0] not in (1, batch):
                raise InputError(None, name, f"expected shape (B, {count}) with B={batch}, found {tuple(value.shape)}")
            if name in ("shape", "expr") and value.shape[1] < count:
                # Fewer components than the model has: the rest are zero, as in FLAME's own code.
                value = torch.nn.functional.pad(value, (0, count - value.shape[1]))
            if value.shape[1] != count:
                raise InputError(None, name, f"expected {count} values per batch entry, found {value.shape[1]}")
            out[name] = value.expand(batch, count)
        for name in OFFSET_NAMES:
            out[name] = self._offset(given.get(name), name, batch, dtype, device)
        return out

    def _offset(self, offset, name: str, batch: int, dtype, device) -> torch.Tensor:
        """A per-vertex offset ``(1 or B, V, 3)``; zeros when not given."""
        if offset is None:
            return torch.zeros(1, self.n_vertices, 3, dtype=dtype, device=device)
        offset = offset.to(dtype=dtype, device=device)
        if offset.dim() != 3 or offset.shape[1:] != (self.n_vertices, 3) or offset.shape[0] not in (1, batch):
            hint = ""
            if offset.dim() == 3 and offset.shape[1] != self.n_vertices:
                hint = " (a tracking with another vertex count: load the model with n_vertices=that count)"
            raise InputError(None, name, f"expected shape (B, {self.n_vertices}, 3), found {tuple(offset.shape)}{hint}")
        return offset
