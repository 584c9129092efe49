"""The method's own parameter source (a MoGaFace run): parameter-driven and image-assisted inference.

- training timestamps (novel view): the run's ``flame_param/`` already holds the corrected
  expressions (the bank's mean, built from training views only);
- other timestamps (self-reenactment), **parameter-driven**: the tracked parameters, no image;
- other timestamps, **image-assisted**: the encoder looks at the *other* views of that timestamp
  (:func:`views_at` with the scored view excluded) and regresses ``Δψ``.

The texture attention reads the parameters given here (as it reads any source's), so nothing else
passes from this source to the render.

The scored view is never an encoder input: every encoder call is recorded in :attr:`inputs`
(scored camera, cameras seen), so tests can check it.
"""

from __future__ import annotations

import numpy as np
import torch

from ...correction.model import MoGaFace
from ...correction.views import ViewImages
from ...data.capture import Capture, Frame
from ...run.folder import RunFolder
from .base import timestep_of, views_at
from .tracked import TrackedParams


class MoGaFaceParams:
    """FLAME parameters of one frame for a MoGaFace run."""

    def __init__(self, capture: Capture, run: RunFolder, model: MoGaFace, image_assisted: bool = True,
                 max_views: int = 16, flame=None):
        self.capture = capture
        self.model = model
        self.tracked = TrackedParams(capture, run, flame)
        self.image_assisted = image_assisted and model.mode != "off"
        self.uses_images = self.image_assisted
        self.max_views = max_views
        self.views = ViewImages(capture, model.spec["input_size"])
        self.inputs: list[tuple[str | None, list[str]]] = []
        self.description = ("image-assisted (MoGaFace: other views of the timestamp, scored view left out)"
                            if self.image_assisted else "parameter-driven (MoGaFace: tracked parameters, no image)")

    def params_for(self, frame: Frame | int, exclude_view: str | None = None) -> dict[str, np.ndarray]:
        timestep = timestep_of(frame)
        params = dict(self.tracked.params_for(timestep))
        if self.model.row.get(timestep) is None and self.image_assisted:
            frames = views_at(self.capture, timestep, exclude_view)[: self.max_views]
            if frames:
                delta = self._regress(frames, params["expr"])
                params["expr"] = (params["expr"] + delta.numpy()).astype(np.float32)
                self.inputs.append((exclude_view, [f.camera_id for f in frames]))
        return params

    @torch.no_grad()
    def _regress(self, frames: list[Frame], expr: np.ndarray) -> torch.Tensor:
        """The mean over the views of their regressed ``Δψ`` (the bank's rule for unseen frames)."""
        tracked = torch.as_tensor(expr, dtype=torch.float32)
        if self.model.mode == "single":
            return torch.cat([self.model.correct(self.views.batch([f]), tracked)[0] for f in frames]).mean(0)
        return self.model.correct(self.views.batch(frames), tracked)[0].mean(0)


def run_inference(run: RunFolder, capture: Capture, image_assisted: bool = True):
    """``(avatar, source)`` of a MoGaFace run (``RUN/mogaface.pt``), or ``(None, None)`` for a plain run."""
    if not run.has_modules():
        return None, None
    avatar = run.load_avatar()
    return avatar, MoGaFaceParams(capture, run, avatar.model, image_assisted=image_assisted, flame=avatar.flame)
