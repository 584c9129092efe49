"""``mogaface.export_ply``: the avatar's posed Gaussians (world space) as 3DGS ``.ply`` files."""

from __future__ import annotations

import os

import bpy
from bpy.props import BoolProperty, IntProperty, StringProperty

from .avatar_head import head_params, head_with_avatar
from .common import OpensFileBrowser, run_core
from .handlers.heads import AVATAR_PATH_PROPERTY


class MOGAFACE_OT_export_ply(OpensFileBrowser, bpy.types.Operator):
    """Export the avatar's posed Gaussians (world space) as a 3DGS .ply, for a frame or a range"""

    bl_idname = "mogaface.export_ply"
    bl_label = "Export PLY"
    bl_options = {"REGISTER"}
    suggested_name = "avatar.ply"

    filepath: StringProperty(name="File", subtype="FILE_PATH",
                             description="Output .ply; with a range, the frame number is added to the name")
    filter_glob: StringProperty(default="*.ply", options={"HIDDEN"})
    head: StringProperty(name="Head", description="Head object with an avatar (empty: the active one)")
    use_range: BoolProperty(name="Frame Range", default=False, description="Export every frame of the range")
    frame_start: IntProperty(name="Start", default=0, description="First frame (0: the scene's)")
    frame_end: IntProperty(name="End", default=0, description="Last frame (0: the scene's)")

    def execute(self, context):
        if not self.filepath:
            self.report({"ERROR"}, "No output file given")
            return {"CANCELLED"}
        head = head_with_avatar(self, context, self.head)
        if head is None:
            return {"CANCELLED"}
        from ..core.avatar.export import export_world_ply
        from ..core.for_blender.avatar import load_avatar

        scene = context.scene
        path = bpy.path.abspath(self.filepath)
        if not path.lower().endswith(".ply"):
            path += ".ply"
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        if self.use_range:
            frames = list(range(self.frame_start or scene.frame_start, (self.frame_end or scene.frame_end) + 1))
        else:
            frames = [scene.frame_current]
        current, written = scene.frame_current, []
        try:
            for frame in frames:
                scene.frame_set(frame)
                avatar = run_core(self, load_avatar, head[AVATAR_PATH_PROPERTY])
                if avatar is None:
                    return {"CANCELLED"}
                out = path if not self.use_range else f"{path[:-4]}_{frame:04d}.ply"
                if run_core(self, export_world_ply, avatar, head_params(head, avatar), out) is None:
                    return {"CANCELLED"}
                written.append(out)
        finally:
            scene.frame_set(current)
        self.report({"INFO"}, f"Wrote {written[0]}" if len(written) == 1 else f"Wrote {len(written)} PLY files")
        return {"FINISHED"}
