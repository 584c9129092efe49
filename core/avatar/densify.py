"""Adaptive density control for bound Gaussians, with binding inheritance.

A :class:`DensifyStrategy` holds the schedule (when to densify, prune, reset opacities and raise
the SH degree) and its state (per-Gaussian screen-gradient accumulators). Clones and splits
inherit their parent's triangle; pruning never removes the last Gaussian of a triangle, so every
face of the mesh stays covered (as GaussianAvatars). The optimizer's Adam moments follow every
row that is added (zeros) or removed.
"""

from __future__ import annotations

import dataclasses
import math

import torch

from .gaussians import PARAMETER_NAMES, BoundGaussians


@dataclasses.dataclass
class DensifySchedule:
    """When and how Gaussians are added, removed and reset. Steps count completed steps (1-based)."""

    start: int = 300
    stop: int = 2000
    interval: int = 150
    grad_threshold: float = 2e-4
    percent_dense: float = 0.01
    split_count: int = 2
    min_opacity: float = 0.005
    max_screen_size: float = 20.0
    max_world_size: float = 0.1
    opacity_reset_interval: int = 1200
    reset_opacity: float = 0.01
    max_gaussians: int = 60000
    sh_degree_interval: int = 400
    max_sh_degree: int = 3
    strategy: str = "adaptive"  # or "mcmc" (:mod:`.mcmc`)
    growth: float = 0.0  # 0: reach max_gaussians at the last pass
    noise: float = 0.1

    def densifies_at(self, step: int) -> bool:
        return self.start < step <= self.stop and step % self.interval == 0

    def resets_opacity_at(self, step: int) -> bool:
        every = self.opacity_reset_interval
        return every > 0 and step <= self.stop and step % every == 0

    def passes_between(self, done: int, now: int) -> list[int]:
        """The steps in ``(done, now]`` whose pass to run: the latest that densifies and the latest
        that resets opacities (one step apart: the step itself, if due). A time budget can move
        the schedule several steps at once; a second pass in a row would find no new statistics."""
        latest = set()
        for every, first in ((self.interval, self.start + 1), (self.opacity_reset_interval, 1)):
            step = min(now, self.stop) // every * every if every > 0 else 0
            if step > done and step >= first:
                latest.add(step)
        return sorted(latest)

    def sh_degree(self, step: int) -> int:
        """The active SH degree while running step ``step`` (0-based count of steps already done)."""
        return min(self.max_sh_degree, step // self.sh_degree_interval)


# -- row surgery on parameters and their Adam moments ---------------------------------------------

def quaternion_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """Unit wxyz quaternions ``(N,4)`` → rotation matrices ``(N,3,3)``."""
    q = q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).view(*q.shape[:-1], 3, 3)


def _group_of(optimizer: torch.optim.Optimizer | None, param: torch.Tensor):
    if optimizer is None:
        return None
    for group in optimizer.param_groups:
        if len(group["params"]) == 1 and group["params"][0] is param:
            return group
    return None


def edit_rows(gaussians: BoundGaussians, optimizer: torch.optim.Optimizer | None, keep: torch.Tensor | None,
              append: dict[str, torch.Tensor] | None) -> None:
    """Keep the rows ``keep`` (bool mask; None: all), then append ``append`` (one tensor per name,
    ``binding`` included). Each parameter is replaced by a new one; its Adam moments follow its rows
    and appended rows start at zero."""
    for name in ("binding", *PARAMETER_NAMES):
        old = getattr(gaussians, name)
        value = old.detach() if keep is None else old.detach()[keep]
        if append is not None:
            value = torch.cat([value, append[name].to(value.dtype)], dim=0)
        if name == "binding":
            gaussians.binding = value.clone()
            continue
        new = torch.nn.Parameter(value.clone())
        group = _group_of(optimizer, old)
        if group is not None:
            state = optimizer.state.pop(old, None)
            group["params"][0] = new
            if state:
                for key in ("exp_avg", "exp_avg_sq"):
                    moment = state[key] if keep is None else state[key][keep]
                    if append is not None:
                        moment = torch.cat([moment, moment.new_zeros((len(append[name]), *moment.shape[1:]))])
                    state[key] = moment.clone()
                optimizer.state[new] = state
        setattr(gaussians, name, new)


