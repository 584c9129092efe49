"""``mogaface.train`` and ``mogaface.train_cancel``: training in a separate process.

The child is ``python -m mogaface train`` with the interpreter from the preferences; its
progress is read by the core's :class:`~mogaface.core.worker.TrainWorker`. In the UI a modal
operator polls it from a timer (Blender never blocks); in background mode, where timers and
modal operators never run, the same poll runs in a blocking loop. Cancel sends SIGINT, and the
trainer writes a checkpoint before it exits.
"""

from __future__ import annotations

import os

import bpy
from bpy.props import EnumProperty, IntProperty, StringProperty

from .common import clear_status_text, core_or_report, redraw_areas
from .dependencies import interpreter, top_package, worker_paths

#: Training presets (core.train.config.PRESETS) offered in the UI, with a one-line description each.
PRESET_ITEMS = (
    ("quick", "Quick", "Smoke run: 200 steps, a minute or two"),
    ("demo", "Demo", "1000 steps, a few minutes: a recognisable avatar"),
    ("full", "Full", "The defaults: about 15 minutes on two cores at 256 px"),
    ("mogaface", "MoGaFace", "The full MoGaFace method (correction, bank, texture attention), default length"),
    ("mogaface-demo", "MoGaFace Demo", "The full MoGaFace method at the demo's length"),
)

#: The one running job (the UI trains one run at a time): a TrainWorker, or None.
_job = {"worker": None, "last": None}


def current_worker():
    """The running training worker, or None."""
    return _job["worker"]


def last_progress():
    """The :class:`Progress` of the running or last finished job, or None."""
    worker = _job["worker"]
    return worker.progress if worker is not None else _job["last"]


def _preference(context, name: str, default):
    addon = context.preferences.addons.get(top_package())
    return getattr(getattr(addon, "preferences", None), name, default) if addon else default


def _threads(context) -> int | None:
    addon = context.preferences.addons.get(top_package())
    threads = getattr(getattr(addon, "preferences", None), "threads", 0) if addon else 0
    return threads or None


def finish_job(operator, progress, settings=None) -> set:
    """Report how a job ended and forget it; the operator's return value. A finished run's
    avatar goes into the scene's Avatar field (``settings``: ``scene.mogaface``)."""
    worker = _job["worker"]
    _job["last"], _job["worker"] = progress, None
    if progress.state == "done" and settings is not None and worker is not None:
        avatar = worker.run / "avatar.pt"
        if avatar.exists():
            settings.avatar_file = str(avatar)
    if progress.state == "done":
        operator.report({"INFO"}, f"Training {progress.message}")
        return {"FINISHED"}
    if progress.state == "cancelled":
        operator.report({"WARNING"}, f"Training {progress.message}")
        return {"CANCELLED"}
    operator.report({"ERROR"}, progress.message)
    return {"CANCELLED"}


def cancel_running_job() -> None:
    """Cancel a running job and wait for its checkpoint (used when the extension is disabled);
    its progress leaves the status bar."""
    worker = _job["worker"]
    if worker is not None:
        clear_status_text()
        worker.cancel()
        try:
            worker.wait(interval=0.1, timeout=30)
        finally:
            worker.kill()
            _job["worker"] = None


class MOGAFACE_OT_train(bpy.types.Operator):
    """Train an avatar on a capture in a separate process, showing its progress"""

    bl_idname = "mogaface.train"
    bl_label = "Train"
    bl_options = {"REGISTER"}

    capture: StringProperty(name="Capture", subtype="DIR_PATH", description="Capture folder (empty: the scene's)")
    run: StringProperty(name="Run", subtype="DIR_PATH", description="Run folder (empty: the scene's)")
    preset: EnumProperty(name="Preset", default="demo", items=PRESET_ITEMS)
    steps: IntProperty(name="Steps", default=0, min=0, description="Total steps (0: the preset's)")
    seed: IntProperty(name="Seed", default=-1, min=-1, description="Random seed (-1: the scene's)")
    python: StringProperty(name="Python", subtype="FILE_PATH", options={"HIDDEN", "SKIP_SAVE"},
                           description="Interpreter for the training process (empty: the preferences')")
    resume: EnumProperty(
        name="Start", default="AUTO",
        items=(("AUTO", "Auto", "Resume when the run folder has a checkpoint"),
               ("NEW", "New", "Start a new run"), ("RESUME", "Resume", "Continue from the latest checkpoint")),
    )

    _timer = None
    _worker = None

    def _start(self, context):
        if _job["worker"] is not None:
            self.report({"ERROR"}, "A training run is already in progress: cancel it first")
            return None
        if core_or_report(self, context) is None:
            return None
        from ..core.worker import TrainWorker, train_command

        settings = context.scene.mogaface
        capture = bpy.path.abspath(self.capture or settings.capture_folder)
        run = bpy.path.abspath(self.run or settings.run_folder)
        if not capture or not run:
            self.report({"ERROR"}, "Set the capture folder and the run folder first")
            return None
        resume = self.resume == "RESUME" or (
            self.resume == "AUTO" and os.path.exists(os.path.join(run, "checkpoints", "latest"))
            and not os.path.exists(os.path.join(run, "avatar.pt")))
        steps = self.steps or None
        python = bpy.path.abspath(self.python) if self.python else interpreter(context)
        command = train_command(
            python, capture, run, preset=self.preset, steps=steps,
            seed=settings.seed if self.seed < 0 else self.seed, threads=_threads(context), resume=resume,
            paths=worker_paths(python),
        )
        from ..core.launcher import with_launcher

        command = with_launcher(command, _preference(context, "launcher", ""))  # e.g. torchrun --nproc_per_node 2
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
        if bpy.app.background or context.window is None:
            # Timers and modal handlers never run headless: poll in a loop instead.
            def show(progress):
                print(f"[train] {progress.text()}", flush=True)

            return finish_job(self, worker.wait(interval=0.2, on_progress=show), context.scene.mogaface)
        self._worker = worker
        self._timer = context.window_manager.event_timer_add(0.5, window=context.window)
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def invoke(self, context, event):
        return self.execute(context)

    def modal(self, context, event):
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        progress = self._worker.poll()
        context.workspace.status_text_set(f"MoGaFace training: {progress.text()}")
        redraw_areas(context)
        if not progress.finished:
            return {"PASS_THROUGH"}
        context.window_manager.event_timer_remove(self._timer)
        context.workspace.status_text_set(None)
        result = finish_job(self, progress, context.scene.mogaface)
        redraw_areas(context)
        return result


class MOGAFACE_OT_train_cancel(bpy.types.Operator):
    """Stop the running training cleanly: it writes a checkpoint, and can be resumed later"""

    bl_idname = "mogaface.train_cancel"
    bl_label = "Cancel Training"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        return _job["worker"] is not None

    def execute(self, context):
        worker = _job["worker"]
        worker.cancel()
        self.report({"INFO"}, "Stopping training after a checkpoint")
        return {"FINISHED"}
