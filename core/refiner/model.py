"""The refiner's model: per camera, a learned linear forward model of how the head crop changes
with each regressed parameter, and a noise model of what else differs between captures and the
avatar's renders. A pass is one generalised least-squares solve over every view it is given.

For view ``v`` the feature ``f_v`` is the difference (observed − rendered at the current
parameters) of the head crop, area-pooled to ``grid``². The model reads it as

    f_v = A_v · x + g_v + noise_v,    noise_v ~ N(0, diag(r_v + s_v) + B_vᵀB_v),    x ~ N(0, I / prior)

where ``x`` is the offset in multiples of each group's expected error (:mod:`.groups`), ``A_v`` and
its residual variance ``r_v`` come from renders at known offsets, and ``g_v`` is the mean of the
capture-versus-render gap at the run's own (fine-tuned) parameters, ``B_v`` its ``gap_rank``
leading components and ``s_v`` the variance they leave. The gap is structured (the same parts of
the face are off together), and telling the solve which patterns are gap rather than motion was
worth more than any other change (docs/notebook/2026-11-26-multiview-refiner.md). The solve
fuses any subset of the cameras it knows (a scored view is simply left out).

Pooled cells keep the low frequencies of the difference and lose where an edge sits within a cell,
which is where an expression shows. So a pass ends with ``full_size_steps`` Gauss–Newton steps on
the full-size crops: the gradient ``g = Σ_v J_vᵀ(o_v − r_v) / pixels_v`` is exact (one render and
one backward per view), and the matrix ``Σ_v H_v`` is each camera's mean ``J_vᵀJ_v / pixels_v``
measured at training timesteps (``curvature``), damped by ``damping``:
``x = (Σ_v H_v + damping·I)⁻¹ g``. Measuring ``J`` itself at every frame would take a render per
regressed value and view; its mean over a few frames read the expression as well
(docs/notebook/2026-11-26-multiview-refiner.md).
"""

from __future__ import annotations

import numpy as np
import torch

from ..errors import InputError
from .groups import scale_vector

SPEC_KEYS = ("grid", "render_limit", "n_expr", "prior", "gap_rank", "full_size_steps", "damping")


class LinearRefiner:
    """``forward`` (C, D, P), ``residual`` / ``gap_mean`` / ``gap_var`` (C, D), ``gap_basis``
    (C, gap_rank, D) and ``curvature`` (C, P, P) for ``camera_ids``."""

    def __init__(self, spec: dict, camera_ids: list[str], forward: torch.Tensor, residual: torch.Tensor,
                 gap_mean: torch.Tensor, gap_var: torch.Tensor, gap_basis: torch.Tensor, curvature: torch.Tensor):
        self.spec = {k: spec[k] for k in SPEC_KEYS}
        self.camera_ids = list(camera_ids)
        self.forward = forward.to(torch.float64)
        self.residual = residual.to(torch.float64)
        self.gap_mean = gap_mean.to(torch.float64)
        self.gap_var = gap_var.to(torch.float64)
        self.gap_basis = gap_basis.to(torch.float64)
        self.curvature = curvature.to(torch.float64)
        self.scales = scale_vector(spec["n_expr"]).to(torch.float64)

    @property
    def grid(self) -> int:
        return self.spec["grid"]

    def knows(self, camera_id: str) -> bool:
        return camera_id in self.camera_ids

    def _index(self, camera_id: str) -> int:
        if not self.knows(camera_id):
            raise InputError(None, "camera", f"the refiner was trained for cameras {self.camera_ids}, "
                                             f"not {camera_id!r}")
        return self.camera_ids.index(camera_id)

    def offset(self, features: torch.Tensor, camera_ids: list[str]) -> np.ndarray:
        """The flat parameter offset (:func:`.groups.flatten` order) that best explains ``features``
        (V, D), one row per view from the cameras ``camera_ids``."""
        size = len(self.scales)
        normal = self.spec["prior"] * torch.eye(size, dtype=torch.float64)
        projected = torch.zeros(size, dtype=torch.float64)
        for row, camera_id in zip(features.to(torch.float64), camera_ids):
            c = self._index(camera_id)
            weighted = self._whitened(c, self.forward[c]).T
            normal += weighted @ self.forward[c]
            projected += weighted @ (row - self.gap_mean[c])
        return (torch.linalg.solve(normal, projected) * self.scales).numpy().astype(np.float32)

    def full_size_steps(self, camera_ids: list[str]) -> int:
        """The full-size steps a pass takes over these views: none where the curvature was never
        measured (a refiner stopped before it)."""
        measured = any(bool(self.curvature[self._index(c)].any()) for c in camera_ids)
        return self.spec["full_size_steps"] if measured else 0

    def full_size_offset(self, gradient: torch.Tensor, camera_ids: list[str]) -> np.ndarray:
        """The flat offset of one damped Gauss–Newton step from the full-size ``gradient``
        (:func:`.views.full_size_gradient` over the views of ``camera_ids``)."""
        size = len(self.scales)
        normal = self.spec["damping"] * torch.eye(size, dtype=torch.float64)
        for camera_id in camera_ids:
            normal += self.curvature[self._index(camera_id)]
        step = torch.linalg.solve(normal, gradient.to(torch.float64))
        return (step * self.scales).numpy().astype(np.float32)

    def _whitened(self, c: int, x: torch.Tensor) -> torch.Tensor:
        """``Σ_c⁻¹ x`` for the noise covariance ``diag(r + s) + BᵀB`` (Woodbury: one small solve)."""
        inverse = 1.0 / (self.residual[c] + self.gap_var[c])
        basis = self.gap_basis[c]
        scaled = inverse[:, None] * x
        small = torch.eye(len(basis), dtype=torch.float64) + (basis * inverse) @ basis.T
        return scaled - (inverse[:, None] * basis.T) @ torch.linalg.solve(small, basis @ scaled)

    # the settings a pass reads at inference, which a trained refiner can change without retraining
    INFERENCE_SETTINGS = ("prior", "gap_rank", "full_size_steps", "damping")

    def with_settings(self, **settings) -> "LinearRefiner":
        """The same measured model solved with other inference settings (:data:`INFERENCE_SETTINGS`),
        for choosing them on validation frames. ``gap_rank`` may only shrink: the dropped
        components' variance joins the diagonal, so the noise model keeps its total variance."""
        unknown = set(settings) - set(self.INFERENCE_SETTINGS)
        if unknown:
            raise InputError(None, sorted(unknown)[0], f"not an inference setting ({', '.join(self.INFERENCE_SETTINGS)})")
        rank = int(settings.get("gap_rank", self.spec["gap_rank"]))
        if not 0 <= rank <= self.gap_basis.shape[1]:
            raise InputError(None, "gap_rank", f"must be 0 to the trained {self.gap_basis.shape[1]}, got {rank}")
        dropped = self.gap_basis[:, rank:]
        return LinearRefiner({**self.spec, **settings, "gap_rank": rank}, self.camera_ids, self.forward,
                             self.residual, self.gap_mean, self.gap_var + (dropped ** 2).sum(dim=1),
                             self.gap_basis[:, :rank], self.curvature)

    def tensors(self) -> dict[str, torch.Tensor]:
        return {"forward": self.forward.float(), "residual": self.residual.float(),
                "gap_mean": self.gap_mean.float(), "gap_var": self.gap_var.float(), "gap_basis": self.gap_basis.float(),
                "curvature": self.curvature.float()}