def reset_moments(optimizer: torch.optim.Optimizer | None, param: torch.Tensor,
                  rows: torch.Tensor | None = None) -> None:
    """Zero the Adam moments of ``param``, or of its rows ``rows`` (after their values were overwritten)."""
    state = optimizer.state.get(param) if optimizer is not None else None
    if state:
        for key in ("exp_avg", "exp_avg_sq"):
            if rows is None:
                state[key].zero_()
            else:
                state[key][rows] = 0.0


def keep_one_per_triangle(remove: torch.Tensor, binding: torch.Tensor, score: torch.Tensor,
                          n_faces: int) -> torch.Tensor:
    """``remove`` with, for every triangle it would empty, its highest-scoring Gaussian spared."""
    remove = remove.clone()
    kept_per_face = torch.zeros(n_faces, dtype=torch.long).index_add_(0, binding[~remove],
                                                                     torch.ones(int((~remove).sum()), dtype=torch.long))
    emptied = (kept_per_face == 0) & (torch.zeros(n_faces, dtype=torch.bool).index_fill_(0, binding, True))
    candidates = remove & emptied[binding]
    if candidates.any():
        index = torch.nonzero(candidates)[:, 0]
        faces = binding[index]
        # Highest score first, then a stable sort by face: the first row of each face wins.
        order = torch.argsort(score[index], descending=True, stable=True)
        order = order[torch.argsort(faces[order], stable=True)]
        faces_sorted = faces[order]
        first = torch.ones_like(faces_sorted, dtype=torch.bool)
        first[1:] = faces_sorted[1:] != faces_sorted[:-1]
        remove[index[order[first]]] = False
    return remove


