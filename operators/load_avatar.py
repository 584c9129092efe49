"""``mogaface.load_avatar``: link a trained avatar to a head object.

A trained avatar is linked to a head object (its path is a custom property of the head); it
loads in a thread, so Blender stays usable while torch imports and the file is read.
"""

from __future__ import annotations

import os

import bpy
from bpy.props import StringProperty

from .avatar_head import BACKGROUND_PROPERTY
from .common import OpensFileBrowser, clear_status_text, dependencies_ready, redraw_areas, run_core
from .handlers.heads import AVATAR_PATH_PROPERTY, is_head


def _located_avatar(path: str):
    """The avatar file, its training background and the loaded avatar (thread-safe core work)."""
    from ..core.for_blender.avatar import avatar_location, load_avatar
    from .dependencies import preload_native_libraries

    preload_native_libraries()  # the first load imports torch: its libraries, without the GIL
    found, background = avatar_location(path)
    return found, background, load_avatar(found)


class MOGAFACE_OT_load_avatar(OpensFileBrowser, bpy.types.Operator):
    """Link a trained avatar (run folder or avatar.pt) to a head, for rendering and export.
    It loads in the background; Blender stays usable"""

    bl_idname = "mogaface.load_avatar"
    bl_label = "Load Avatar"
    bl_options = {"REGISTER", "UNDO"}

    filepath: StringProperty(name="Avatar", subtype="FILE_PATH", description="Run folder or avatar.pt")
    target: StringProperty(name="Head", description="Head object (empty: the active object)")

    _timer = None
    _future = None

    def execute(self, context):
        obj = bpy.data.objects.get(self.target) if self.target else context.active_object
        if not is_head(obj):
            self.report({"ERROR"}, f"{self.target or getattr(obj, 'name', 'nothing')} is not a MoGaFace head")
            return {"CANCELLED"}
        if not dependencies_ready(self, context):
            return {"CANCELLED"}
        self.target = obj.name
        path = bpy.path.abspath(self.filepath)
        if bpy.app.background or context.window is None:  # timers never run headless: load here
            return self._link(context, run_core(self, _located_avatar, path))
        from .common import background_thread

        # Reading the file and importing torch take seconds: a thread does it, a timer collects it.
        self._future = background_thread("render").submit(_located_avatar, path)
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.05, window=context.window)
        wm.modal_handler_add(self)
        context.workspace.status_text_set(f"MoGaFace: loading the avatar {os.path.basename(path.rstrip(os.sep))}")
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type != "TIMER" or not self._future.done():
            return {"PASS_THROUGH"}
        context.window_manager.event_timer_remove(self._timer)
        clear_status_text()
        return self._link(context, run_core(self, self._future.result))

    def _link(self, context, loaded) -> set:
        """Link a loaded avatar to the head (main thread), or report why not."""
        obj = bpy.data.objects.get(self.target)
        if loaded is None:
            return {"CANCELLED"}
        if not is_head(obj):
            self.report({"ERROR"}, f"{self.target} was removed while its avatar loaded")
            return {"CANCELLED"}
        path, background, avatar = loaded
        vertices = avatar.flame.n_vertices
        if vertices != len(obj.data.vertices):
            self.report({"ERROR"}, f"{path}: the avatar's head has {vertices} vertices, {obj.name} has "
                        f"{len(obj.data.vertices)}: import the avatar's head model (head.pkl beside it)")
            return {"CANCELLED"}
        obj[AVATAR_PATH_PROPERTY] = str(path)
        obj[BACKGROUND_PROPERTY] = list(background)
        from .handlers.viewport import display_for_avatar

        display_for_avatar(obj)  # the avatar is drawn in the viewport; the mesh would cover it
        context.scene.mogaface.avatar_file = str(path)
        redraw_areas(context, ("VIEW_3D", "PROPERTIES"))
        self.report({"INFO"}, f"{obj.name}: avatar with {len(avatar.gaussians)} Gaussians")
        return {"FINISHED"}
