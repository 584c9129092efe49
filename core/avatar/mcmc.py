"""A fixed Gaussian budget as the densification strategy (3DGS as Markov chain Monte Carlo).

Instead of cloning and splitting where the screen gradient is large, :class:`MCMCStrategy` keeps
the Gaussians as samples of where the picture needs them: every ``interval`` steps it moves the
dead ones (opacity at most ``min_opacity``) onto live ones drawn in proportion to their opacity,
then adds ``growth`` − 1 more of them the same way until ``max_gaussians`` (by default at the
growth that reaches it at the schedule's last pass). A Gaussian that gets
``n − 1`` copies becomes ``n`` stacked ones that render what it did (:func:`stacked_equivalent`).
Between passes, nearly transparent Gaussians wander (:meth:`MCMCStrategy.perturb`), so a dead
one explores before it is moved. There are no opacity resets. As with clone-and-split, a copy
inherits its parent's triangle and a triangle's last Gaussian is never taken away.

As gsplat's ``MCMCStrategy`` (after Kheradmand et al., 2024), with the noise in the Gaussian's own
frame: positions are in triangle units here, so a noise of world covariance times a rate would
depend on the triangle's size.
"""

from __future__ import annotations

import math

import torch

from .densify import DensifyStrategy, edit_rows, keep_one_per_triangle, quaternion_to_matrix, reset_moments
from .gaussians import BoundGaussians

MAX_COPIES = 51  # a Gaussian drawn more often in one pass becomes at most this many


