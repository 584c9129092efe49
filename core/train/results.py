"""What a training run writes besides its checkpoints: the final avatar and the FLAME parameters
it used, the cameras it learned, ``run.json``, and its val checks (the quick one during training,
the one at the end).

:class:`RunOutputs` knows the run folder, the settings and the training data; the trainer hands it
the trained parts (avatar, table, modules, cameras) and where the run stands, so this module needs
nothing of the training loop.
"""

from __future__ import annotations

import dataclasses
import pathlib
import time

from ..data import layout
from ..io.atomic import write_json
from ..io.npz import save_npz
from ..run.names import COLOURS_FILE, DELAYS_FILE, REFINED_CAMERAS_FILE, RUN_FORMAT, RUN_VERSION
from .camera_refine import write_refined_cameras
from .correction_part import corrected_avatar, finish_mogaface


def write_learned_cameras(root: pathlib.Path, offsets, delays, colours=None) -> None:
    """``RUN/cameras_refined.json``, ``RUN/camera_delays.json`` and ``RUN/camera_colours.json``, for
    the parts a run learns."""
    if offsets is not None:
        write_refined_cameras(root / REFINED_CAMERAS_FILE, offsets)
    if delays is not None:
        delays.write(root / DELAYS_FILE)
    if colours is not None:
        colours.write(root / COLOURS_FILE)


#: What a ``not_scored`` key of :meth:`RunOutputs.score_at_end` names, for its warning.
NOT_SCORED_LABELS = {"lpips": "LPIPS", "val": "the val split"}


def written_avatar(mogaface, avatar, table):
    """``(table, avatar)`` as the run writes them: the corrected parameters and the modulated avatar
    for a MoGaFace run (:func:`.correction_part.corrected_avatar`), so a check during training
    scores what ``render`` will draw."""
    if mogaface is None:
        return table, avatar
    return corrected_avatar(mogaface, avatar, table)


class RunOutputs:
    """The files of one run folder that are not checkpoints, for its settings and training data."""

    def __init__(self, run_folder, config, data, extent: float):
        self.run_folder, self.config, self.data, self.extent = run_folder, config, data, extent

    def write_final(self, avatar, table, mogaface, cameras: tuple, step: int, elapsed: float, events) -> None:
        """Write the final avatar, the FLAME parameters used, the learned ``cameras`` (offsets,
        delays, colours), run.json and the val metrics; emit ``done``."""
        run_folder = self.run_folder
        avatar.save(run_folder.avatar_path)
        write_learned_cameras(run_folder.root, *cameras)
        written_table, written = table, avatar
        if mogaface is not None:  # the corrected expressions and the modules
            written_table, written = finish_mogaface(mogaface, avatar, table, run_folder.root)
        for t in table.timesteps:
            save_npz(run_folder.root / layout.flame_param_path(t), layout.batched_flame_params(written_table.numpy(t)))
        metrics = None
        if self.config.eval.at_end and "val" in self.data.capture.splits:
            metrics = self.score_at_end(written, written_table, step, events)
            write_json(run_folder.metrics_path, metrics)
        self.write_run_json(avatar, table, step, elapsed, complete=True)
        events.emit("done", step=step, gaussians=len(avatar.gaussians), elapsed_s=elapsed, metrics=metrics)

    def score_at_end(self, avatar, table, step: int, events) -> dict:
        """The val metrics of the finished run. A metric that cannot be computed here (LPIPS without its
        weights, a val image that cannot be read) is left out and named, with why, under ``not_scored``,
        and said in a ``warning`` event: the trained avatar is never lost to its scoring."""
        from ..errors import MogafaceError
        from ..metrics import lpips_weights
        from .quick_eval import evaluate_val

        settings, not_scored = self.config.eval, {}
        if settings.lpips and (reason := lpips_weights.unavailable_reason()):
            not_scored["lpips"] = reason
            settings = dataclasses.replace(settings, lpips=False)
        start = time.monotonic()
        try:
            metrics = evaluate_val(avatar, self.data, table, settings)
        except MogafaceError as error:
            metrics = {"split": "val", "frames": 0}
            not_scored["val"] = str(error)
        metrics["step"] = step
        metrics["seconds"] = round(time.monotonic() - start, 3)
        if not_scored:
            metrics["not_scored"] = not_scored
            for name, reason in not_scored.items():
                events.emit("warning", message=f"{NOT_SCORED_LABELS[name]} not scored: {reason}")
        return metrics

    def write_run_json(self, avatar, table, step: int, elapsed: float, complete: bool) -> None:
        config, data = self.config, self.data
        write_json(self.run_folder.run_json_path, {
            "format": RUN_FORMAT,
            "version": RUN_VERSION,
            "capture": str(data.root),
            "head_file": avatar.head_file.name,
            "background": list(data.background),
            "scene_extent": self.extent,
            "splits": data.split_summary(),
            "train_timesteps": list(table.timesteps),
            "flame_finetuned": config.flame.finetune,
            "cameras_refined": config.cameras.refine,
            "mogaface": {k: getattr(config.mogaface, k) for k in ("mode", "bank", "texture")},
            "steps": config.train.steps,
            "final_step": step,
            "wall_time_s": round(elapsed, 3),
            "gaussians": len(avatar.gaussians),
            "complete": complete,
            "time_limited": complete and (step < config.train.steps or config.train.schedule == "minutes"),
        })

    def quick_check(self, avatar, table, step: int, events) -> None:
        """A few val frames' PSNR/SSIM of the written ``(table, avatar)`` as a 'val' event (not
        counted in the training time)."""
        if "val" not in self.data.capture.splits:
            return
        from .config import EvalSection
        from .quick_eval import evaluate_val

        settings = EvalSection(max_frames=self.config.eval.every_frames, lpips=False)
        metrics = evaluate_val(avatar, self.data, table, settings)
        events.emit("val", step=step, **{k: metrics[k] for k in ("frames", "psnr", "ssim", "psnr_masked",
                                                                 "ssim_masked")})
