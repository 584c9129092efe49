"""One training image of a step: posed, rendered and scored.

:class:`LossTerms` is the one list of a view's weighted loss terms (it makes the total and names
what every step logs, the same on every rank, one that renders no view of the step included);
:class:`ViewRenderer` poses the avatar for a frame (tracked or corrected expression, the camera's
delay and offset) and renders it; :class:`ViewResult` is what the step takes from the view.
"""

from __future__ import annotations

import dataclasses

import torch

from ..camera import Camera
from ..correction.avatar import render_world
from ..correction.training import CorrectionTraining, StepCorrection
from ..data.target import area_resized
from ..splat.api import SplatOutput
from .config import TrainConfig
from .correction_part import mogaface_render
from .losses import image_loss, opacity_mean, position_hinge, psnr, scaling_hinge, size_mean

IMAGE_TERMS = ("l1", "ssim", "rgb")  # ``rgb`` = (1 − λ)·l1 + λ·(1 − ssim): the image term of the total


class LossTerms:
    """The weighted terms added to a view's image loss ``rgb``: the position and scaling hinges, the
    mean opacity and size (where their weights are not zero), with camera colours their penalty, and
    with the MoGaFace modules the correction's consistency, centring and rendered losses (those whose
    weight is not zero: consistency always)."""

    def __init__(self, config: TrainConfig, mogaface: bool):
        self.weights = {"position": config.loss.position_weight, "scaling": config.loss.scaling_weight}
        for name in ("opacity", "size"):
            if getattr(config.loss, f"{name}_weight"):
                self.weights[name] = getattr(config.loss, f"{name}_weight")
        if config.cameras.colour:
            self.weights["colour"] = config.cameras.colour_weight
        if mogaface:
            settings = config.mogaface
            self.weights["consistency"] = settings.consistency_weight
            for name in ("centring", "rendered"):
                if getattr(settings, f"{name}_weight"):
                    self.weights[name] = getattr(settings, f"{name}_weight")
        self.names = [*IMAGE_TERMS, *self.weights, "loss", "psnr"]  # what a step reports, in this order

    def total(self, losses: dict[str, torch.Tensor]) -> torch.Tensor:
        """``rgb`` plus each weighted term, added in the order of :attr:`weights`."""
        total = losses["rgb"]
        for name, weight in self.weights.items():
            total = total + weight * losses[name]
        return total


@dataclasses.dataclass
class ViewResult:
    """One scored training image: its camera, target and render, its losses by name (``loss``: the
    weighted total the step backpropagates) and the step's MoGaFace correction (or None)."""

    camera: Camera
    target: torch.Tensor
    render: SplatOutput
    losses: dict[str, torch.Tensor]
    correction: StepCorrection | None = None

    def logged(self) -> dict[str, float]:
        """The losses as numbers, and the render's PSNR."""
        values = {name: float(value.detach()) for name, value in self.losses.items()}
        values["psnr"] = psnr(self.render.rgb, self.target)
        return values

    def observe(self, strategy, step: int, batch: int) -> None:
        """Give densification this view's screen gradient and radii (after ``backward``). The batch
        mean divides each view's gradient by ``batch``; the view's own is what it counts, as gsplat."""
        grad = self.render.means2d.grad
        strategy.observe(step, None if grad is None else grad * batch, self.render.radii,
                         self.camera.width, self.camera.height)


