"""The training schedules: what a rate, the image size and densification are at a given step.

Plain functions of the settings and a step (or the share of the training done), read by the
trainer every step and by anything that runs a schedule of its own (camera alignment at scoring
time), so none of them needs the training loop.
"""

from __future__ import annotations

import math

from ..avatar.densify import DensifySchedule, DensifyStrategy
from ..avatar.mcmc import MCMCStrategy
from .config import TrainConfig


def densify_schedule(config: TrainConfig) -> DensifySchedule:
    """The ``[densify]`` settings as the densification strategy's schedule."""
    d = config.densify
    return DensifySchedule(**{name: getattr(d, name) for name in DensifySchedule.__dataclass_fields__})


def densify_strategy(config: TrainConfig, n_gaussians: int, n_faces: int) -> DensifyStrategy:
    """The ``densify.strategy`` the settings name, fresh, for ``n_gaussians`` on ``n_faces`` triangles."""
    schedule = densify_schedule(config)
    kind = MCMCStrategy if schedule.strategy == "mcmc" else DensifyStrategy
    return kind(schedule, n_gaussians, n_faces)


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
                               ("delay", cams.delay_lr), ("colour", cams.colour_lr))}


def rates_at(config: TrainConfig, extent: float, step: int) -> dict[str, float]:
    """The rates that follow a schedule at ``step``, by optimiser group name (the others are constant)."""
    return {"local_position": position_lr(config, extent, step), **camera_lrs(config, step)}


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


def schedule_position(config: TrainConfig, steps_done: int, elapsed: float) -> float:
    """Where the schedules stand, in steps: ``steps_done``, or under ``train.schedule = "minutes"``
    the step of ``train.steps`` that the share of ``train.max_minutes`` spent (``elapsed`` seconds)
    stands for. Every schedule (rates, densification, SH degree, cameras, bank, resolution) reads
    it, so a budget in minutes runs the whole schedule whatever the machine's speed."""
    cfg = config.train
    if cfg.schedule == "minutes":
        return min(float(cfg.steps), elapsed / (cfg.max_minutes * 60) * cfg.steps)
    return float(steps_done)


def cameras_settling(config: TrainConfig, step: int) -> bool:
    """Whether ``step`` is in the cameras-only phase (``[cameras] settle_at``, ``settle_steps``)."""
    cams = config.cameras
    return cams.settle_at <= step < cams.settle_at + cams.settle_steps


def hold_still(optimizer, config: TrainConfig, step: int, settling: bool) -> None:
    """Drop the gradients of the optimiser groups that hold still at ``step`` (Adam skips them this
    step): the camera offsets before ``cameras.begin``, the delays before ``cameras.delay_begin``,
    the colours before ``cameras.colour_begin``, and everything but the cameras while they settle (:func:`cameras_settling`)."""
    cams, steps = config.cameras, config.train.steps

    def holds(name: str) -> bool:
        if not name.startswith("cameras."):
            return settling
        if name == "cameras.delay":
            return step < cams.delay_begin * steps
        if name == "cameras.colour":
            return step < cams.colour_begin * steps
        return name in ("cameras.rotation", "cameras.translation") and step < cams.begin * steps

    for group in optimizer.param_groups:
        if holds(group["name"]):
            for param in group["params"]:
                param.grad = None
