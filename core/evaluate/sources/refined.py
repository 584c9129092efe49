"""The multi-view refiner's parameters (``RUN/refiner.pt``): the frozen avatar renders the frame
at the base source's parameters, the refiner compares those renders with the other views of the
timestep (the scored view left out) and regresses an offset; ``passes`` times, re-rendering between.
:class:`RefinerInference` is what a run's refiner gives a user: the refiner, then fitting where
training did not fit.

Every set of views it looks at is recorded in :attr:`inputs` (scored camera, cameras seen).
"""

from __future__ import annotations

import numpy as np

from ...data.capture import Capture, Frame
from ...data.target import target_image
from ...refiner.inference import refine
from ...run.cameras import InputCameras
from .base import INPUT_VIEWS, ImageAssistedSource, ParamSource, timestep_of
from .fitted import FittedParams
from .tracked import AlignedTrackedParams


class RefinedParams(ImageAssistedSource):
    """``base``'s parameters refined by the run's refiner from ``max_views`` other views of the
    timestep from ``input_cameras`` (ids; None: any), spread over the rig (:func:`.base.input_views`)."""

    def __init__(self, avatar, capture: Capture, base: ParamSource, refiner, background, passes: int = 1,
                 max_views: int = INPUT_VIEWS, cameras: InputCameras | None = None, input_cameras=None):
        super().__init__(avatar, capture, base, background, passes, max_views, cameras, input_cameras)
        self.refiner = refiner
        self.passes = passes
        self.max_views = max_views
        self.description = (f"multi-view refiner ({passes} pass{'es' if passes > 1 else ''}, "
                            f"{max_views} other views; scored view left out)")

    def improve(self, start: dict[str, np.ndarray], frames: list[Frame], timestep: int) -> dict[str, np.ndarray]:
        images = [target_image(self.capture, f, self.background, self.recorded) for f in frames]
        cameras = [self.cameras(f) for f in frames]
        return refine(self.avatar, self.refiner, start, cameras, images, self.background, self.passes)[-1]


class RefinerInference:
    """A run's refiner as ``refine-tracking``, Blender's Improve Tracking and ``eval`` use it:
    ``passes`` refiner passes from :class:`AlignedTrackedParams` on every timestep, then, when
    asked, ``fit_steps`` of test-time fitting from the refiner's answer on the timesteps whose
    parameters training did not fit (the unseen ones; every timestep of a run that kept the tracking),
    to every other view of ``input_cameras`` (ids; None: any).

    No fitting by default: since a pass ends with full-size steps, fitting after it lowered the
    self-reenactment PSNR and moved the pose away
    (docs/notebook/2026-11-26-multiview-refiner.md, "A pass that ends at full size").
    Never on training timesteps: a fine-tuned run fitted them to every view already, and fitting
    from there moved them off ("Fitting at full size").
    """

    uses_images = True

    def __init__(self, avatar, capture: Capture, run, refiner, passes: int = 1, views: int = INPUT_VIEWS,
                 fit_steps: int = 0, cameras: InputCameras | None = None, input_cameras=None):
        self.start = AlignedTrackedParams(capture, run)
        self.refined = RefinedParams(avatar, capture, self.start, refiner, run.background, passes=passes,
                                     max_views=views, cameras=cameras, input_cameras=input_cameras)
        self.fitted = (FittedParams(avatar, capture, self.refined, fit_steps, run.background, cameras=cameras,
                                    input_cameras=input_cameras) if fit_steps else None)
        self.fitted_by_training = set(run.trained_timesteps) if self.start.offset else set()
        self.inputs: list[tuple[str | None, list[str]]] = []
        self.description = self.refined.description + (
            f", then {fit_steps} fitting steps on the timesteps training did not fit" if fit_steps else "")

    def fits(self, timestep: int) -> bool:
        """Whether ``timestep`` gets test-time fitting after the refiner."""
        return self.fitted is not None and timestep not in self.fitted_by_training

    def params_for(self, frame: Frame | int, exclude_view: str | None = None) -> dict[str, np.ndarray]:
        source = self.fitted if self.fits(timestep_of(frame)) else self.refined
        seen = len(source.inputs)
        params = source.params_for(frame, exclude_view)
        self.inputs.extend(source.inputs[seen:])
        return params


def run_refiner(run_root, avatar):
    """The run's refiner, or None when it has none (``RUN/refiner.pt``)."""
    from ...refiner.files import REFINER_FILE, load_refiner

    path = run_root / REFINER_FILE
    return load_refiner(path, avatar.flame.n_expr)[0] if path.exists() else None