def stacked_equivalent(opacity: torch.Tensor, count: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The opacity and the scale factor of each of ``count`` stacked copies of a Gaussian of
    opacity ``opacity`` so that together they render what it did.

    At the centre ``1 − (1 − o')ⁿ = o``. Over the footprint, the copies' alpha
    ``1 − (1 − o'g)ⁿ = Σⱼ C(n, j) (−1)^{j−1} o'^j g^j``, and ``g^j`` is ``g`` narrowed by ``√j``:
    the scale factor makes its integral the parent's ``o ∫g`` (the MCMC paper's Eq. 9, its double
    sum folded by the hockey-stick identity). Computed in float64: the sum alternates.
    """
    n = count.to(torch.float64).clamp(1, MAX_COPIES)
    o = opacity.to(torch.float64)
    o_new = 1.0 - (1.0 - o) ** (1.0 / n)
    j = torch.arange(1, MAX_COPIES + 1, dtype=torch.float64)
    log_binomial = torch.lgamma(n[:, None] + 1) - torch.lgamma(j + 1) - torch.lgamma((n[:, None] - j + 1).clamp_min(1))
    terms = torch.exp(log_binomial) * o_new[:, None] ** j / j.sqrt() * torch.where(j % 2 == 1, 1.0, -1.0)
    denominator = torch.where(j <= n[:, None], terms, 0.0).sum(-1)
    return o_new.to(opacity.dtype), (o / denominator).to(opacity.dtype)


class MCMCStrategy(DensifyStrategy):
    """Relocate dead Gaussians and grow toward ``max_gaussians`` (see the module)."""

    def observe(self, step, means2d_grad, radii, width, height) -> None:
        """Nothing to gather: the passes decide by opacity alone."""

    def after_step(self, step: int, gaussians: BoundGaussians, optimizer, face_scale: torch.Tensor,
                   extent: float, generator: torch.Generator) -> dict:
        if not self.schedule.densifies_at(step):
            return {}
        relocated = self.relocate(gaussians, optimizer, generator)
        added = self.grow(gaussians, optimizer, generator, self.growth_at(step, len(gaussians)))
        return {"relocated": relocated, "added": added, "gaussians": len(gaussians)}

    def growth_at(self, step: int, n: int) -> float:
        """The pass's growth factor: ``growth``, or with ``growth = 0`` the one that reaches
        ``max_gaussians`` at the schedule's last pass (the same factor every pass from here)."""
        s = self.schedule
        if s.growth:
            return s.growth
        passes_left = max(s.stop // s.interval - (step - 1) // s.interval, 1)  # this one included
        return max(s.max_gaussians / max(n, 1), 1.0) ** (1.0 / passes_left)

    def perturb(self, gaussians: BoundGaussians, rate_share: float, generator: torch.Generator) -> None:
        """Move each nearly transparent Gaussian by ``noise × rate_share`` of its own spread along
        its axes (``rate_share``: the position rate now over the first); opaque ones stay put. Every
        rank draws the same numbers from the shared ``generator``."""
        s = self.schedule
        if s.noise <= 0 or rate_share <= 0:
            return
        with torch.no_grad():
            opacity = torch.sigmoid(gaussians.opacity_logit)
            gate = torch.sigmoid(100.0 * (s.min_opacity - opacity))  # ½ at the dead line, < 1 % from +0.05 above it
            step = torch.randn(gaussians.local_position.shape, generator=generator) * torch.exp(gaussians.local_log_scale)
            step = (quaternion_to_matrix(gaussians.local_rotation) @ step[..., None])[..., 0]
            gaussians.local_position.add_(step * (s.noise * rate_share * gate)[:, None])

    # -- the passes -----------------------------------------------------------------------------
    def relocate(self, gaussians: BoundGaussians, optimizer, generator: torch.Generator) -> int:
        """Move every dead Gaussian (a triangle's last one spared) onto a live one; returns how many."""
        opacity = torch.sigmoid(gaussians.opacity_logit.detach())
        dead = keep_one_per_triangle(opacity <= self.schedule.min_opacity, gaussians.binding, opacity, self.n_faces)
        alive = torch.nonzero(~dead)[:, 0]
        n_dead = int(dead.sum())
        if n_dead == 0 or len(alive) == 0:
            return 0
        sources = alive[torch.multinomial(opacity[alive], n_dead, replacement=True, generator=generator)]
        edit_rows(gaussians, optimizer, ~dead, self._copies(gaussians, optimizer, sources))
        self._reset_statistics(len(gaussians))
        return n_dead

    def grow(self, gaussians: BoundGaussians, optimizer, generator: torch.Generator, growth: float) -> int:
        """Add copies of live Gaussians, ``growth`` times as many in all, up to the budget."""
        n = len(gaussians)
        n_new = min(self.schedule.max_gaussians, math.floor(growth * n + 1e-9)) - n
        if n_new <= 0:
            return 0
        opacity = torch.sigmoid(gaussians.opacity_logit.detach())
        sources = torch.multinomial(opacity, n_new, replacement=True, generator=generator)
        edit_rows(gaussians, optimizer, None, self._copies(gaussians, optimizer, sources))
        self._reset_statistics(len(gaussians))
        return n_new

    def _copies(self, gaussians: BoundGaussians, optimizer, sources: torch.Tensor) -> dict[str, torch.Tensor]:
        """Make each source Gaussian a stack with its copies (:func:`stacked_equivalent`), forget
        the sources' Adam moments, and return the copies' rows (``binding`` included)."""
        count = torch.bincount(sources, minlength=len(gaussians))[sources] + 1
        opacity = torch.sigmoid(gaussians.opacity_logit.detach()[sources])
        new_opacity, scale_factor = stacked_equivalent(opacity, count)
        new_opacity = new_opacity.clamp(self.schedule.min_opacity, 1.0 - 1e-6)
        with torch.no_grad():
            gaussians.opacity_logit[sources] = torch.logit(new_opacity)
            gaussians.local_log_scale[sources] += torch.log(scale_factor)[:, None]
        for param in (gaussians.opacity_logit, gaussians.local_log_scale):
            reset_moments(optimizer, param, sources)
        return {name: t.detach()[sources].clone() for name, t in gaussians.tensors().items()}
