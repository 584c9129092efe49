"""Long work followed from Blender without freezing it: child processes, frame renders, Cancel buttons.

A child job (training, improving the tracking) is a dict ``{"worker": running worker or None,
"last": Progress of the last finished one}``; each kind has one, and the UI runs one such job at
a time, of any kind: each takes every core it is given, and improving the tracking reads the run
that a training may be rewriting. :class:`FollowsChildJob` follows a started worker: from a timer
in the UI (Blender never blocks), in a blocking loop in background mode, where timers and modal
handlers never run.

A :class:`RenderJob` renders a range of frames: reading a frame's values needs
``scene.frame_set`` (main thread only); the render itself is pure core work, so it runs in a
worker thread while Blender keeps drawing. It is stepped by its caller: from a modal operator's
timer in the UI, in a blocking loop in background mode. The same ``step`` serves both.

:func:`cancel_operator` makes the one kind of Cancel button every job has.
"""

from __future__ import annotations

import time

import bpy

from .common import background_thread, clear_status_text, redraw_areas

#: Every kind's job, by the label that names it in messages.
_jobs: dict[str, dict] = {}


def new_job(label: str) -> dict:
    job = {"worker": None, "last": None}
    _jobs[label] = job
    return job


def refuse_if_busy(operator) -> bool:
    """Report the running job, if any (True: the caller must not start another)."""
    for label, job in _jobs.items():
        if job["worker"] is not None:
            operator.report({"ERROR"}, f"{label[0].upper()}{label[1:]} is running: wait for it or cancel it first")
            return True
    return False


def job_progress(job: dict):
    """The :class:`Progress` of the running or last finished job, or None."""
    worker = job["worker"]
    return worker.progress if worker is not None else job["last"]


def end_job(job: dict, progress):
    """Forget the running worker, keep its progress; returns the worker."""
    worker = job["worker"]
    job["last"], job["worker"] = progress, None
    return worker


def cancel_and_wait(job: dict, timeout: float = 30) -> None:
    """Cancel a running job and wait for it (the extension is being disabled); its progress
    leaves the status bar."""
    worker = job["worker"]
    if worker is not None:
        clear_status_text()
        worker.cancel()
        try:
            worker.wait(interval=0.1, timeout=timeout)
        finally:
            worker.kill()
            job["worker"] = None


def cancel_child_jobs(timeout: float = 30) -> None:
    """Cancel every running child job and wait for it (the extension is being disabled): a
    training writes its checkpoint; no child outlives the extension."""
    for job in _jobs.values():
        cancel_and_wait(job, timeout)


class FollowsChildJob:
    """Mixin of an operator that starts a worker: ``follow`` it, then ``finished(context, progress)``
    (the operator's own) reports how it ended and returns the operator's result."""

    label = "job"  # in the status bar: "MoGaFace training: step 3/10"
    tag = "job"  # before each headless progress line: "[train] step 3/10"

    _timer = None
    _worker = None

    def follow(self, context, worker) -> set:
        if bpy.app.background or context.window is None:
            def show(progress):
                print(f"[{self.tag}] {progress.text()}", flush=True)

            return self.finished(context, worker.wait(interval=0.2, on_progress=show))
        self._worker = worker
        self._timer = context.window_manager.event_timer_add(0.5, window=context.window)
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        progress = self._worker.poll()
        context.workspace.status_text_set(f"MoGaFace {self.label}: {progress.text()}")
        redraw_areas(context)
        if not progress.finished:
            return {"PASS_THROUGH"}
        context.window_manager.event_timer_remove(self._timer)
        context.workspace.status_text_set(None)
        result = self.finished(context, progress)
        redraw_areas(context)
        return result


def cancel_operator(idname: str, label: str, description: str, running, message: str | None = None,
                    options=frozenset({"REGISTER"})):
    """An operator class ``idname`` that cancels the job ``running()`` returns (available while
    it returns one), reporting ``message``; every job's Cancel button is one of these."""

    def poll(cls, context):
        return running() is not None

    def execute(self, context):
        running().cancel()
        if message:
            self.report({"INFO"}, message)
        return {"FINISHED"}

    prefix, name = idname.split(".")
    return type(f"{prefix.upper()}_OT_{name}", (bpy.types.Operator,), {
        "__doc__": description, "__module__": __name__, "bl_idname": idname, "bl_label": label,
        "bl_options": set(options), "poll": classmethod(poll), "execute": execute,
    })


class RenderJob:
    """Render ``frames`` one after another.

    ``make_request(frame)`` builds a core :class:`RenderRequest` (main thread); ``on_result(result)``
    stores a finished render (main thread). ``error`` holds the message of a render that failed.
    """

    def __init__(self, frames, make_request, on_result, render=None):
        from ..core.for_blender.render import render as core_render

        self.frames = list(frames)
        self.done = 0
        self.error: str | None = None
        self.cancelled = False
        self._make_request = make_request
        self._on_result = on_result
        self._render = render or core_render
        self._future = None

    @property
    def fraction(self) -> float:
        return self.done / len(self.frames) if self.frames else 1.0

    @property
    def finished(self) -> bool:
        return self._future is None and (self.cancelled or self.error is not None or self.done == len(self.frames))

    def text(self) -> str:
        return f"frame {self.done}/{len(self.frames)}"

    def cancel(self) -> None:
        """Stop after the frame being rendered (its result is dropped)."""
        self.cancelled = True

    def step(self) -> bool:
        """Collect a finished render and start the next; True while the job is not finished."""
        from ..core.errors import MogafaceError

        if self._future is not None and self._future.done():
            future, self._future = self._future, None
            try:
                result = future.result()
            except (MogafaceError, OSError) as error:
                self.error = str(error)
            else:
                if not self.cancelled:
                    self._on_result(result)
                    self.done += 1
        if self._future is None and not self.finished:
            try:
                request = self._make_request(self.frames[self.done])
            except (MogafaceError, OSError) as error:
                self.error = str(error)
            else:
                self._future = background_thread("render").submit(self._render, request)
        return not self.finished

    def run(self, interval: float = 0.005, on_progress=None) -> "RenderJob":
        """Step until finished (background mode)."""
        while self.step():
            if on_progress is not None:
                on_progress(self)
            time.sleep(interval)
        return self
