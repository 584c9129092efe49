"""Temporal smoothing of another source's parameters: the image-free baseline a tracker's jitter
invites. A Gaussian filter over each sequence, one σ per group (expression, rotations,
translation), chosen on the training sequences against the truth, never on the scored sequence.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d

from ...data.capture import Capture, Frame
from ...data.capture_info import capture_info
from ...data.sequences import NOISE_GROUPS
from .base import ParamSource, timestep_of
from .true import true_params

SIGMAS = (0.0, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0)  # candidates, timesteps


def sequence_timesteps(capture: Capture) -> dict[str, list[int]]:
    """Each sequence's timesteps in order (``capture_info.json`` ranges, else the frames' sequence)."""
    ranges = capture_info(capture.root).get("sequences")
    if ranges:
        return {name: list(range(int(a), int(b))) for name, (a, b) in ranges.items()}
    found: dict[str, set[int]] = {}
    for frame in capture.frames():
        found.setdefault(frame.sequence or "", set()).add(frame.timestep_index)
    return {name: sorted(steps) for name, steps in found.items()}


def smooth(values: np.ndarray, sigma: float) -> np.ndarray:
    """``(T, n)`` values filtered along time (edges: nearest value repeated)."""
    if sigma <= 0 or len(values) < 2:
        return values
    return gaussian_filter1d(values, sigma, axis=0, mode="nearest").astype(values.dtype)


def choose_sigmas(capture: Capture, held_out: list[str], candidates=SIGMAS) -> dict[str, float]:
    """Per group, the σ whose smoothing of the tracked parameters comes closest (RMSE) to the truth
    over the sequences not in ``held_out``."""
    errors = {group: np.zeros(len(candidates)) for group in NOISE_GROUPS}
    for name, steps in sequence_timesteps(capture).items():
        if name in held_out or not steps:
            continue
        tracked = [capture.flame_params(t) for t in steps]
        truth = [true_params(capture, t) for t in steps]
        for group, keys in NOISE_GROUPS.items():
            values = np.concatenate([np.stack([p[k] for p in tracked]) for k in keys], axis=1)
            target = np.concatenate([np.stack([p[k] for p in truth]) for k in keys], axis=1)
            for i, sigma in enumerate(candidates):
                errors[group][i] += np.square(smooth(values, sigma) - target).sum()
    return {group: float(candidates[int(np.argmin(e))]) for group, e in errors.items()}


class SmoothedParams:
    """``base``'s parameters (an image-free source) filtered over the frame's sequence."""

    uses_images = False

    def __init__(self, capture: Capture, base: ParamSource, sigmas: dict[str, float]):
        self.capture = capture
        self.base = base
        self.sigmas = dict(sigmas)
        self.description = "smoothed in time (σ " + ", ".join(f"{g} {s:g}" for g, s in self.sigmas.items()) + ")"
        self._sequence_of = {t: steps for steps in sequence_timesteps(capture).values() for t in steps}
        self._cache: dict[int, dict[str, np.ndarray]] = {}

    def params_for(self, frame: Frame | int, exclude_view: str | None = None) -> dict[str, np.ndarray]:
        timestep = timestep_of(frame)
        if timestep not in self._cache:
            self._smooth_sequence(self._sequence_of.get(timestep, [timestep]))
        return dict(self._cache[timestep])

    def _smooth_sequence(self, steps: list[int]) -> None:
        raw = [self.base.params_for(t) for t in steps]
        out = [dict(p) for p in raw]
        for group, keys in NOISE_GROUPS.items():
            for key in keys:
                filtered = smooth(np.stack([p[key] for p in raw]), self.sigmas.get(group, 0.0))
                for params, row in zip(out, filtered):
                    params[key] = row.astype(np.float32)
        self._cache.update(zip(steps, out))
