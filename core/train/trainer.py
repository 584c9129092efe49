"""The baseline trainer: Gaussians bound to the tracked FLAME mesh, optimised view by view.

One step renders one random training image (a timestep and a camera) and takes an Adam step
on ``0.8·L1 + 0.2·(1 − SSIM)`` plus the position and scaling hinges of the Gaussians visible in
it; the :class:`~mogaface.core.avatar.densify.DensifyStrategy` then densifies, prunes, resets
opacities and raises the SH degree on its schedule. Optionally the per-timestep FLAME
parameters are fine-tuned too. Everything that decides what happens next (step, parameters,
Adam moments, densification statistics, random state, frame order) is in :meth:`Trainer.state`,
so a resumed run continues exactly where its checkpoint left it.
"""

from __future__ import annotations

import math
import os
import pathlib
import shutil
import signal
import time

import torch

from ..avatar.avatar import Avatar
from ..avatar.binding import triangle_frames
from ..avatar.densify import DensifySchedule, DensifyStrategy
from ..data import layout
from ..errors import InputError, MogafaceError
from ..io.atomic import atomic_path, write_json, write_text
from ..io.npz import save_npz
from . import config as config_module
from .checkpoint import latest_checkpoint, newest_intact_checkpoint, save_checkpoint
from .run_lock import resume_notes, take_run_folder
from .config import TrainConfig
from .data import TrainingData, capture_head_file
from .events import EventLog, Listener
from .losses import image_loss, position_hinge, psnr, scaling_hinge
from .mogaface_part import build_mogaface, finish_mogaface, mogaface_render
from .run_folder import RUN_FORMAT, RUN_VERSION, RunFolder

GAUSSIAN_GROUPS = ("local_position", "local_log_scale", "local_rotation", "opacity_logit", "sh_dc", "sh_rest")


def set_threads(threads: int) -> None:
    """Use ``threads`` CPU threads in torch and in the splat engine's numba kernels."""
    import numba

    torch.set_num_threads(threads)
    numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))


def densify_schedule(config: TrainConfig) -> DensifySchedule:
    d = config.densify
    return DensifySchedule(**{name: getattr(d, name) for name in DensifySchedule.__dataclass_fields__})


def position_lr(config: TrainConfig, extent: float, step: int) -> float:
    """Exponential decay from ``lr.position × extent`` to ``position_final_ratio`` of it at the last step."""
    t = min(max(step / max(config.train.steps, 1), 0.0), 1.0)
    return config.lr.position * extent * math.exp(t * math.log(config.lr.position_final_ratio))