class DensifyStrategy:
    """The densify/prune/reset schedule and the screen-gradient statistics it decides with."""

    def __init__(self, schedule: DensifySchedule, n_gaussians: int, n_faces: int):
        self.schedule = schedule
        self.n_faces = n_faces
        self.grad_accum = torch.zeros(n_gaussians)
        self.grad_count = torch.zeros(n_gaussians)
        self.max_radii = torch.zeros(n_gaussians)
        self.resets_done = 0

    # -- state ----------------------------------------------------------------------------------
    def state_dict(self) -> dict:
        return {"grad_accum": self.grad_accum.clone(), "grad_count": self.grad_count.clone(),
                "max_radii": self.max_radii.clone(), "resets_done": self.resets_done}

    def load_state_dict(self, state: dict) -> None:
        self.grad_accum = state["grad_accum"].clone()
        self.grad_count = state["grad_count"].clone()
        self.max_radii = state["max_radii"].clone()
        self.resets_done = int(state["resets_done"])

    def _reset_statistics(self, n: int) -> None:
        self.grad_accum = torch.zeros(n)
        self.grad_count = torch.zeros(n)
        self.max_radii = torch.zeros(n)

    # -- per step -------------------------------------------------------------------------------
    def observe(self, step: int, means2d_grad: torch.Tensor | None, radii: torch.Tensor, width: int,
                height: int) -> None:
        """Accumulate one view's screen-space gradient norms (3DGS's NDC units) of visible Gaussians."""
        if step > self.schedule.stop or means2d_grad is None:
            return
        # Whole-array updates (adding exact zeros off the visible set): no gathers and scatters.
        visible = radii > 0
        norms = (means2d_grad * torch.tensor([0.5 * width, 0.5 * height])).norm(dim=-1)
        self.grad_accum += torch.where(visible, norms, 0.0)
        self.grad_count += visible
        self.max_radii = torch.maximum(self.max_radii, torch.where(visible, radii.float(), 0.0))

    def perturb(self, gaussians: BoundGaussians, rate_share: float, generator: torch.Generator) -> None:
        """After each optimiser step: nothing here (the MCMC strategy moves faint Gaussians)."""

    def after_step(self, step: int, gaussians: BoundGaussians, optimizer, face_scale: torch.Tensor,
                   extent: float, generator: torch.Generator) -> dict:
        """Run what the schedule says for completed step ``step``; returns what was done."""
        report = {}
        s = self.schedule
        if s.densifies_at(step):
            report.update(self.densify_and_prune(gaussians, optimizer, face_scale, extent, generator,
                                                 prune_screen=self.resets_done > 0))
        if s.resets_opacity_at(step):
            self.reset_opacity(gaussians, optimizer)
            report["opacity_reset"] = True
        return report

    # -- the operations -------------------------------------------------------------------------
    def world_size(self, gaussians: BoundGaussians, face_scale: torch.Tensor) -> torch.Tensor:
        """Largest world-space axis of each Gaussian on a mesh with triangle scales ``face_scale``."""
        return torch.exp(gaussians.local_log_scale.detach()).amax(-1) * face_scale[gaussians.binding]

    def densify_and_prune(self, gaussians: BoundGaussians, optimizer, face_scale: torch.Tensor, extent: float,
                          generator: torch.Generator, prune_screen: bool = True) -> dict:
        s = self.schedule
        n = len(gaussians)
        grads = self.grad_accum / self.grad_count.clamp_min(1)
        size = self.world_size(gaussians, face_scale)
        selected = grads >= s.grad_threshold
        room = max(s.max_gaussians - n, 0)
        small = size <= s.percent_dense * extent
        clone = selected & small
        split = selected & ~small
        # Within the budget, the Gaussians with the largest gradients go first.
        cost = clone.long() + split.long() * (s.split_count - 1)
        if int(cost.sum()) > room:
            order = torch.argsort(torch.where(selected, grads, torch.full_like(grads, -1.0)), descending=True,
                                  stable=True)
            within = torch.cumsum(cost[order], 0) <= room
            allowed = torch.zeros(n, dtype=torch.bool)
            allowed[order[within]] = True
            clone &= allowed
            split &= allowed
        n_clone, n_split = int(clone.sum()), int(split.sum())
        appended = self._clones(gaussians, clone)
        splits = self._splits(gaussians, split, generator)
        for name in appended:
            appended[name] = torch.cat([appended[name], splits[name]])
        if n_clone or n_split:
            edit_rows(gaussians, optimizer, None, appended)
        # Prune: split parents, faint Gaussians, huge ones; never a triangle's last Gaussian.
        total = len(gaussians)
        remove = torch.zeros(total, dtype=torch.bool)
        remove[:n] = split
        opacity = torch.sigmoid(gaussians.opacity_logit.detach())
        remove |= opacity < s.min_opacity
        remove |= self.world_size(gaussians, face_scale) > s.max_world_size * extent
        if prune_screen:
            radii = torch.cat([self.max_radii, torch.zeros(total - n)])
            remove |= radii > s.max_screen_size
        remove = keep_one_per_triangle(remove, gaussians.binding, opacity, self.n_faces)
        n_removed = int(remove.sum())
        if n_removed:
            edit_rows(gaussians, optimizer, ~remove, None)
        self._reset_statistics(len(gaussians))
        return {"cloned": n_clone, "split": n_split, "pruned": n_removed - n_split, "gaussians": len(gaussians)}

    def _clones(self, gaussians: BoundGaussians, mask: torch.Tensor) -> dict[str, torch.Tensor]:
        return {name: t.detach()[mask].clone() for name, t in gaussians.tensors().items()}

    def _splits(self, gaussians: BoundGaussians, mask: torch.Tensor, generator: torch.Generator):
        """``split_count`` children per selected Gaussian, sampled from it in its triangle's space."""
        k = self.schedule.split_count
        rows = {name: t.detach()[mask].repeat_interleave(k, dim=0) for name, t in gaussians.tensors().items()}
        stds = torch.exp(rows["local_log_scale"])
        samples = torch.randn(stds.shape, generator=generator) * stds
        rotation = quaternion_to_matrix(rows["local_rotation"])
        rows["local_position"] = rows["local_position"] + (rotation @ samples[..., None])[..., 0]
        rows["local_log_scale"] = rows["local_log_scale"] - math.log(0.8 * k)
        return rows

    def reset_opacity(self, gaussians: BoundGaussians, optimizer) -> None:
        """Clamp every opacity to ``reset_opacity`` and forget its Adam moments."""
        ceiling = math.log(self.schedule.reset_opacity / (1 - self.schedule.reset_opacity))
        with torch.no_grad():
            gaussians.opacity_logit.clamp_(max=ceiling)
        reset_moments(optimizer, gaussians.opacity_logit)
        self.resets_done += 1
