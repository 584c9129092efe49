"""The trainer: Gaussians bound to the tracked FLAME mesh, optimised view by view, with the
correction modules (expression correction, bank, texture attention) where ``[mogaface]`` has them.

One step renders ``train.batch`` random training images (a timestep and a camera each) and takes
an Adam step on ``0.8·L1 + 0.2·(1 − SSIM)`` plus the position and scaling hinges of the Gaussians
visible; the densification strategy (:mod:`..avatar.densify`, :mod:`..avatar.mcmc`) then adds,
prunes, moves or resets Gaussians and raises the SH degree on its schedule. Optionally the per-timestep
FLAME parameters and the cameras (poses, delays, colours) are learned too. Everything that decides what happens next
(step, parameters, Adam moments, densification statistics, random state, frame order) is in
:meth:`Trainer.state`, so a resumed run continues exactly where its checkpoint left it.

The trainer holds the loop and gathers the parts: each trainable part gives its own optimiser
groups (``param_groups``), :mod:`.schedule` gives each rate and size at a step, :mod:`.training_view`
renders and scores a view, :mod:`.camera_start` starts the cameras, :mod:`.checkpoint` says where a
run starts, :mod:`.results` writes what it ends with.
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
from ..data.capture_info import capture_head_file
from ..errors import InputError, MogafaceError
from ..io.atomic import atomic_path, write_text
from ..run.folder import RunFolder
from ..run.names import LANDMARK_CAMERAS_FILE
from ..splat import cancel
from ..splat.cancel import RenderCancelled
from . import config as config_module
from .camera_start import build_cameras, camera_state, load_cameras
from .checkpoint import save_checkpoint, starting_state
from .config import TrainConfig
from .correction_part import build_mogaface
from .data import FrameOrder, TrainingData, principal_point_notes
from .distributed import Communicator
from .events import EventLog, Listener
from .results import RunOutputs, write_learned_cameras, written_avatar
from .run_lock import take_run_folder
from .schedule import cameras_settling, densify_strategy, hold_still, image_scale, rates_at, schedule_position
from .training_view import ViewRenderer, ViewResult


def set_threads(threads: int) -> None:
    """Use ``threads`` CPU threads in torch and in the splat engine's numba kernels."""
    import numba

    torch.set_num_threads(threads)
    numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))


