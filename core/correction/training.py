"""One training step's MoGaFace part: pick the encoder views, regress ``Δψ``, keep the bank.

The trainer owns the Gaussians and the render; this object owns the MoGaFace modules, their
optimizer and the small view-image cache, and answers "which expression and which texture
offsets for this training image". Encoder inputs are other training views of the scored image's
timestamp: the scored view is left out in training as it is at evaluation (the paper's code
feeds it in; we do not, so training and inference see the same kind of input).
"""

from __future__ import annotations

import dataclasses

import torch

from .bank import consistency_loss, momentum_at
from .model import MoGaFace
from .rendered_targets import rendered_target_loss
from .views import ViewImages


@dataclasses.dataclass
class StepCorrection:
    """What the trainer needs from MoGaFace for one image."""

    expr_delta: torch.Tensor  # (n_expr,) differentiable
    consistency: torch.Tensor  # scalar
    centring: torch.Tensor  # scalar: the squared running mean of the corrections, this step's included
    inputs: list  # the encoder's frames
    row: int  # the timestamp's bank row
    slots: torch.Tensor | None  # the bank slots written (None without the bank)
    blended: torch.Tensor | None  # their new EMA values (None without the bank)
    rendered: torch.Tensor | None = None  # scalar: the self-supervised loss on renders, when on


def spec_from_settings(settings, n_expr: int) -> dict:
    """The model spec of a ``[mogaface]`` config section."""
    return {"mode": settings.mode, "bank": settings.bank, "texture": settings.texture,
            "input_size": settings.input_size, "feature_dim": settings.feature_dim,
            "encoder_width": settings.encoder_width, "heads": settings.heads, "hidden": settings.hidden,
            "plane_size": settings.plane_size, "plane_dim": settings.plane_dim,
            "texture_hidden": settings.texture_hidden, "n_expr": n_expr}


def centring_loss(running_mean: torch.Tensor, delta: torch.Tensor, decay: float) -> torch.Tensor:
    """The zero-mean prior: ``‖m'‖² / 2(1 − decay)`` with ``m' = decay·m + (1 − decay)·Δψ``.

    ``m'`` is the running mean as this step will leave it, so the push on ``Δψ`` is ``m'``:
    proportional to the shared offset and bounded below by zero. (A linear ``m · Δψ`` against a
    slow mean is unbounded below and, under Adam, oscillates with a growing amplitude.)
    """
    blended = decay * running_mean + (1.0 - decay) * delta
    return (blended * blended).sum() / (2.0 * (1.0 - decay))


