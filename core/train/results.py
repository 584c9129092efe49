"""What a training run writes besides its checkpoints: the final avatar and the FLAME parameters
it used, the cameras it learned, ``run.json``, and its val checks (the quick one during training,
the one at the end).

Functions of the :class:`~mogaface.core.train.trainer.Trainer` they write for (imported for type
checking only: the trainer imports this module).
"""

from __future__ import annotations

import dataclasses
import pathlib
import time
from typing import TYPE_CHECKING

from ..data import layout
from ..io.atomic import write_json
from ..io.npz import save_npz
from ..run.names import DELAYS_FILE, REFINED_CAMERAS_FILE, RUN_FORMAT, RUN_VERSION
from .camera_refine import write_refined_cameras
from .correction_part import corrected_avatar, finish_mogaface

if TYPE_CHECKING:
    from .trainer import Trainer


def write_learned_cameras(root: pathlib.Path, offsets, delays) -> None:
    """``RUN/cameras_refined.json`` and ``RUN/camera_delays.json``, for the parts a run learns."""
    if offsets is not None:
        write_refined_cameras(root / REFINED_CAMERAS_FILE, offsets)
    if delays is not None:
        delays.write(root / DELAYS_FILE)


def write_results(trainer: Trainer) -> None:
    """Write the final avatar, the FLAME parameters used, run.json and the val metrics; emit ``done``."""
    run_folder, config = trainer.run_folder, trainer.config
    trainer.avatar.gaussians.active_sh_degree = trainer.strategy.schedule.sh_degree(trainer.schedule_step())
    trainer.avatar.save(run_folder.avatar_path)
    write_learned_cameras(run_folder.root, trainer.camera_offsets, trainer.camera_delays)
    table, avatar = trainer.table, trainer.avatar
    if trainer.mogaface is not None:  # the corrected expressions and the modules
        table, avatar = finish_mogaface(trainer.mogaface, trainer.avatar, trainer.table, run_folder.root)
    for t in trainer.table.timesteps:
        save_npz(run_folder.root / layout.flame_param_path(t), layout.batched_flame_params(table.numpy(t)))
    metrics = None
    if config.eval.at_end and "val" in trainer.data.capture.splits:
        metrics = score_at_end(trainer, avatar, table)
        write_json(run_folder.metrics_path, metrics)
    write_run_json(trainer, complete=True)
    trainer.events.emit("done", step=trainer.step, gaussians=len(trainer.avatar.gaussians),
                        elapsed_s=trainer.elapsed, metrics=metrics)


def score_at_end(trainer: Trainer, avatar, table) -> dict:
    """The val metrics of the finished run. A metric that cannot be computed here (LPIPS without its
    weights, a val image that cannot be read) is left out and named, with why, under ``not_scored``,
    and said in a ``warning`` event: the trained avatar is never lost to its scoring."""
    from ..errors import MogafaceError
    from ..metrics import lpips_weights
    from .quick_eval import evaluate_val

    settings, not_scored = trainer.config.eval, {}
    if settings.lpips and (reason := lpips_weights.unavailable_reason()):
        not_scored["lpips"] = reason
        settings = dataclasses.replace(settings, lpips=False)
    start = time.monotonic()
    try:
        metrics = evaluate_val(avatar, trainer.data, table, settings)
    except MogafaceError as error:
        metrics = {"split": "val", "frames": 0}
        not_scored["val"] = str(error)
    metrics["step"] = trainer.step
    metrics["seconds"] = round(time.monotonic() - start, 3)
    if not_scored:
        metrics["not_scored"] = not_scored
        for name, reason in not_scored.items():
            trainer.events.emit("warning", message=f"{NOT_SCORED_LABELS[name]} not scored: {reason}")
    return metrics


#: What a ``not_scored`` key of :func:`score_at_end` names, for its warning.
NOT_SCORED_LABELS = {"lpips": "LPIPS", "val": "the val split"}


def write_run_json(trainer: Trainer, complete: bool) -> None:
    config = trainer.config
    write_json(trainer.run_folder.run_json_path, {
        "format": RUN_FORMAT,
        "version": RUN_VERSION,
        "capture": str(trainer.data.root),
        "head_file": trainer.avatar.head_file.name,
        "background": list(trainer.data.background),
        "scene_extent": trainer.extent,
        "splits": trainer.data.split_summary(),
        "train_timesteps": list(trainer.table.timesteps),
        "flame_finetuned": config.flame.finetune,
        "cameras_refined": config.cameras.refine,
        "mogaface": {k: getattr(config.mogaface, k) for k in ("mode", "bank", "texture")},
        "steps": config.train.steps,
        "final_step": trainer.step,
        "wall_time_s": round(trainer.elapsed, 3),
        "gaussians": len(trainer.avatar.gaussians),
        "complete": complete,
        "time_limited": complete and (trainer.step < config.train.steps or config.train.schedule == "minutes"),
    })


def current_avatar(trainer: Trainer):
    """``(table, avatar)`` as the run would write them at this step: the corrected parameters and
    the modulated avatar for a MoGaFace run (:func:`.correction_part.corrected_avatar`), so a check
    during training scores what ``render`` will draw."""
    trainer.avatar.gaussians.active_sh_degree = trainer.strategy.schedule.sh_degree(trainer.schedule_step())
    if trainer.mogaface is None:
        return trainer.table, trainer.avatar
    return corrected_avatar(trainer.mogaface, trainer.avatar, trainer.table)


def quick_check(trainer: Trainer) -> None:
    """A few val frames' PSNR/SSIM as a 'val' event (not counted in the training time)."""
    if "val" not in trainer.data.capture.splits:
        return
    from .config import EvalSection
    from .quick_eval import evaluate_val

    table, avatar = current_avatar(trainer)
    settings = EvalSection(max_frames=trainer.config.eval.every_frames, lpips=False)
    metrics = evaluate_val(avatar, trainer.data, table, settings)
    trainer.events.emit("val", step=trainer.step, **{k: metrics[k] for k in ("frames", "psnr", "ssim", "psnr_masked",
                                                                         "ssim_masked")})
