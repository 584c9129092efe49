"""``mogaface.install_dependencies`` and its Cancel: the core's packages, installed in the background.

The core's :class:`~mogaface.core.for_blender.dependencies.InstallJob` runs pip in a background thread; in
the UI a modal operator polls it from a timer (Blender stays responsive, the panel shows the
progress and a Cancel button); in background mode the same poll runs in a loop. Packages go
into the extension's user folder, which Blender deletes when the extension is removed.
"""

from __future__ import annotations

import bpy

from . import dependencies
from .common import redraw_areas
from .jobs import cancel_operator

OFFLINE_MESSAGE = "Online access is off: allow it in Preferences › System › Network, then try again"

#: The one running install, and the progress of the last finished one.
_install = {"job": None, "last": None}


def current_install():
    """The running :class:`InstallJob`, or None."""
    return _install["job"]


def last_install_progress():
    """The progress of the running or last install, or None."""
    job = _install["job"]
    return job.progress if job is not None else _install["last"]


def cancel_running_install() -> None:
    """Stop a running install (used when the extension is disabled)."""
    job = _install["job"]
    if job is not None:
        job.cancel()
        _install["job"], _install["last"] = None, job.progress


class MOGAFACE_OT_install_dependencies(bpy.types.Operator):
    """Download torch, numba and the other packages MoGaFace needs into the extension's user folder
    (only what this Blender lacks; the CPU build of torch unless the preferences name another index)"""

    bl_idname = "mogaface.install_dependencies"
    bl_label = "Install Dependencies"
    bl_options = {"INTERNAL"}

    _timer = None

    def execute(self, context):
        if _install["job"] is not None:
            self.report({"ERROR"}, "Dependencies are already being installed")
            return {"CANCELLED"}
        if not dependencies.online_access():
            self.report({"ERROR"}, OFFLINE_MESSAGE)
            return {"CANCELLED"}
        target = dependencies.site_packages(create=True)
        if target is None:
            self.report({"ERROR"}, "Only an installed extension has a user folder to install into")
            return {"CANCELLED"}
        from ..core.for_blender.dependencies import DEFAULT_TORCH_INDEX, InstallJob
        from ..core.for_blender.worker import worker_environment

        python = dependencies.interpreter(context)
        index = dependencies.preference(context, "torch_index", DEFAULT_TORCH_INDEX)
        job = InstallJob(python, target, torch_index=index, env=worker_environment()).start()
        _install["job"], _install["last"] = job, None
        if bpy.app.background or context.window is None:
            def show(progress):
                print(f"[install] {progress.message}", flush=True)

            return self._finish(job.wait(on_progress=show))
        self._timer = context.window_manager.event_timer_add(0.5, window=context.window)
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def invoke(self, context, event):
        return self.execute(context)

    def modal(self, context, event):
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        job = _install["job"]
        progress = job.poll() if job is not None else _install["last"]
        redraw_areas(context, ("VIEW_3D", "PREFERENCES"))
        if progress is not None and not progress.finished:
            return {"PASS_THROUGH"}
        context.window_manager.event_timer_remove(self._timer)
        return self._finish(progress)

    def _finish(self, progress) -> set:
        _install["job"], _install["last"] = None, progress
        if progress is None or progress.state == "cancelled":
            self.report({"WARNING"}, "Install Dependencies cancelled; nothing was changed")
            return {"CANCELLED"}
        if progress.state != "done":
            self.report({"ERROR"}, f"Install Dependencies failed: {progress.message}")
            return {"CANCELLED"}
        dependencies.add_site_packages()
        self.report({"INFO"}, progress.message)
        return {"FINISHED"}


MOGAFACE_OT_install_dependencies_cancel = cancel_operator(
    "mogaface.install_dependencies_cancel", "Cancel Install",
    "Stop installing the dependencies; the packages folder stays as it was",
    current_install, "Stopping the installation", options={"INTERNAL"},
)
