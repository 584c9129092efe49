"""The ceiling: the true motion of a synthetic capture (``flame_param_gt/``)."""

from __future__ import annotations

import numpy as np

from ...data.capture import Capture, Frame
from ...data.capture_info import capture_info
from ...errors import InputError
from ...run.folder import MOTION_KEYS, RunFolder, load_flame_file
from ..expression_error import in_gauge
from .base import timestep_of


def truth_dir(capture: Capture):
    """The folder of the capture's true parameters; an input error when it carries none."""
    name = capture_info(capture.root).get("ground_truth", {}).get("flame_param")
    if not name or not (capture.root / name).is_dir():
        raise InputError(capture.root, "ground_truth.flame_param", "the capture carries no true parameters")
    return capture.root / name


def true_params(capture: Capture, timestep: int) -> dict[str, np.ndarray]:
    """The true parameters of one timestep, as the capture stores them."""
    return load_flame_file(truth_dir(capture) / f"{timestep:05d}.npz")


class TrueParams:
    """The true motion (expression, jaw, eyes, neck, rotation, translation) of each timestep with
    the run's identity (shape and static offset as trained, as the other sources use): what a
    perfect tracker would give this avatar. With ``gauge`` (:func:`..expression_error.truth_gauge`)
    the truth in the avatar's gauge: the image ceiling of a correction, since an avatar trained on a
    biased tracking renders the raw truth worse than its own parameters. Looks at no image."""

    uses_images = False

    def __init__(self, capture: Capture, run: RunFolder | None = None, gauge: dict[str, np.ndarray] | None = None):
        self.capture = capture
        truth_dir(capture)  # fail early on a capture without truth
        self._identity = run.identity_params() if run is not None else None
        self.gauge = gauge or {}
        self.description = ("true parameters in the avatar's gauge (flame_param_gt + the run's mean offset from "
                            "it on training timesteps; the ceiling)" if self.gauge
                            else "true parameters (flame_param_gt)")

    def params_for(self, frame: Frame | int, exclude_view: str | None = None) -> dict[str, np.ndarray]:
        truth = in_gauge(true_params(self.capture, timestep_of(frame)), self.gauge)
        if not self._identity:
            return truth
        return {**{k: truth[k] for k in MOTION_KEYS if k in truth}, **self._identity}
