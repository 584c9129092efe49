"""``mogaface.improve_tracking`` and ``mogaface.improve_tracking_cancel``: the run's multi-view
refiner improves the tracking of every timestep of its capture, in a separate process
(``python -m mogaface refine-tracking RUN``, the refiner trained first when the run has none);
the refined ``flame_param`` folder is then keyed on the head exactly as Import Tracking keys one.
Cancel stops the child; the previous refined folder and the head's keys stay as they were.
"""

from __future__ import annotations

import os

import bpy
from bpy.props import IntProperty, StringProperty

from ..core.run.names import AVATAR_FILE
from .common import dependencies_ready
from .dependencies import interpreter, worker_paths
from .handlers.heads import is_head
from .import_tracking import existing_keys, head_or_report, key_tracking
from .jobs import FollowsChildJob, cancel_operator, end_job, job_progress, new_job, refuse_if_busy
from .train import preferred_threads

#: The one running tracking improvement, and the head its result will be keyed on.
_job = new_job("improving the tracking")


def current_worker():
    return _job["worker"]


def last_progress():
    return job_progress(_job)


def folder_to_key(folders: list[str], out: str, capture: str, tracking: str) -> str:
    """Of the refined folders (one per sequence of a union capture), the one in the place the
    scene's tracking folder has in the capture; else the first."""
    if tracking and capture:
        wanted = os.path.relpath(os.path.normpath(tracking), os.path.normpath(capture))
        for folder in folders:
            if os.path.relpath(folder, out) == wanted:
                return folder
    return folders[0]


class MOGAFACE_OT_improve_tracking(FollowsChildJob, bpy.types.Operator):
    """Refine the tracking of every timestep from the capture's views with the run's refiner, then
    key the head with it (a separate process; trains the refiner first when the run has none)"""

    bl_idname = "mogaface.improve_tracking"
    bl_label = "Improve Tracking"
    bl_options = {"REGISTER", "UNDO"}

    run: StringProperty(name="Run", subtype="DIR_PATH", description="Trained run folder (empty: the scene's)")
    out: StringProperty(name="Output", subtype="DIR_PATH",
                        description="Folder for the refined tracking (empty: the run's refined_tracking)")
    target: StringProperty(name="Head", description="Head object to key (empty: the active object)")
    passes: IntProperty(name="Passes", default=1, min=1, max=10, description="Refiner passes per timestep")
    views: IntProperty(name="Views", default=4, min=1, max=64, description="Views per timestep, spread over the rig")
    fit_steps: IntProperty(name="Fitting Steps", default=0, min=0, max=200,
                           description="Then fit each timestep whose parameters training did not fit to all "
                                       "its views from the refiner's answer: one to two seconds per timestep; it "
                                       "read the expression slightly better and the pose worse (0: none)")
    python: StringProperty(name="Python", subtype="FILE_PATH", options={"HIDDEN", "SKIP_SAVE"},
                           description="Interpreter for the child process (empty: the preferences')")

    label, tag = "improving the tracking", "improve-tracking"

    def _target(self, context):
        return bpy.data.objects.get(self.target) if self.target else context.active_object

    def invoke(self, context, event):
        obj = self._target(context)
        count = existing_keys(obj) if is_head(obj) else 0
        if count:
            return context.window_manager.invoke_confirm(
                self, event, title="Replace Keyframes?", confirm_text="Improve",
                message=f"{obj.name} has {count} keyframes on its expressions and pose; the improved tracking "
                        "replaces them when it is done")
        return self.execute(context)

    def execute(self, context):
        if refuse_if_busy(self):
            return {"CANCELLED"}
        obj = self._target(context)
        if not head_or_report(self, obj) or not dependencies_ready(self, context):
            return {"CANCELLED"}
        run = bpy.path.abspath(self.run or context.scene.mogaface.run_folder)
        if not run or not os.path.isfile(os.path.join(run, AVATAR_FILE)):
            self.report({"ERROR"}, f"{run or 'The scene has no run folder'}: not a finished run (no avatar.pt); "
                                   "train one first")
            return {"CANCELLED"}
        from ..core.for_blender.worker import RefineTrackingWorker, refine_tracking_command

        python = bpy.path.abspath(self.python) if self.python else interpreter(context)
        out = bpy.path.abspath(self.out) if self.out else None
        command = refine_tracking_command(python, run, out=out, passes=self.passes, views=self.views,
                                          fit_steps=self.fit_steps, threads=preferred_threads(context),
                                          paths=worker_paths(python))
        worker = RefineTrackingWorker(command, run)
        try:
            worker.start()
        except OSError as error:
            self.report({"ERROR"}, f"Cannot start {command[0]}: {error.strerror or error}")
            return {"CANCELLED"}
        self.target = obj.name  # the head to key, whatever is active when the job ends
        _job["worker"], _job["last"] = worker, None
        return self.follow(context, worker)

    def finished(self, context, progress) -> set:
        worker = end_job(_job, progress)
        if progress.state != "done":
            self.report({"WARNING"} if progress.state == "cancelled" else {"ERROR"},
                        f"Improving the tracking: {progress.message}")
            return {"CANCELLED"}
        done = next(e for e in reversed(worker.events) if e.get("event") == "done")
        settings = context.scene.mogaface
        folder = folder_to_key(done["folders"], done["path"], bpy.path.abspath(settings.capture_folder),
                               bpy.path.abspath(settings.tracking_folder))
        obj = bpy.data.objects.get(self.target)
        if not is_head(obj):
            self.report({"ERROR"}, f"The head {self.target} is gone; the improved tracking is in {folder}")
            return {"CANCELLED"}
        if not key_tracking(self, context, obj, folder):
            return {"CANCELLED"}
        self.report({"INFO"}, f"Improving the tracking {progress.message}: {folder}")
        return {"FINISHED"}


MOGAFACE_OT_improve_tracking_cancel = cancel_operator(
    "mogaface.improve_tracking_cancel", "Cancel Improving",
    "Stop improving the tracking: the head's keys and any earlier result stay as they were",
    current_worker, "Stopping the tracking improvement",
)