class Trainer:
    """A training run in a run folder: create it fresh, or resume it from its latest checkpoint.

    ``listeners`` receive every progress event (dicts) besides ``RUN/events.jsonl``. ``comm`` places
    the trainer among the ranks of a data-parallel run (default: a single process); only rank 0
    writes the run folder and emits events.
    """

    def __init__(self, capture: str | os.PathLike, run: str | os.PathLike, config: TrainConfig | None = None, *,
                 resume: bool = False, head_file: str | os.PathLike | None = None,
                 listeners: list[Listener] | None = None, comm: Communicator | None = None):
        self.comm = comm or Communicator()
        self.run_folder = RunFolder.at(run)
        # One writer per run folder: rank 0 holds the lock for every rank of a data-parallel run.
        self.lock = take_run_folder(self.run_folder.root) if self.comm.is_writer else None
        checkpoint, self._notes = starting_state(self.run_folder, resume, self.lock)
        if resume and config is None:
            config = config_module.load(self.run_folder.config_path)
        self.config = (config or TrainConfig()).check()
        set_threads(self.config.train.threads)
        self.data = TrainingData(capture)
        self.extent = self.config.lr.scene_extent or self.data.extent
        self.background = torch.tensor(self.data.background, dtype=torch.float32)
        self.outputs = RunOutputs(self.run_folder, self.config, self.data, self.extent)
        self.generator = torch.Generator().manual_seed(self.config.train.seed)
        self.frame_order = FrameOrder(len(self.data.frames))
        self.step = 0
        self.elapsed = 0.0
        self._stop_signal: int | None = None

        writer = self.comm.is_writer
        if writer:
            self.run_folder.root.mkdir(parents=True, exist_ok=True)
        if checkpoint is None:
            self._start_fresh(head_file)
        else:
            self._restore(checkpoint)
        self._scheduled_through = int(self._schedule_position(self.step))  # scheduled passes done up to here
        self.views = ViewRenderer(self.config, self.data, self.avatar, self.table, self.background, self.camera_offsets,
                                  self.camera_delays, self.mogaface, self.camera_colours)
        self.events = EventLog(self.run_folder.events_path if writer else None, listeners if writer else None)
        for note in self._notes:
            self.events.emit("warning", message=note)
        if self.comm.world > self.config.train.batch:
            self.events.emit("warning", message=f"{self.comm.world} ranks share a batch of {self.config.train.batch} "
                                                f"image(s) a step: ranks {self.config.train.batch} and up render "
                                                "nothing (train --batch auto gives each rank an image)")

    # -- setting up ----------------------------------------------------------------------------
    def _start_fresh(self, head_file) -> None:
        source = pathlib.Path(head_file) if head_file is not None else capture_head_file(self.data.root)
        head = self.run_folder.head_path(source.suffix or ".pkl")
        if self.comm.is_writer:
            with atomic_path(head) as tmp:
                shutil.copyfile(source, tmp)
            write_text(self.run_folder.config_path, config_module.to_toml(self.config))
        self.comm.barrier()  # the other ranks read the head model rank 0 copied
        self.table = self.data.flame_table()
        self.avatar = Avatar.initial(head, self.config.densify.max_sh_degree, n_vertices=self.table.n_vertices)
        self.data.check_counts(self.table, self.avatar.flame)
        landmarks_file = self.run_folder.root / LANDMARK_CAMERAS_FILE if self.comm.is_writer else None
        self.camera_offsets, self.camera_delays, self.camera_colours = build_cameras(
            self.config, self.data, self.table.timesteps, source, landmarks_file)
        self._build_optimizer()
        self.mogaface = build_mogaface(self.config, self.data, self.table, self.avatar)
        self.strategy = densify_strategy(self.config, len(self.avatar.gaussians), len(self.avatar.flame.faces))
        if self.comm.is_writer:
            self.outputs.write_run_json(self.avatar, self.table, self.step, self.elapsed, complete=False)
            self._notes.extend(principal_point_notes(self.data.capture, self.avatar.flame))

    def _restore(self, state: dict) -> None:
        self.avatar = Avatar.from_state(state["avatar"], self.run_folder.root, source=self.run_folder.checkpoint_dir)
        self.table = self.data.flame_table()
        self.data.check_counts(self.table, self.avatar.flame)
        if state["table"]["timesteps"] != self.table.timesteps:
            raise InputError(self.run_folder.checkpoint_dir, "table.timesteps",
                             "the capture's training timesteps differ from the checkpoint's")
        with torch.no_grad():
            for name, value in self.table.trainable().items():
                value.copy_(state["table"][name])
        self.camera_offsets, self.camera_delays, self.camera_colours = build_cameras(self.config, self.data,
                                                                                     self.table.timesteps)
        load_cameras(state, self._camera_parts(), self.run_folder.checkpoint_dir)
        self._build_optimizer()
        self.optimizer.load_state_dict(state["optimizer"])
        self.mogaface = build_mogaface(self.config, self.data, self.table, self.avatar)
        if self.mogaface is not None:
            if "mogaface" not in state:
                raise InputError(self.run_folder.checkpoint_dir, "mogaface", "the checkpoint holds no MoGaFace modules")
            self.mogaface.load_state_dict(state["mogaface"])
        self.strategy = densify_strategy(self.config, len(self.avatar.gaussians), len(self.avatar.flame.faces))
        self.strategy.load_state_dict(state["densify"])
        self.comm.keep_statistics_once(self.strategy)  # the checkpoint's totals count once (rank 0)
        self.generator.set_state(state["rng"]["torch"])
        self.frame_order.load_state(state["sampler"])
        self.step = int(state["step"])
        self.elapsed = float(state["elapsed_s"])
        if self.comm.is_writer:
            write_text(self.run_folder.config_path, config_module.to_toml(self.config))  # e.g. a new --steps

    def _build_optimizer(self) -> None:
        """One Adam over the groups each trainable part gives (Gaussians, FLAME table, cameras)."""
        position = rates_at(self.config, self.extent, self.step)["local_position"]
        groups = [*self.avatar.gaussians.param_groups(self.config.lr, position), *self.table.param_groups(self.config.flame)]
        for cameras in self._camera_parts():
            if cameras is not None:
                groups += cameras.param_groups(self.config.cameras)
        self.optimizer = torch.optim.Adam(groups, lr=0.0, eps=1e-15, fused=True)  # one kernel per group

    # -- state ----------------------------------------------------------------------------------
    def state(self) -> dict:
        """Everything a resumed run needs, as tensors and plain values (``weights_only`` safe)."""
        self._set_sh_degree()
        return {
            "elapsed_s": self.elapsed,
            "config": self.config.to_dict(),
            "avatar": self.avatar.state(),
            "table": {"timesteps": list(self.table.timesteps),
                      **{k: v.detach().clone() for k, v in self.table.trainable().items()}},
            "optimizer": self.optimizer.state_dict(),
            "densify": self.strategy.state_dict(),
            "rng": {"torch": self.generator.get_state()},
            "sampler": self.frame_order.state(),
            **({"mogaface": self.mogaface.state_dict()} if self.mogaface is not None else {}),
            **camera_state(*self._camera_parts()),
        }

    def _camera_parts(self) -> tuple:  # the learned camera parts, each None where the run has it off
        return self.camera_offsets, self.camera_delays, self.camera_colours

    def checkpoint(self) -> pathlib.Path | None:
        """Write a checkpoint (rank 0; every rank must call this at the same step). Returns its path."""
        self.comm.reduce_statistics(self.strategy)
        path = None
        if self.comm.is_writer:
            path = save_checkpoint(self.run_folder.checkpoint_dir, self.step, self.state(),
                                   keep=self.config.train.keep_checkpoints)
            write_learned_cameras(self.run_folder.root, *self._camera_parts())
            self.events.emit("checkpoint", step=self.step, path=str(path.relative_to(self.run_folder.root)))
        self.comm.keep_statistics_once(self.strategy)
        return path

    # -- one step -------------------------------------------------------------------------------
    def view_generator(self, index: int) -> torch.Generator:
        """The random source of view ``index`` of the current step (encoder views, rendered offsets).

        Derived from the seed, the step and the view's place in the batch alone, so whichever rank
        renders the view draws the same numbers.
        """
        return torch.Generator().manual_seed(hash((self.config.train.seed, self.step, index)) & (2**63 - 1))

    def _schedule_position(self, steps_done: int) -> float:
        """Where the schedules stand after ``steps_done`` steps (:func:`.schedule.schedule_position`)."""
        return schedule_position(self.config, steps_done, self.elapsed)

    def schedule_step(self) -> int:
        """The step the schedules read while running step :attr:`step` (:meth:`_schedule_position`)."""
        return int(self._schedule_position(self.step))

    def progress(self) -> float:
        """How far the training is, 0 to 1 (:meth:`_schedule_position` over ``train.steps``)."""
        return self._schedule_position(self.step) / self.config.train.steps

    def _render_view(self, frame, index: int) -> ViewResult:
        """Render view ``index`` of the step (training image ``frame``) and score it."""
        return self.views.render(frame, self.schedule_step(), self.view_generator(index),
                                 image_scale(self.config, self.progress()))

    def _trainable(self) -> list[torch.Tensor]:
        """Every parameter an optimiser steps, in the same order on every rank."""
        params = [p for group in self.optimizer.param_groups for p in group["params"] if p.requires_grad]
        if self.mogaface is not None:
            params += [p for group in self.mogaface.optimizer.param_groups for p in group["params"]]
        return params

    def train_step(self) -> dict:
        """Run step ``self.step`` (0-based) and advance; returns its losses and what densification did.

        A render cancelled by a signal (``RenderCancelled``) abandons the step before anything is
        updated; what it drew from the random sampler is put back, so a checkpoint written then
        equals the one an uninterrupted run writes at this step.
        """
        drawn = (self.generator.get_state(), self.frame_order.state())
        try:
            return self._run_step()
        except RenderCancelled:
            self.generator.set_state(drawn[0])
            self.frame_order.load_state(drawn[1])
            self.optimizer.zero_grad(set_to_none=True)
            raise

    def _run_step(self) -> dict:
        """The step itself (see :meth:`train_step`).

        A step scores ``train.batch`` training images (their mean loss); with several ranks each
        renders its share and the gradients are summed over the ranks before the optimiser step.
        """
        cfg = self.config
        comm = self.comm
        gaussians = self.avatar.gaussians
        at = self.schedule_step()
        rates = rates_at(cfg, self.extent, at)
        for group in self.optimizer.param_groups:
            if group["name"] in rates:
                group["lr"] = rates[group["name"]]
        gaussians.active_sh_degree = self.strategy.schedule.sh_degree(at)
        batch = cfg.train.batch
        frames = [self.data.frames[self.frame_order.next(self.generator)] for _ in range(batch)]
        names = self.views.terms.names  # the same on every rank, one without a view included
        views = {j: self._render_view(frames[j], j) for j in comm.share(batch)}
        settling = self.camera_offsets is not None and cameras_settling(cfg, at)
        after = int(self._schedule_position(self.step + 1))  # where the schedules stand once this step is done
        sums = torch.zeros(len(names), dtype=torch.float64)
        if views:
            total = sum(view.losses["loss"] for view in views.values()) / batch
            total.backward()
            self.views.step_done()
            for view in views.values():
                values = view.logged()
                sums += torch.tensor([values[name] for name in names], dtype=torch.float64)
                if not settling:  # settling, the Gaussians hold still: their densification statistics too
                    view.observe(self.strategy, after, batch)
        sums = comm.reduce_step(self._trainable(), sums)
        hold_still(self.optimizer, cfg, at, settling)
        self.optimizer.step()
        self.optimizer.zero_grad(set_to_none=True)
        if not settling:  # the MCMC noise follows the position rate's decay (none where positions do not learn)
            first = rates_at(cfg, self.extent, 0)["local_position"]
            self.strategy.perturb(gaussians, rates["local_position"] / first if first else 0.0, self.generator)
        for part in (p for p in (self.camera_offsets, self.camera_colours) if p is not None):
            part.fix_gauge()
        if self.mogaface is not None:
            if settling:
                self.mogaface.optimizer.zero_grad(set_to_none=True)
            else:
                self.mogaface.optimizer_step()
            records = torch.zeros(batch, self.mogaface.record_size())
            for j, view in views.items():
                records[j] = self.mogaface.record(view.correction)
            for record in comm.reduce_rows(records):
                self.mogaface.commit(record)
        self.step += 1
        report = {}
        schedule = self.strategy.schedule
        due = schedule.passes_between(self._scheduled_through, after)  # one step's, or a time budget's
        self._scheduled_through = max(self._scheduled_through, after)
        for passed in [] if settling else due:
            if schedule.densifies_at(passed):
                comm.reduce_statistics(self.strategy)
            with torch.no_grad():
                # The triangle sizes of the step's first timestep, tracked pose: the same on every rank.
                vertices = self.avatar.posed_vertices(self.table.params(frames[0].timestep_index))
                face_scale = triangle_frames(vertices, self.avatar.flame.faces).scale
                report.update(self.strategy.after_step(passed, gaussians, self.optimizer, face_scale, self.extent,
                                                       self.generator))
        values = dict(zip(names, (sums / batch).tolist()))
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
        if self.comm.world == 1:  # ranks must finish a step together: they stop between steps
            cancel.arm((signal.SIGINT, signal.SIGTERM))

    def run(self, until: int | None = None) -> dict:
        """Train to step ``until`` (default: the configured steps), then write the results.

        Returns ``{"step", "stopped" (signal number or None), "complete"}``. A run stopped by a
        signal or by ``until`` ends with a checkpoint; a complete one also writes the avatar,
        FLAME parameters, run.json and (when configured) the val metrics. A run that uses up
        ``train.max_minutes`` of training time finishes early as if complete; under
        ``train.schedule = "minutes"`` only the time (or a signal, or ``until``) ends it.
        """
        cfg = self.config.train
        by_minutes = cfg.schedule == "minutes"
        last_step = math.inf if by_minutes else cfg.steps
        end = last_step if until is None else min(until, last_step)
        self.events.emit("resume" if self.step else "start", step=self.step, steps=cfg.steps,
                         gaussians=len(self.avatar.gaussians), extent=self.extent,
                         frames=len(self.data.frames), timesteps=len(self.data.timesteps))
        window_start, window_steps = time.monotonic(), 0
        first_window = True  # its pace includes numba's compilation and the first loads: no ETA from it
        last = time.monotonic()
        budget = cfg.max_minutes * 60 if cfg.max_minutes > 0 else math.inf
        out_of_time = False
        if self.lock is not None:
            self.lock.acquire()
        try:
            while self.step < end:
                # Every rank stops at the same step: a signal to any, or rank 0's clock.
                # Rank 0's training time too: the schedules read it, so every rank must read the same.
                signum, timed, clock = self.comm.agree([self._stop_signal or 0,
                                                        float(self.comm.is_writer and self.elapsed >= budget),
                                                        self.elapsed if self.comm.is_writer else 0.0])
                self.elapsed = clock
                if signum:
                    self._stop_signal = int(signum)
                    break
                if timed:
                    out_of_time = True
                    break
                try:
                    result = self.train_step()
                except RenderCancelled:
                    if self._stop_signal is None:  # only a signal sets the flag
                        raise
                    break
                now = time.monotonic()
                self.elapsed += now - last
                last = now
                window_steps += 1
                if result["densify"]:
                    self.events.emit("densify", step=self.step, **result["densify"])
                if self.step % cfg.log_every == 0 or self.step == end:
                    rate = window_steps / max(now - window_start, 1e-9)
                    # under a schedule in minutes, the steps the whole budget will make at this pace
                    steps = round(self.step / max(self.progress(), 1e-9)) if by_minutes else cfg.steps
                    budget_left = max(budget - self.elapsed, 0.0)
                    eta = budget_left if by_minutes else min((cfg.steps - self.step) / max(rate, 1e-9), budget_left)
                    self.events.emit("iter", step=self.step, steps=max(steps, self.step), **result["losses"],
                                     gaussians=len(self.avatar.gaussians),
                                     sh_degree=self.avatar.gaussians.active_sh_degree,
                                     lr_position=rates_at(self.config, self.extent, self.schedule_step())["local_position"],
                                     it_s=rate, eta_s=None if first_window else eta,
                                     elapsed_s=self.elapsed)
                    window_start, window_steps, first_window = now, 0, False
                if self.config.eval.every and self.step % self.config.eval.every == 0 and self.comm.is_writer:
                    try:
                        self._quick_check()
                    except RenderCancelled:
                        break
                    last = time.monotonic()
                if cfg.checkpoint_every and self.step % cfg.checkpoint_every == 0 and self.step < last_step:
                    self.checkpoint()
            if self._stop_signal is not None or (self.step < last_step and not out_of_time):
                self.checkpoint()
                self.comm.wait_for_writer()
                if self._stop_signal is not None:
                    self.events.emit("stopped", step=self.step, signal=signal.Signals(self._stop_signal).name)
                return {"step": self.step, "stopped": self._stop_signal, "complete": False}
            if out_of_time:
                self.events.emit("time_limit", step=self.step, elapsed_s=self.elapsed)
            self.checkpoint()
            if self.comm.is_writer:
                try:
                    self.finish()
                except RenderCancelled:  # a signal during the final evaluation: the checkpoint holds the run
                    if self._stop_signal is None:
                        raise
                    self.events.emit("stopped", step=self.step, signal=signal.Signals(self._stop_signal).name)
                    return {"step": self.step, "stopped": self._stop_signal, "complete": False}
            self.comm.wait_for_writer()
            return {"step": self.step, "stopped": None, "complete": True}
        except MogafaceError:
            if self.comm.world == 1:  # ranks checkpoint together; a lone rank's error must not wait on them
                self.checkpoint()  # bad data met mid-run (a corrupt image): keep the steps done so far
            raise
        finally:
            self.events.close()
            if self.lock is not None:
                self.lock.release()

    def _set_sh_degree(self) -> None:
        """The SH degree the schedule gives now: what a checkpoint, a check or the final avatar holds."""
        self.avatar.gaussians.active_sh_degree = self.strategy.schedule.sh_degree(self.schedule_step())

    def current_avatar(self):
        """``(table, avatar)`` as the run would write them at this step (:func:`.results.written_avatar`)."""
        self._set_sh_degree()
        return written_avatar(self.mogaface, self.avatar, self.table)

    def _quick_check(self) -> None:
        table, avatar = self.current_avatar()
        self.outputs.quick_check(avatar, table, self.step, self.events)

    def finish(self) -> None:
        """Write the final avatar, the FLAME parameters used, run.json and the quick val metrics."""
        self._set_sh_degree()
        self.outputs.write_final(self.avatar, self.table, self.mogaface, self._camera_parts(), self.step, self.elapsed,
                                 self.events)