class Trainer:
    """A training run in a run folder: create it fresh, or resume it from its latest checkpoint.

    ``listeners`` receive every progress event (dicts) besides ``RUN/events.jsonl``.
    """

    def __init__(self, capture: str | os.PathLike, run: str | os.PathLike, config: TrainConfig | None = None, *,
                 resume: bool = False, head_file: str | os.PathLike | None = None,
                 listeners: list[Listener] | None = None):
        self.run_folder = RunFolder.at(run)
        self.lock = take_run_folder(self.run_folder.root)
        checkpoint, self._notes = None, []
        if resume:
            path, checkpoint, skipped = newest_intact_checkpoint(self.run_folder.checkpoints)
            self._notes = resume_notes(self.run_folder.checkpoints, path, skipped, self.lock)
            if config is None:
                config = config_module.load(self.run_folder.config)
        elif latest_checkpoint(self.run_folder.checkpoints) is not None or self.run_folder.avatar.exists():
            raise InputError(self.run_folder.root, None, "already holds a run (resume it with --resume, "
                                                         "or choose another folder)")
        self.config = (config or TrainConfig()).check()
        set_threads(self.config.train.threads)
        self.data = TrainingData(capture)
        self.extent = self.config.lr.scene_extent or self.data.extent
        self.background = torch.tensor(self.data.background, dtype=torch.float32)
        self.generator = torch.Generator().manual_seed(self.config.train.seed)
        self.step = 0
        self.elapsed = 0.0
        self._order = torch.zeros(0, dtype=torch.long)
        self._position = 0
        self._stop_signal: int | None = None
        self._posed_cache: dict[int, torch.Tensor] = {}

        self.run_folder.root.mkdir(parents=True, exist_ok=True)
        if checkpoint is None:
            self._start_fresh(head_file)
        else:
            self._restore(checkpoint)
        self.events = EventLog(self.run_folder.events, listeners)
        for note in self._notes:
            self.events.emit("warning", message=note)

    # -- setting up ----------------------------------------------------------------------------
    def _start_fresh(self, head_file) -> None:
        source = pathlib.Path(head_file) if head_file is not None else capture_head_file(self.data.root)
        head = self.run_folder.head(source.suffix or ".pkl")
        with atomic_path(head) as tmp:
            shutil.copyfile(source, tmp)
        write_text(self.run_folder.config, config_module.to_toml(self.config))
        self.avatar = Avatar.initial(head, self.config.densify.max_sh_degree)
        self.table = self.data.flame_table()
        self._build_optimizer()
        self.mogaface = build_mogaface(self.config, self.data, self.table, self.avatar)
        self.strategy = DensifyStrategy(densify_schedule(self.config), len(self.avatar.gaussians),
                                        len(self.avatar.flame.faces))
        self._write_run_json(complete=False)

    def _restore(self, state: dict) -> None:
        self.avatar = Avatar.from_state(state["avatar"], self.run_folder.root, source=self.run_folder.checkpoints)
        self.table = self.data.flame_table()
        if state["table"]["timesteps"] != self.table.timesteps:
            raise InputError(self.run_folder.checkpoints, "table.timesteps",
                             "the capture's training timesteps differ from the checkpoint's")
        with torch.no_grad():
            for name, value in self.table.trainable().items():
                value.copy_(state["table"][name])
        self._build_optimizer()
        self.optimizer.load_state_dict(state["optimizer"])
        self.mogaface = build_mogaface(self.config, self.data, self.table, self.avatar)
        if self.mogaface is not None:
            if "mogaface" not in state:
                raise InputError(self.run_folder.checkpoints, "mogaface", "the checkpoint holds no MoGaFace modules")
            self.mogaface.load_state_dict(state["mogaface"])
        self.strategy = DensifyStrategy(densify_schedule(self.config), len(self.avatar.gaussians),
                                        len(self.avatar.flame.faces))
        self.strategy.load_state_dict(state["densify"])
        self.generator.set_state(state["rng"]["torch"])
        self._order = state["sampler"]["order"].clone()
        self._position = int(state["sampler"]["position"])
        self.step = int(state["step"])
        self.elapsed = float(state["elapsed_s"])
        write_text(self.run_folder.config, config_module.to_toml(self.config))  # e.g. a new --steps

    def _build_optimizer(self) -> None:
        lr = self.config.lr
        rates = {
            "local_position": position_lr(self.config, self.extent, self.step),
            "local_log_scale": lr.scaling,
            "local_rotation": lr.rotation,
            "opacity_logit": lr.opacity,
            "sh_dc": lr.color,
            "sh_rest": lr.color * lr.color_rest_ratio,
        }
        groups = [{"params": [getattr(self.avatar.gaussians, n)], "lr": rates[n], "name": n} for n in GAUSSIAN_GROUPS]
        flame = self.config.flame
        for name, value in self.table.trainable().items():
            value.requires_grad_(flame.finetune)
            if flame.finetune:
                rate = {"expr": flame.expression_lr, "translation": flame.translation_lr}.get(name, flame.joints_lr)
                groups.append({"params": [value], "lr": rate, "name": f"flame.{name}"})
        self.optimizer = torch.optim.Adam(groups, lr=0.0, eps=1e-15)

    # -- state ----------------------------------------------------------------------------------
    def state(self) -> dict:
        """Everything a resumed run needs, as tensors and plain values (``weights_only`` safe)."""
        self.avatar.gaussians.active_sh_degree = self.strategy.schedule.sh_degree(self.step)
        return {
            "elapsed_s": self.elapsed,
            "config": self.config.to_dict(),
            "avatar": self.avatar.state(),
            "table": {"timesteps": list(self.table.timesteps),
                      **{k: v.detach().clone() for k, v in self.table.trainable().items()}},
            "optimizer": self.optimizer.state_dict(),
            "densify": self.strategy.state_dict(),
            "rng": {"torch": self.generator.get_state()},
            "sampler": {"order": self._order.clone(), "position": self._position},
            **({"mogaface": self.mogaface.state_dict()} if self.mogaface is not None else {}),
        }

    def checkpoint(self) -> pathlib.Path:
        path = save_checkpoint(self.run_folder.checkpoints, self.step, self.state(),
                               keep=self.config.train.keep_checkpoints)
        self.events.emit("checkpoint", step=self.step, path=str(path.relative_to(self.run_folder.root)))
        return path

    # -- one step -------------------------------------------------------------------------------
    def _next_frame(self):
        """Training frames in a fresh random order each epoch (every image seen once per epoch)."""
        if self._position >= len(self._order):
            self._order = torch.randperm(len(self.data.frames), generator=self.generator)
            self._position = 0
        frame = self.data.frames[int(self._order[self._position])]
        self._position += 1
        return frame

    def _posed_vertices(self, timestep: int) -> torch.Tensor:
        """The mesh of a timestep; cached when the FLAME parameters are fixed."""
        if self.config.flame.finetune:
            return self.avatar.posed_vertices(self.table.params(timestep))
        vertices = self._posed_cache.get(timestep)
        if vertices is None:
            with torch.no_grad():
                vertices = self.avatar.posed_vertices(self.table.params(timestep))
            self._posed_cache[timestep] = vertices
        return vertices

    def train_step(self) -> dict:
        """Run step ``self.step`` (0-based) and advance; returns its losses and what densification did."""
        cfg = self.config
        gaussians = self.avatar.gaussians
        for group in self.optimizer.param_groups:
            if group["name"] == "local_position":
                group["lr"] = position_lr(cfg, self.extent, self.step)
        gaussians.active_sh_degree = self.strategy.schedule.sh_degree(self.step)
        frame = self._next_frame()
        camera = self.data.capture.camera(frame)
        target = self.data.target(frame)
        correction = None
        if self.mogaface is None:
            vertices = self._posed_vertices(frame.timestep_index)
            out = self.avatar.render_posed(vertices, camera, self.background)
        else:
            vertices, out, correction = mogaface_render(self.mogaface, self.avatar, self.table, frame, camera,
                                                        self.background, self.step, self.generator)
        losses = image_loss(out.rgb, target, cfg.loss.ssim_weight)
        visible = out.visible
        losses["position"] = position_hinge(gaussians.local_position[visible], cfg.loss.position_threshold)
        losses["scaling"] = scaling_hinge(gaussians.local_log_scale[visible], cfg.loss.scaling_threshold)
        total = losses["rgb"] + cfg.loss.position_weight * losses["position"] \
            + cfg.loss.scaling_weight * losses["scaling"]
        if correction is not None:
            losses["consistency"] = correction.consistency
            total = total + cfg.mogaface.consistency_weight * correction.consistency
            if cfg.mogaface.centring_weight:
                losses["centring"] = correction.centring
                total = total + cfg.mogaface.centring_weight * correction.centring
            if correction.rendered is not None:
                losses["rendered"] = correction.rendered
                total = total + cfg.mogaface.rendered_weight * correction.rendered
        total.backward()
        self.strategy.observe(self.step + 1, out.means2d.grad, out.radii, camera.width, camera.height)
        self.optimizer.step()
        self.optimizer.zero_grad(set_to_none=True)
        if correction is not None:
            self.mogaface.optimizer_step()
            correction.commit()
        self.step += 1
        report = {}
        if self.strategy.schedule.densifies_at(self.step) or self.strategy.schedule.resets_opacity_at(self.step):
            with torch.no_grad():
                face_scale = triangle_frames(vertices.detach(), self.avatar.flame.faces).scale
                report = self.strategy.after_step(self.step, gaussians, self.optimizer, face_scale, self.extent,
                                                  self.generator)
        values = {k: float(v.detach()) for k, v in losses.items()}
        values["loss"] = float(total.detach())
        values["psnr"] = psnr(out.rgb, target)
        return {"losses": values, "densify": report}

    # -- the loop -------------------------------------------------------------------------------
    def request_stop(self, signum: int = signal.SIGTERM) -> None:
        """Ask the loop to checkpoint and return after the current step (safe in a signal handler)."""
        self._stop_signal = signum

    def install_signal_handlers(self) -> None:
        """SIGINT and SIGTERM stop the run cleanly (checkpoint first) instead of killing it."""
        def handle(number, _frame):
            if self._stop_signal is not None:  # asked twice: leave now (files are written atomically)
                raise SystemExit(128 + number)
            self.request_stop(number)

        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, handle)

    def run(self, until: int | None = None) -> dict:
        """Train to step ``until`` (default: the configured steps), then write the results.

        Returns ``{"step", "stopped" (signal number or None), "complete"}``. A run stopped by a
        signal or by ``until`` ends with a checkpoint; a complete one also writes the avatar,
        FLAME parameters, run.json and (when configured) the val metrics. A run that uses up
        ``train.max_minutes`` of training time finishes early as if complete.
        """
        cfg = self.config.train
        end = cfg.steps if until is None else min(until, cfg.steps)
        self.events.emit("resume" if self.step else "start", step=self.step, steps=cfg.steps,
                         gaussians=len(self.avatar.gaussians), extent=self.extent,
                         frames=len(self.data.frames), timesteps=len(self.data.timesteps))
        window_start, window_steps = time.monotonic(), 0
        last = time.monotonic()
        budget = cfg.max_minutes * 60 if cfg.max_minutes > 0 else math.inf
        out_of_time = False
        self.lock.acquire()
        try:
            while self.step < end and self._stop_signal is None:
                if self.elapsed >= budget:
                    out_of_time = True
                    break
                result = self.train_step()
                now = time.monotonic()
                self.elapsed += now - last
                last = now
                window_steps += 1
                if result["densify"]:
                    self.events.emit("densify", step=self.step, **result["densify"])
                if self.step % cfg.log_every == 0 or self.step == end:
                    rate = window_steps / max(now - window_start, 1e-9)
                    self.events.emit("iter", step=self.step, steps=cfg.steps, **result["losses"],
                                     gaussians=len(self.avatar.gaussians),
                                     sh_degree=self.avatar.gaussians.active_sh_degree,
                                     lr_position=position_lr(self.config, self.extent, self.step),
                                     it_s=rate, eta_s=(cfg.steps - self.step) / max(rate, 1e-9),
                                     elapsed_s=self.elapsed)
                    window_start, window_steps = now, 0
                if self.config.eval.every and self.step % self.config.eval.every == 0:
                    self._quick_check()
                    last = time.monotonic()
                if cfg.checkpoint_every and self.step % cfg.checkpoint_every == 0 and self.step < cfg.steps:
                    self.checkpoint()
            if self._stop_signal is not None or (self.step < cfg.steps and not out_of_time):
                self.checkpoint()
                if self._stop_signal is not None:
                    self.events.emit("stopped", step=self.step, signal=signal.Signals(self._stop_signal).name)
                return {"step": self.step, "stopped": self._stop_signal, "complete": False}
            if out_of_time:
                self.events.emit("time_limit", step=self.step, elapsed_s=self.elapsed)
            self.checkpoint()
            self.finish()
            return {"step": self.step, "stopped": None, "complete": True}
        except MogafaceError:
            self.checkpoint()  # bad data met mid-run (a corrupt image): keep the steps done so far
            raise
        finally:
            self.events.close()
            self.lock.release()

    def _quick_check(self) -> None:
        """A few val frames' PSNR/SSIM as a 'val' event (not counted in the training time)."""
        if "val" not in self.data.capture.splits:
            return
        from .config import EvalSection
        from .quick_eval import evaluate_val

        self.avatar.gaussians.active_sh_degree = self.strategy.schedule.sh_degree(self.step)
        settings = EvalSection(max_frames=self.config.eval.every_frames, lpips=False)
        metrics = evaluate_val(self.avatar, self.data, self.table, settings)
        self.events.emit("val", step=self.step, **{k: metrics[k] for k in ("frames", "psnr", "ssim", "psnr_masked",
                                                                         "ssim_masked")})

    # -- results --------------------------------------------------------------------------------
    def finish(self) -> None:
        """Write the final avatar, the FLAME parameters used, run.json and the quick val metrics."""
        self.avatar.gaussians.active_sh_degree = self.strategy.schedule.sh_degree(self.step)
        self.avatar.save(self.run_folder.avatar)
        table, avatar, extra = self.table, self.avatar, None
        if self.mogaface is not None:  # the corrected expressions, the modules and their features
            table, avatar, extra = finish_mogaface(self.mogaface, self.avatar, self.table, self.run_folder.root)
        for t in self.table.timesteps:
            save_npz(self.run_folder.root / layout.flame_param_path(t), layout.batched_flame_params(table.numpy(t)))
        metrics = None
        if self.config.eval.at_end and "val" in self.data.capture.splits:
            from .quick_eval import evaluate_val

            start = time.monotonic()
            metrics = evaluate_val(avatar, self.data, table, self.config.eval, extra)
            metrics["step"] = self.step
            metrics["seconds"] = round(time.monotonic() - start, 3)
            write_json(self.run_folder.metrics, metrics)
        self._write_run_json(complete=True)
        self.events.emit("done", step=self.step, gaussians=len(self.avatar.gaussians), elapsed_s=self.elapsed,
                         metrics=metrics)

    def _write_run_json(self, complete: bool) -> None:
        write_json(self.run_folder.run_json, {
            "format": RUN_FORMAT,
            "version": RUN_VERSION,
            "capture": str(self.data.root),
            "head_file": self.avatar.head_file.name,
            "background": list(self.data.background),
            "scene_extent": self.extent,
            "splits": self.data.split_summary(),
            "train_timesteps": list(self.table.timesteps),
            "flame_finetuned": self.config.flame.finetune,
            "mogaface": {k: getattr(self.config.mogaface, k) for k in ("mode", "bank", "texture")},
            "steps": self.config.train.steps,
            "final_step": self.step,
            "wall_time_s": round(self.elapsed, 3),
            "gaussians": len(self.avatar.gaussians),
            "complete": complete,
            "time_limited": complete and self.step < self.config.train.steps,
        })

