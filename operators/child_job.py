"""A job in a child process (training, improving the tracking), followed from Blender.

A job is a dict ``{"worker": running worker or None, "last": Progress of the last finished one}``;
each kind has one, and the UI runs one such job at a time, of any kind: each takes every core it
is given, and improving the tracking reads the run that a training may be rewriting.
:class:`FollowsChildJob` follows a started worker: from a timer in the UI (Blender never blocks),
in a blocking loop in background mode, where timers and modal handlers never run.
"""

from __future__ import annotations

import bpy

from .common import clear_status_text, redraw_areas


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
