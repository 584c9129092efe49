"""Test-time fitting: the frozen trained avatar, Adam on one frame's expression and pose against
the other views of its timestep (the scored view left out). The baseline an image-driven
correction has to beat: it uses the same images, at the cost of optimisation per frame.
"""

from __future__ import annotations

import contextlib

import numpy as np
import torch

from ...data.capture import Capture, Frame
from ...data.target import area_resized, target_image
from ...run.cameras import InputCameras
from .base import ImageAssistedSource, ParamSource

# The width of the prior toward the start per parameter (make-capture's default tracker error for
# the expression, twice it for rotations and translation), and the scale of the Adam step sizes,
# which start at a fifth of it and decay to zero over the fit (cosine). Constant rates of a tenth
# kept walking away from a start that was already right (docs/notebook/2026-11-23-parameter-sources.md).
# The step sizes and the prior's weight as chosen on validation frames by ``bench refiner_search``
# (docs/notebook/2026-11-27-validation-and-unseen-subjects.md).
PRIOR_SIGMA = {"expr": 0.5, "rotation": 0.02, "neck_pose": 0.02, "jaw_pose": 0.02, "eyes_pose": 0.02,
               "translation": 2e-3}
RATES = {k: v / 5 for k, v in PRIOR_SIGMA.items()}
PRIOR_WEIGHT = 1e-4
# Renders at the views' full size: at half size the avatar (trained at full size) renders what a
# downsampled capture does not show, and fitting read the expression worse than it started
# (docs/notebook/2026-11-26-multiview-refiner.md, "Fitting at full size").
SCALE = 1.0


def fitting_settings() -> dict:
    """The defaults that decide what fitting returns: scores kept with other settings are stale."""
    return {"rates": RATES, "prior_sigma": PRIOR_SIGMA, "prior_weight": PRIOR_WEIGHT, "decay": "cosine",
            "scale": SCALE}


@contextlib.contextmanager
def frozen(*modules):
    """No gradient to any weight of ``modules`` while fitting (restored afterwards)."""
    params = [p for m in modules if hasattr(m, "parameters") for p in m.parameters()]
    flags = [p.requires_grad for p in params]
    for p in params:
        p.requires_grad_(False)
    try:
        yield
    finally:
        for p, flag in zip(params, flags):
            p.requires_grad_(flag)


class FittedParams(ImageAssistedSource):
    """``base``'s parameters (image-free) refined by ``steps`` Adam steps of the L1 photometric
    error on ``views_per_step`` of the other views per step, rendered at ``scale`` of their size.

    The views fitted to: the other views of the timestep from ``input_cameras`` (ids; None: any),
    ``views`` of them spread over the rig (None: all), chosen as the refiner chooses its own
    (:func:`.base.input_views`). Every set of views it fits to is recorded in :attr:`inputs`
    (scored camera, cameras seen).
    """

    def __init__(self, avatar, capture: Capture, base: ParamSource, steps: int, background,
                 views_per_step: int = 2, scale: float = SCALE, rates: dict[str, float] | None = None,
                 prior_weight: float = PRIOR_WEIGHT, decay: bool = True, cameras: InputCameras | None = None,
                 views: int | None = None, input_cameras=None):
        super().__init__(avatar, capture, base, background, steps, views, cameras, input_cameras)
        self.steps = steps
        self.views_per_step = views_per_step
        self.scale = scale
        self.rates = dict(RATES if rates is None else rates)
        self.prior_weight = float(prior_weight)
        self.decay = decay
        self.views = views
        among = "other views" if views is None else f"of {views} other views"
        self.description = (f"test-time fitting ({steps} Adam steps on expression and pose, "
                            f"{views_per_step} {among} per step at {scale:g}× size; scored view left out)")

    def improve(self, start: dict[str, np.ndarray], frames: list[Frame], timestep: int) -> dict[str, np.ndarray]:
        return {**start, **self._fit(start, frames, timestep)}

    def _fit(self, start: dict[str, np.ndarray], frames: list[Frame], timestep: int) -> dict[str, np.ndarray]:
        views = []
        for f in frames:
            camera = self.cameras(f).scaled(self.scale)
            image = target_image(self.capture, f, self.background, self.recorded)
            views.append((camera, area_resized(torch.tensor(np.asarray(image, np.float32)), camera.width,
                                               camera.height)))
        free = {k: torch.tensor(np.asarray(start[k], np.float32))[None].requires_grad_(True)
                for k in self.rates if k in start}
        fixed = {k: torch.as_tensor(np.asarray(v, np.float32))[None] for k, v in start.items() if k not in free}
        anchor = {k: v.detach().clone() for k, v in free.items()}
        optimiser = torch.optim.Adam([{"params": [v], "lr": self.rates[k]} for k, v in free.items()])
        order = np.random.default_rng(timestep).permutation(len(views))
        cursor = 0
        model = getattr(self.avatar, "model", None)
        with frozen(self.avatar, model), torch.enable_grad():
            for step in range(self.steps):
                if self.decay:  # cosine to zero: the last steps settle instead of jumping by a full rate
                    for group, key in zip(optimiser.param_groups, free):
                        group["lr"] = self.rates[key] * 0.5 * (1 + np.cos(np.pi * step / self.steps))
                picks = [order[(cursor + i) % len(views)] for i in range(min(self.views_per_step, len(views)))]
                cursor += len(picks)
                params = {**fixed, **free}
                loss = sum((self.avatar.render(params, views[i][0], self.background).rgb - views[i][1]).abs().mean()
                           for i in picks) / len(picks)
                if self.prior_weight > 0:  # the start is the tracker's estimate: stay near it where images say little
                    loss = loss + self.prior_weight * sum(
                        (((v - anchor[k]) / PRIOR_SIGMA[k]) ** 2).mean() for k, v in free.items())
                optimiser.zero_grad()
                loss.backward()
                optimiser.step()
        return {k: v.detach()[0].numpy().astype(np.float32) for k, v in free.items()}