class ViewRenderer:
    """Renders and scores training images of one run's capture.

    Holds the meshes of the timesteps: for good when the FLAME parameters are fixed, for one step
    when they are fine-tuned (each timestep posed once per step, shared by its views; call
    :meth:`step_done` after the step's ``backward``). With camera colours, a render is recoloured
    by its camera's map before it is scored.
    """

    def __init__(self, config: TrainConfig, data, avatar, table, background: torch.Tensor,
                 camera_offsets=None, camera_delays=None, mogaface: CorrectionTraining | None = None,
                 camera_colours=None):
        self.config = config
        self.data = data
        self.avatar = avatar
        self.table = table
        self.background = background
        self.camera_offsets = camera_offsets
        self.camera_delays = camera_delays
        self.mogaface = mogaface
        self.camera_colours = camera_colours
        self.terms = LossTerms(config, mogaface is not None)
        self._posed_cache: dict[int, torch.Tensor] = {}
        self._step_posed: dict[int, torch.Tensor] = {}

    def posed_vertices(self, timestep: int) -> torch.Tensor:
        """The mesh of a timestep; cached when the FLAME parameters are fixed."""
        if self.config.flame.finetune:
            vertices = self._step_posed.get(timestep)
            if vertices is None:
                vertices = self._step_posed[timestep] = self.avatar.posed_vertices(self.table.params(timestep))
            return vertices
        vertices = self._posed_cache.get(timestep)
        if vertices is None:
            with torch.no_grad():
                vertices = self.avatar.posed_vertices(self.table.params(timestep))
            self._posed_cache[timestep] = vertices
        return vertices

    def step_done(self) -> None:
        """The step's meshes (and their graphs) are spent."""
        self._step_posed.clear()

    def render(self, frame, step: int, generator: torch.Generator, scale: float = 1.0) -> ViewResult:
        """Render training image ``frame`` at ``step`` and score it (``generator``: the view's random
        source, for the encoder's views and the rendered targets), both at ``scale`` of the image's
        size (progressive resolution; the target area-averaged)."""
        camera = self.data.capture.camera(frame)
        target = self.data.target(frame)
        if scale < 1.0:
            camera = camera.scaled(scale)
            target = area_resized(target, camera.width, camera.height)
        offsets = self.camera_offsets
        move = None if offsets is None else (lambda world: offsets.move_scene(world, frame.camera_id, camera.center))
        shift = None if self.camera_delays is None else self.camera_delays.shift(
            frame.camera_id, frame.timestep_index, self.posed_vertices)
        correction = None
        if self.mogaface is None:
            vertices = self.posed_vertices(frame.timestep_index)
            if shift is not None:
                vertices = vertices + shift
            if move is None:
                render = self.avatar.render_posed(vertices, camera, self.background)
            else:
                world = self.avatar.gaussians.world(vertices, self.avatar.flame.faces)
                render = render_world(move(world), camera, self.background)
        else:
            _, render, correction = mogaface_render(self.mogaface, self.avatar, self.table, frame, camera,
                                                    self.background, step, generator, move, shift)
        colours = self.camera_colours
        if colours is not None:  # the camera's colours, over the background as it is
            render = dataclasses.replace(render, rgb=colours.apply(frame.camera_id, render.rgb, render.alpha,
                                                                   self.background))
        losses = self.score(render, target, correction, frame.camera_id)
        return ViewResult(camera, target, render, losses, correction)

    def score(self, render: SplatOutput, target: torch.Tensor, correction: StepCorrection | None,
              camera_id: str | None = None) -> dict:
        """The view's losses by name: the image terms, the weighted terms, ``loss`` (their total)."""
        settings = self.config.loss
        gaussians = self.avatar.gaussians
        losses = image_loss(render.rgb, target, settings.ssim_weight)
        losses["position"] = position_hinge(gaussians.local_position, settings.position_threshold, render.visible)
        losses["scaling"] = scaling_hinge(gaussians.local_log_scale, settings.scaling_threshold, render.visible)
        if "opacity" in self.terms.weights:
            losses["opacity"] = opacity_mean(gaussians.opacity_logit)
        if "size" in self.terms.weights:
            losses["size"] = size_mean(gaussians.local_log_scale)
        if self.camera_colours is not None:
            losses["colour"] = self.camera_colours.penalty(camera_id)
        for name in self.terms.weights:
            if name not in losses:  # the correction's terms
                losses[name] = getattr(correction, name)
        losses["loss"] = self.terms.total(losses)
        return losses
