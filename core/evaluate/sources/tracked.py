"""Parameter-driven inference: the tracker's parameters, no image; and the same moved by the
run's mean fine-tuning offset, the start of every image-assisted source."""

from __future__ import annotations

import numpy as np

from ...data.capture import Capture, Frame
from ...run.folder import MOTION_KEYS, RunFolder
from .base import timestep_of


class TrackedParams:
    """The run's own parameters for training timesteps, the capture's tracked ones (with the
    run's identity: shape, static offset) for the rest.

    Looks at no image, so ``exclude_view`` is satisfied trivially. ``flame``: the head model the
    parameters pose, when known; a file with more coefficients than it has is refused, named.
    """

    uses_images = False
    description = "parameter-driven (tracked FLAME parameters; no image input)"

    def __init__(self, capture: Capture, run: RunFolder | None = None, flame=None):
        self.capture = capture
        self.run = run
        self.flame = flame
        self._identity = run.identity_params() if run is not None else None
        if self._identity and flame is not None:
            flame.check_counts(self._identity, run.flame_param_file(run.trained_timesteps[0]))

    def params_for(self, frame: Frame | int, exclude_view: str | None = None) -> dict[str, np.ndarray]:
        timestep = timestep_of(frame)
        trained = self.run.flame_params(timestep) if self.run is not None else None
        if trained is not None:
            if self.flame is not None:
                self.flame.check_counts(trained, self.run.flame_param_file(timestep))
            return trained
        params = dict(self.capture.flame_params(timestep))
        if self.flame is not None:
            self.flame.check_counts(params, self.capture.flame_param_file(timestep))
        if self._identity:
            params.update(self._identity)
        return params


def mean_finetuning_offset(run: RunFolder, capture: Capture) -> dict[str, np.ndarray]:
    """Per motion parameter, the mean of (the run's parameters − the capture's tracked ones) over
    the run's training timesteps; empty when the run kept the tracked parameters (Freeze)."""
    timesteps = [t for t in run.trained_timesteps if t in capture.timestep_ids]
    if not timesteps:
        return {}
    pairs = [(run.flame_params(t), capture.flame_params(t)) for t in timesteps]
    offset = {}
    for key in MOTION_KEYS:
        if all(key in own and key in tracked and np.shape(own[key]) == np.shape(tracked[key])
               for own, tracked in pairs):
            mean = np.mean([np.asarray(own[key], np.float64) - tracked[key] for own, tracked in pairs], axis=0)
            if np.any(mean != 0):
                offset[key] = mean.astype(np.float32)
    return offset


class AlignedTrackedParams(TrackedParams):
    """:class:`TrackedParams`, with the tracked parameters of timesteps the run never saw moved by
    :func:`mean_finetuning_offset`.

    Why: fine-tuning moved the tracker's parameters of the training frames to where the avatar
    renders the captures; the constant part of that move is the tracker's own constant error as
    the avatar sees it, and the same tracker made it on the other frames of the capture. Only the
    run's parameters and the capture's tracking are read (no image, nothing of the frame scored).
    A capture driving another subject's avatar has another tracker error: use :class:`TrackedParams`.
    """

    description = "parameter-driven, tracked + the run's mean fine-tuning offset (no image input)"

    def __init__(self, capture: Capture, run: RunFolder):
        super().__init__(capture, run)
        self.offset = mean_finetuning_offset(run, capture)
        self._trained = set(run.trained_timesteps)

    def params_for(self, frame: Frame | int, exclude_view: str | None = None) -> dict[str, np.ndarray]:
        params = super().params_for(frame, exclude_view)
        if timestep_of(frame) in self._trained:
            return params
        return {**params, **{key: (params[key] + value).astype(np.float32) for key, value in self.offset.items()}}