class CorrectionTraining:
    """The MoGaFace modules under training on one capture's training frames."""

    def __init__(self, settings, frames, capture, timesteps: list[int], canonical_vertices: torch.Tensor,
                 n_expr: int, total_steps: int, seed: int = 0):
        self.settings = settings
        self.total_steps = total_steps
        self.by_timestep: dict[int, list] = {}
        for frame in frames:
            self.by_timestep.setdefault(frame.timestep_index, []).append(frame)
        cameras = sorted({f.camera_id for f in frames}, key=lambda c: min(f.camera_index for f in frames
                                                                          if f.camera_id == c))
        with torch.random.fork_rng(devices=[]):  # seeded initialisation, global RNG untouched
            torch.manual_seed(seed)
            self.model = MoGaFace(spec_from_settings(settings, n_expr), timesteps, cameras, canonical_vertices)
        self.views = ViewImages(capture, settings.input_size)
        self.optimizer = torch.optim.Adam(self.model.param_groups(settings), fused=True)

    def encoder_frames(self, frame, generator: torch.Generator) -> list:
        """Other training views of the frame's timestamp: one (single) or up to ``encoder_views`` (multi)."""
        others = [f for f in self.by_timestep[frame.timestep_index] if f.camera_id != frame.camera_id]
        if not others:
            others = [frame]  # a one-camera capture: nothing else to look at
        count = 1 if self.model.mode == "single" else min(self.settings.encoder_views, len(others))
        picks = torch.randperm(len(others), generator=generator)[:count].sort().values
        return [others[int(i)] for i in picks]

    def step(self, frame, tracked_expr: torch.Tensor, step: int, generator: torch.Generator) -> StepCorrection:
        model = self.model
        inputs = self.encoder_frames(frame, generator)
        images = self.views.batch(inputs)
        per_view, _ = model.correct(images, tracked_expr.detach())
        row = model.row[frame.timestep_index]
        zero = per_view.sum() * 0
        slots = blended = None
        if model.bank is None:
            delta, consistency = per_view.mean(0), zero
        else:
            bank = model.bank
            slots = torch.tensor([model.slot[f.camera_id] for f in inputs])
            consistency = consistency_loss(per_view, bank.mean(row)) if bank.has(row) else zero
            momentum = momentum_at(step, self.total_steps, self.settings.momentum_start, self.settings.momentum_end)
            blended = bank.blend(row, slots, per_view, momentum)
            delta = bank.mean_with(row, slots, blended)
        centring = centring_loss(model.correction_mean.detach().clone(), delta, self.settings.centring_decay)
        return StepCorrection(delta, consistency, centring, inputs, row, slots, blended)

    # -- what a step leaves behind (bank writes, running means) ----------------------------------
    def record_size(self) -> int:
        """Length of one view's :meth:`record`: row, slot mask, bank values, correction."""
        model = self.model
        views, n_expr = len(model.cameras), int(model.spec["n_expr"])
        return 1 + views + views * n_expr + n_expr

    def record(self, correction: StepCorrection) -> torch.Tensor:
        """One view's step outcome as a flat tensor, so ranks can sum the records of their views."""
        model = self.model
        views, n_expr = len(model.cameras), int(model.spec["n_expr"])
        mask = torch.zeros(views)
        values = torch.zeros(views, n_expr)
        if correction.slots is not None:
            mask[correction.slots] = 1.0
            values[correction.slots] = correction.blended.detach()
        return torch.cat([torch.tensor([float(correction.row)]), mask, values.reshape(-1),
                          correction.expr_delta.detach().reshape(-1)])

    @torch.no_grad()
    def commit(self, record: torch.Tensor) -> None:
        """Apply one view's record after the optimiser step: bank write, running correction."""
        model = self.model
        views, n_expr = len(model.cameras), int(model.spec["n_expr"])
        row = int(round(float(record[0])))
        mask = record[1:1 + views] > 0.5
        values = record[1 + views:1 + views + views * n_expr].view(views, n_expr)
        rest = record[1 + views + views * n_expr:]
        if model.bank is not None and mask.any():
            slots = torch.nonzero(mask)[:, 0]
            model.bank.store(row, slots, values[slots])
        model.observe_correction(rest[:n_expr], self.settings.centring_decay)

    def rendered_loss(self, avatar, params: dict, inputs: list, background, generator: torch.Generator):
        """The self-supervised correction loss on renders from the first ``rendered_views`` encoder cameras."""
        settings = self.settings
        cameras = [self.views.capture.camera(f) for f in inputs[:settings.rendered_views]]
        if self.model.mode == "single":
            cameras = cameras[:1]
        return rendered_target_loss(self.model, avatar, params, cameras, settings.input_size, background,
                                    settings.rendered_offset, generator)

    def optimizer_step(self) -> None:
        self.optimizer.step()
        self.optimizer.zero_grad(set_to_none=True)

    # -- after training -----------------------------------------------------------------------
    @torch.no_grad()
    @torch.no_grad()
    def timestep_correction(self, timestep: int, tracked_expr: torch.Tensor) -> torch.Tensor:
        """The final ``Δψ`` of a training timestamp, from its training views only.

        With the bank, ``Δψ`` is the bank's mean (what training posed the mesh with; no view is
        read); without it, the modules' regression over all the timestamp's training views.
        """
        model = self.model
        row = model.row[timestep]
        if model.bank is not None and model.bank.has(row):
            return model.bank.mean(row)
        frames = self.by_timestep[timestep]
        if model.mode == "single":  # one view per regression, averaged over every training view
            per_view = torch.cat([model.correct(self.views.batch([f]), tracked_expr)[0] for f in frames])
        else:
            per_view, _ = model.correct(self.views.batch(frames), tracked_expr)
        return per_view.mean(0)

    def state_dict(self) -> dict:
        return {"model": {k: v.detach().clone() for k, v in self.model.state_dict().items()},
                "optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        self.model.load_state_dict(state["model"])
        self.optimizer.load_state_dict(state["optimizer"])
