"""The training schedules: what a rate, the image size and densification are at a given step.

Plain functions of the settings and a step (or the share of the training done), read by the
trainer every step and by anything that runs a schedule of its own (camera alignment at scoring
time), so none of them needs the training loop.
"""

from __future__ import annotations

import math

from ..avatar.densify import DensifySchedule
from .config import TrainConfig


def densify_schedule(config: TrainConfig) -> DensifySchedule:
    """The ``[densify]`` settings as the densification strategy's schedule."""
    d = config.densify
    return DensifySchedule(**{name: getattr(d, name) for name in DensifySchedule.__dataclass_fields__})


def decayed(rate: float, final_ratio: float, step: int, steps: int) -> float:
    """Exponential decay from ``rate`` at the first step to ``final_ratio × rate`` at the last."""
    t = min(max(step / max(steps, 1), 0.0), 1.0)
    return rate * math.exp(t * math.log(final_ratio))


def position_lr(config: TrainConfig, extent: float, step: int) -> float:
    """The Gaussians' position rate at ``step``: scaled by the scene's extent, decayed over the run."""
    return decayed(config.lr.position * extent, config.lr.position_final_ratio, step, config.train.steps)


def camera_lrs(config: TrainConfig, step: int) -> dict[str, float]:
    """The camera offsets' rates at ``step``: constant unless ``cameras.final_ratio`` < 1."""
    cams = config.cameras
    return {f"cameras.{name}": decayed(rate, cams.final_ratio, step, config.train.steps)
            for name, rate in (("rotation", cams.rotation_lr), ("translation", cams.translation_lr),
                               ("delay", cams.delay_lr))}


def image_scale(config: TrainConfig, progress: float) -> float:
    """Progressive resolution: the scale of the training images at ``progress`` (0 to 1) of the
    training. From ``train.resolution_start`` it doubles in even stages up to full size at
    ``train.resolution_full``: early steps, which shape the avatar coarsely, cost a fraction of a
    full-size step."""
    start, full = config.train.resolution_start, config.train.resolution_full
    if start >= 1.0 or full <= 0.0:
        return 1.0
    stages = math.ceil(math.log2(1.0 / start) - 1e-9)
    return min(1.0, start * 2.0 ** min(stages, int(progress / full * stages)))
