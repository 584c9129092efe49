"""``mogaface.render_frame``, ``render_animation`` and its Cancel: the avatar into Blender images.

A render reads what the head shows at a frame (expression shape-key values and pose properties,
i.e. what the keyframes give), the active camera converted back to OpenCV, and calls the core's
one render; the image goes into ``bpy.data.images`` (and, if asked, files).
"""

from __future__ import annotations

import bpy
from bpy.props import EnumProperty, IntProperty, StringProperty

from .avatar_head import camera_of, head_request, head_with_avatar
from .common import clear_status_text, redraw_areas, run_core
from .images import show_image, show_image_soon, store_image, write_files
from .jobs import cancel_operator


class _RenderBase:
    head: StringProperty(name="Head", description="Head object with an avatar (empty: the active one)")
    directory: StringProperty(name="Folder", subtype="DIR_PATH", description="Also save files here (empty: none)")
    file_format: EnumProperty(
        name="Files", default="PNG",
        items=(("PNG", "PNG", "8-bit sRGB with alpha"), ("EXR", "EXR", "linear float with alpha"),
               ("BOTH", "Both", "PNG and EXR")),
    )

    def _prepare(self, context):
        camera = context.scene.camera
        if camera is None or camera.type != "CAMERA":
            self.report({"ERROR"}, "The scene has no active camera")
            return None
        head = head_with_avatar(self, context, self.head)
        return None if head is None else (head, camera)

    def _request(self, context, head, camera, frame: int):
        """The request of ``frame`` (main thread: it moves the scene to that frame)."""
        scene = context.scene
        scene.frame_set(frame)
        return head_request(scene, head, camera_of(scene, camera, head), frame)

    def _store(self, camera, result):
        """Put a finished render into its image (and files); returns the image or None."""
        from ..core.for_blender.render import render_image_name

        frame = result.request.frame
        image = store_image(render_image_name(camera.name, frame), result)
        if self.directory:
            written = run_core(self, write_files, self.directory, f"{camera.name}_{frame:04d}".replace(" ", "_"),
                               result, self.file_format)
            if written is None:
                return None
        return image

    def _render(self, context, head, camera, frame: int):
        from ..core.for_blender.render import render

        result = run_core(self, lambda: render(self._request(context, head, camera, frame)))
        return None if result is None else self._store(camera, result)


class MOGAFACE_OT_render_frame(_RenderBase, bpy.types.Operator):
    """Render the avatar at the current frame from the active camera into an image"""

    bl_idname = "mogaface.render_frame"
    bl_label = "Render Frame"
    bl_options = {"REGISTER"}

    def execute(self, context):
        prepared = self._prepare(context)
        if prepared is None:
            return {"CANCELLED"}
        image = self._render(context, *prepared, context.scene.frame_current)
        if image is None:
            return {"CANCELLED"}
        show_image(context, image)
        self.report({"INFO"}, f"Rendered {image.name}")
        return {"FINISHED"}


#: The one running Render Animation job (a RenderJob), for the panel's progress and Cancel.
_animation = {"job": None}


def current_render_job():
    return _animation["job"]


class MOGAFACE_OT_render_animation(_RenderBase, bpy.types.Operator):
    """Render the avatar at every frame of the scene's range from the active camera into images,
    in the background with progress (Esc or Cancel stops it)"""

    bl_idname = "mogaface.render_animation"
    bl_label = "Render Animation"
    bl_options = {"REGISTER"}

    frame_start: IntProperty(name="Start", default=0, description="First frame (0: the scene's)")
    frame_end: IntProperty(name="End", default=0, description="Last frame (0: the scene's)")
    frame_step: IntProperty(name="Step", default=1, min=1)

    _timer = None

    def _job(self, context):
        if _animation["job"] is not None:
            self.report({"ERROR"}, "An animation is already being rendered: cancel it first")
            return None
        prepared = self._prepare(context)
        if prepared is None:
            return None
        head, camera = prepared
        scene = context.scene
        start = self.frame_start or scene.frame_start
        end = self.frame_end or scene.frame_end
        frames = list(range(start, end + 1, self.frame_step))
        if not frames:
            self.report({"ERROR"}, f"Empty frame range {start}..{end}")
            return None
        images = []

        def make_request(frame):  # the keys at that frame: the timeline stays where the user left it
            return head_request(scene, head, camera_of(scene, camera, head), frame, keyed=True)

        def on_result(result):
            image = self._store(camera, result)
            if image is None:
                job.cancel()
            else:
                images.append(image)

        from .jobs import RenderJob

        job = RenderJob(frames, make_request, on_result)
        job.images = images
        _animation["job"] = job
        return job

    def _finish(self, context, job) -> set:
        _animation["job"] = None
        if job.error is not None:
            self.report({"ERROR"}, job.error)
            return {"CANCELLED"}
        if job.images:
            if bpy.app.background or context.window is None:
                show_image(context, job.images[-1])
            else:
                show_image_soon(job.images[-1].name)
        frames = job.frames
        if job.cancelled:
            self.report({"WARNING"}, f"Render cancelled after {job.done} of {len(frames)} frames")
            return {"CANCELLED"}
        self.report({"INFO"}, f"Rendered {len(frames)} frames ({frames[0]}..{frames[-1]})")
        return {"FINISHED"}

    def execute(self, context):
        job = self._job(context)
        if job is None:
            return {"CANCELLED"}
        if bpy.app.background or context.window is None:  # timers never run headless
            return self._finish(context, job.run())
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.05, window=context.window)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def invoke(self, context, event):
        return self.execute(context)

    def modal(self, context, event):
        job = _animation["job"]
        if event.type == "ESC" and job is not None:
            job.cancel()
        if event.type not in ("TIMER", "ESC"):
            return {"PASS_THROUGH"}
        running = job is not None and job.step()
        if running:
            context.workspace.status_text_set(f"MoGaFace rendering: {job.text()} (Esc to cancel)")
            redraw_areas(context)
            return {"PASS_THROUGH"}
        context.window_manager.event_timer_remove(self._timer)
        clear_status_text()
        if job is None:  # finished already
            return {"CANCELLED"}
        return self._finish(context, job)



MOGAFACE_OT_render_cancel = cancel_operator(
    "mogaface.render_cancel", "Cancel Rendering", "Stop rendering the animation after the current frame",
    current_render_job,
)


def cancel_render_job() -> None:
    """Stop a running animation render (the extension is being disabled)."""
    job = _animation["job"]
    if job is not None:
        job.cancel()
        _animation["job"] = None
        clear_status_text()
