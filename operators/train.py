"""``mogaface.train`` and ``mogaface.train_cancel``: training in a separate process.

The child is ``python -m mogaface train`` with the interpreter from the preferences; its
progress is read by the core's :class:`~mogaface.core.for_blender.worker.TrainWorker`. In the UI a modal
operator polls it from a timer (Blender never blocks); in background mode, where timers and
modal operators never run, the same poll runs in a blocking loop. Cancel sends SIGINT, and the
trainer writes a checkpoint before it exits.
"""

from __future__ import annotations

import os

import bpy
from bpy.props import EnumProperty, FloatProperty, IntProperty, StringProperty

from ..core.run.names import AVATAR_FILE
from .common import dependencies_ready
from .dependencies import interpreter, top_package, worker_paths
from .jobs import FollowsChildJob, cancel_operator, end_job, job_progress, new_job, refuse_if_busy

#: Training presets (core.train.presets.PRESETS) offered in the UI, with a one-line description each.
PRESET_ITEMS = (
    ("quick", "Quick", "Smoke run: 200 steps, a minute or two"),
    ("demo", "Demo", "1000 steps, a few minutes: a recognisable avatar"),
    ("full", "Full", "The defaults: about 15 minutes on two cores at 256 px"),
    ("mogaface", "MoGaFace", "The full MoGaFace method (correction, bank, texture attention), default length"),
    ("mogaface-demo", "MoGaFace Demo", "The full MoGaFace method at the demo's length"),
)

#: The one running training (the UI trains one run at a time).
_job = new_job("training")


def current_worker():
    """The running training worker, or None."""
    return _job["worker"]


def last_progress():
    """The :class:`Progress` of the running or last finished training, or None."""
    return job_progress(_job)


def _preference(context, name: str, default):
    addon = context.preferences.addons.get(top_package())
    return getattr(getattr(addon, "preferences", None), name, default) if addon else default


def preferred_threads(context) -> int | None:
    """CPU threads for a child process: the preferences' count, None (the command's default) for 0."""
    addon = context.preferences.addons.get(top_package())
    threads = getattr(getattr(addon, "preferences", None), "threads", 0) if addon else 0
    return threads or None


def finish_job(operator, progress, settings=None) -> set:
    """Report how a training ended and forget it; the operator's return value. A finished run's
    avatar goes into the scene's Avatar field (``settings``: ``scene.mogaface``)."""
    worker = end_job(_job, progress)
    if progress.state == "done" and settings is not None and worker is not None:
        avatar = worker.run / AVATAR_FILE
        if avatar.exists():
            settings.avatar_file = str(avatar)
    if progress.state == "done":  # what the run could not do (say, score LPIPS) is a warning, not a failure
        operator.report({"WARNING"} if progress.warnings else {"INFO"}, f"Training {progress.message}")
        return {"FINISHED"}
    if progress.state == "cancelled":
        operator.report({"WARNING"}, f"Training {progress.message}")
        return {"CANCELLED"}
    operator.report({"ERROR"}, progress.message)
    return {"CANCELLED"}


class MOGAFACE_OT_train(FollowsChildJob, bpy.types.Operator):
    """Train an avatar on a capture in a separate process, showing its progress"""

    bl_idname = "mogaface.train"
    bl_label = "Train"
    bl_options = {"REGISTER"}

    capture: StringProperty(name="Capture", subtype="DIR_PATH", description="Capture folder (empty: the scene's)")
    run: StringProperty(name="Run", subtype="DIR_PATH", description="Run folder (empty: the scene's)")
    preset: EnumProperty(name="Preset", default="demo", items=PRESET_ITEMS)
    steps: IntProperty(name="Steps", default=0, min=0, description="Total steps (0: the preset's)")
    minutes: FloatProperty(name="Minutes", default=0.0, min=0.0,
                           description="Train for this many minutes, the whole schedule run through them (0: the steps)")
    seed: IntProperty(name="Seed", default=-1, min=-1, description="Random seed (-1: the scene's)")
    camera_rounds: IntProperty(name="Camera Rounds", default=-1, min=-1, max=16,
                               description="Rounds of camera refinement (-1: the scene's; 0: none)")
    python: StringProperty(name="Python", subtype="FILE_PATH", options={"HIDDEN", "SKIP_SAVE"},
                           description="Interpreter for the training process (empty: the preferences')")
    resume: EnumProperty(
        name="Start", default="AUTO",
        items=(("AUTO", "Auto", "Resume when the run folder has a checkpoint"),
               ("NEW", "New", "Start a new run"), ("RESUME", "Resume", "Continue from the latest checkpoint")),
    )

    label, tag = "training", "train"

    def _start(self, context):
        if refuse_if_busy(self):
            return None
        if not dependencies_ready(self, context):
            return None
        from ..core.for_blender.launcher import launcher_arguments
        from ..core.for_blender.worker import TrainWorker, train_command

        settings = context.scene.mogaface
        capture = bpy.path.abspath(self.capture or settings.capture_folder)
        run = bpy.path.abspath(self.run or settings.run_folder)
        if not capture or not run:
            self.report({"ERROR"}, "Set the capture folder and the run folder first")
            return None
        from ..core.train.checkpoint import resumable

        resume = self.resume == "RESUME" or (self.resume == "AUTO" and resumable(run))
        steps = self.steps or None
        python = bpy.path.abspath(self.python) if self.python else interpreter(context)
        launcher = _preference(context, "launcher", "")  # e.g. torchrun --nproc_per_node 2
        command = train_command(
            python, capture, run, preset=self.preset, steps=steps,
            seed=settings.seed if self.seed < 0 else self.seed, threads=preferred_threads(context), resume=resume,
            camera_rounds=settings.camera_rounds if self.camera_rounds < 0 else self.camera_rounds,
            cameras_from_landmarks=settings.cameras_from_landmarks,
            centres_measured=settings.camera_centres_measured, camera_delays=settings.camera_delays,
            minutes=self.minutes, paths=worker_paths(python), extra=launcher_arguments(launcher, resume),
        )
        from ..core.for_blender.launcher import with_launcher

        command = with_launcher(command, launcher)
        os.makedirs(run, exist_ok=True)
        worker = TrainWorker(command, run)
        try:
            worker.start()
        except OSError as error:
            self.report({"ERROR"}, f"Cannot start {command[0]}: {error.strerror or error}")
            return None
        settings.run_folder = run
        _job["worker"], _job["last"] = worker, None
        return worker

    def execute(self, context):
        worker = self._start(context)
        if worker is None:
            return {"CANCELLED"}
        return self.follow(context, worker)

    def invoke(self, context, event):
        return self.execute(context)

    def finished(self, context, progress) -> set:
        return finish_job(self, progress, context.scene.mogaface)


MOGAFACE_OT_train_cancel = cancel_operator(
    "mogaface.train_cancel", "Cancel Training",
    "Stop the running training cleanly: it writes a checkpoint, and can be resumed later",
    current_worker, "Stopping training after a checkpoint",
)
