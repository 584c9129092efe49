"""Parameter-driven inference: the tracker's parameters, no image."""

from __future__ import annotations

import numpy as np

from ...data.capture import Capture, Frame
from ..run_folder import RunFolder
from .base import timestep_of


class TrackedParams:
    """The run's own parameters for training timesteps, the capture's tracked ones (with the
    run's identity: shape, static offset) for the rest.

    Looks at no image, so ``exclude_view`` is satisfied trivially.
    """

    uses_images = False
    description = "parameter-driven (tracked FLAME parameters; no image input)"

    def __init__(self, capture: Capture, run: RunFolder | None = None):
        self.capture = capture
        self.run = run
        self._identity = run.identity_params() if run is not None else None

    def params_for(self, frame: Frame | int, exclude_view: str | None = None) -> dict[str, np.ndarray]:
        timestep = timestep_of(frame)
        trained = self.run.flame_params(timestep) if self.run is not None else None
        if trained is not None:
            return trained
        params = dict(self.capture.flame_params(timestep))
        if self._identity:
            params.update(self._identity)
        return params
