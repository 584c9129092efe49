"""Camera refinement in rounds (``[cameras] rounds = N``): train, then train a fresh avatar from
the cameras the last round refined, N times in all.

An avatar trained against misaligned views absorbs part of the misalignment (it blurs to agree
with all of them), and a blurred avatar pulls the cameras less; a fresh avatar trained from the
refined cameras starts from views that agree better, so its own refinement goes further
(docs/notebook/2026-11-26-camera-refinement.md). Rounds 1 … N−1 are whole runs in
``RUN/camera_rounds/<k>/`` without the final evaluation; the last round is ``RUN`` itself,
starting from the cameras of round N−1 (``[cameras] start``). A complete round is skipped and a
round with a checkpoint resumed, so a stopped training continues where it stopped; each round has
``train.steps`` steps, and a time budget (``train.max_minutes``) is the whole run's, shared evenly
by its rounds (a user who asks for an hour gets an hour, not one per round).
"""

from __future__ import annotations

import dataclasses
import pathlib

from ..run.names import AVATAR_FILE, CHECKPOINT_DIR, REFINED_CAMERAS_FILE
from .checkpoint import latest_checkpoint
from .config import TrainConfig

ROUNDS_DIR = "camera_rounds"


def round_folder(run, k: int) -> pathlib.Path:
    return pathlib.Path(run) / ROUNDS_DIR / str(k)


def round_config(config: TrainConfig, start: str) -> TrainConfig:
    """An earlier round's settings: one round, from ``start``, the cameras moving from the first
    step (``begin`` and ``delay_begin`` are the last round's), no evaluation at its end."""
    cameras = dataclasses.replace(config.cameras, rounds=1, start=start, begin=0, delay_begin=0)
    return dataclasses.replace(config, cameras=cameras, eval=dataclasses.replace(config.eval, at_end=False, every=0))


def shared_budget(config: TrainConfig) -> TrainConfig:
    """Each round's settings under the whole run's time budget: ``max_minutes / rounds`` (no budget:
    unchanged). Applied once, to the whole run's settings (``RUN/camera_rounds/config.toml``)."""
    if config.train.max_minutes <= 0:
        return config
    return dataclasses.replace(config, train=dataclasses.replace(
        config.train, max_minutes=config.train.max_minutes / config.cameras.rounds))


def train_earlier_rounds(run, config: TrainConfig, trainer_for) -> tuple[int | None, TrainConfig]:
    """Train rounds 1 … N−1 of ``config`` (the whole run's settings); ``trainer_for(folder, config or
    None, resume, k)`` builds round k's trainer. Returns the signal that stopped a round (else None)
    and the last round's settings, which start from the cameras of round N−1."""
    config = shared_budget(config)
    start = config.cameras.start
    for k in range(1, config.cameras.rounds):
        folder = round_folder(run, k)
        if not (folder / AVATAR_FILE).exists():
            resume = latest_checkpoint(folder / CHECKPOINT_DIR) is not None
            trainer = trainer_for(folder, None if resume else round_config(config, start), resume, k)
            result = trainer.run()
            if result["stopped"] is not None:
                return result["stopped"], config
        start = str((folder / REFINED_CAMERAS_FILE).resolve())
    return None, dataclasses.replace(config, cameras=dataclasses.replace(config.cameras, start=start))
