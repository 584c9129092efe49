"""The momentum-updated expression bank: one entry per timestamp holding every view's correction.

``values (T, V, n_expr)`` is updated by an exponential moving average
``bank ← m·bank + (1 − m)·Δψ_i`` whose momentum ``m`` falls linearly from ``momentum_start`` to
``momentum_end`` over training. The mean over the written views of a timestamp is the expression
adjustment that poses its mesh, so every view of a timestamp shares one mesh; the same mean is
the target of the per-view consistency loss.
"""

from __future__ import annotations

import torch
from torch import nn

from ..errors import InputError


def momentum_at(step: int, total_steps: int, start: float, end: float) -> float:
    """Linear decay of the momentum from ``start`` (step 0) to ``end`` (last step), clamped."""
    t = min(max(step / max(total_steps, 1), 0.0), 1.0)
    return start + (end - start) * t


class ExpressionBank(nn.Module):
    """Per-timestamp, per-view expression corrections with EMA updates (buffers: saved with the model)."""

    def __init__(self, timesteps: int, views: int, n_expr: int):
        super().__init__()
        self.register_buffer("values", torch.zeros(timesteps, views, n_expr))
        self.register_buffer("written", torch.zeros(timesteps, views, dtype=torch.bool))

    def blend(self, row: int, slots: torch.Tensor, corrections: torch.Tensor, momentum: float) -> torch.Tensor:
        """The EMA values of ``slots`` after an update with ``corrections`` (differentiable in them).

        A slot never written before takes the correction as it is (no pull towards zero).
        """
        if not 0.0 <= momentum < 1.0:
            raise InputError(None, "mogaface.bank_momentum", f"momentum must lie in [0, 1), got {momentum}")
        old = self.values[row, slots]
        m = torch.where(self.written[row, slots], momentum, 0.0)[:, None]
        return m * old + (1.0 - m) * corrections

    def mean_with(self, row: int, slots: torch.Tensor, blended: torch.Tensor) -> torch.Tensor:
        """Mean over the timestamp's written views, with ``slots`` replaced by ``blended`` values."""
        values = self.values[row].clone()
        written = self.written[row].clone()
        values = values.index_put((slots,), blended)
        written[slots] = True
        weights = written.float()
        return (values * weights[:, None]).sum(0) / weights.sum().clamp(min=1.0)

    @torch.no_grad()
    def store(self, row: int, slots: torch.Tensor, blended: torch.Tensor) -> None:
        """Commit the blended values of one update."""
        self.values[row, slots] = blended.detach()
        self.written[row, slots] = True

    def update(self, row: int, slots: torch.Tensor, corrections: torch.Tensor, momentum: float) -> torch.Tensor:
        """EMA-update ``slots`` of timestamp ``row``; returns the new values."""
        blended = self.blend(row, slots, corrections.detach(), momentum)
        self.store(row, slots, blended)
        return blended

    def mean(self, row: int | None = None) -> torch.Tensor:
        """Mean correction over written views: ``(n_expr,)`` for one row, ``(T, n_expr)`` for all."""
        values = self.values if row is None else self.values[row]
        weights = (self.written if row is None else self.written[row]).float()
        return (values * weights[..., None]).sum(-2) / weights.sum(-1, keepdim=True).clamp(min=1.0)

    def has(self, row: int) -> bool:
        return bool(self.written[row].any())


def consistency_loss(corrections: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean squared distance of per-view corrections ``(V, n)`` from the bank's consensus ``(n,)``."""
    return ((corrections - target.detach()[None]) ** 2).mean()
