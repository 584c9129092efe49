"""``mogaface.import_tracking``: tracked FLAME parameters as keyframes on a head.

Keys the expression shape keys and the pose properties, never the identity, so importing
subject B's tracking onto subject A's head is cross-identity reenactment.
"""

from __future__ import annotations

import bpy
from bpy.props import BoolProperty, StringProperty

from .animation import fcurve_container, id_fcurves, write_fcurve
from .common import dependencies_ready, run_core
from .handlers.heads import is_head, rig_of, update_head


def existing_keys(obj) -> int:
    """How many keyframes on ``obj``'s pose and expressions an import would replace."""
    curves = [c for c in id_fcurves(obj) if c.data_path.startswith('["mogaface_')]
    if obj.data.shape_keys is not None:
        curves += [c for c in id_fcurves(obj.data.shape_keys) if c.data_path.startswith("key_blocks[")]
    return sum(len(c.keyframe_points) for c in curves)


class MOGAFACE_OT_import_tracking(bpy.types.Operator):
    """Keyframe a head's expressions and pose from a flame_param folder, one key per timestep"""

    bl_idname = "mogaface.import_tracking"
    bl_label = "Import Tracking"
    bl_options = {"REGISTER", "UNDO"}

    directory: StringProperty(
        name="Tracking Folder", subtype="DIR_PATH", description="A flame_param folder of .npz files"
    )
    filter_folder: BoolProperty(default=True, options={"HIDDEN"})
    target: StringProperty(name="Head", description="Head object to animate (empty: the active object)")

    def _target(self, context):
        return bpy.data.objects.get(self.target) if self.target else context.active_object

    def invoke(self, context, event):
        if not self.directory:
            context.window_manager.fileselect_add(self)
            return {"RUNNING_MODAL"}
        obj = self._target(context)
        count = existing_keys(obj) if is_head(obj) else 0
        if count:
            return context.window_manager.invoke_confirm(
                self, event, title="Replace Keyframes?", confirm_text="Replace",
                message=f"{obj.name} has {count} keyframes on its expressions and pose; importing replaces them")
        return self.execute(context)

    def execute(self, context):
        obj = self._target(context)
        if not head_or_report(self, obj) or not dependencies_ready(self, context):
            return {"CANCELLED"}
        return {"FINISHED"} if key_tracking(self, context, obj, bpy.path.abspath(self.directory)) else {"CANCELLED"}


def head_or_report(operator, obj) -> bool:
    """Whether ``obj`` (the operator's ``target``, or the active object) is a head; else reported."""
    if is_head(obj):
        return True
    name = operator.target or getattr(obj, "name", "nothing")
    operator.report({"ERROR"}, f"{name} is not a MoGaFace head: import one with Import Head first")
    return False


def key_tracking(operator, context, obj, folder: str, tolerance: float = 0.0) -> bool:
    """Key head ``obj``'s expressions and pose from a ``flame_param`` folder, one key per timestep
    (fewer with a ``tolerance``: the keys the curve needs to stay within it); what goes wrong is
    reported through ``operator``. The scene's Tracking field becomes ``folder``."""
    from ..core.for_blender.tracking import tracking_channels

    replaced = existing_keys(obj)
    key = obj.data.shape_keys
    rig = run_core(operator, rig_of, obj)
    if rig is None:
        return False
    n_expr = rig.model.n_expr  # expression keys are key blocks 1…n_expr, after Basis
    channels = run_core(operator, tracking_channels, folder, n_expr, tolerance)
    if channels is None:
        return False
    container = fcurve_container(obj, f"{obj.name} MoGaFace pose")
    for prop, columns in channels.pose.items():
        for index, co in enumerate(columns):
            write_fcurve(container, f'["{prop}"]', index, co, group="MoGaFace pose")
    container = fcurve_container(key, f"{obj.name} MoGaFace expressions")
    for block, co in zip(key.key_blocks[1 : 1 + n_expr], channels.expressions):
        write_fcurve(container, block.path_from_id("value"), 0, co, group="MoGaFace expressions")
    scene = context.scene
    scene.frame_start, scene.frame_end = int(channels.frames.min()), int(channels.frames.max())
    scene.frame_set(scene.frame_current)  # the frame handler re-poses the head
    run_core(operator, update_head, obj)
    scene.mogaface.tracking_folder = folder
    if channels.note:
        operator.report({"WARNING"}, channels.note)
    if replaced:
        operator.report({"WARNING"}, f"Replaced {replaced} existing keyframes on {obj.name}")
    operator.report({"INFO"}, f"Keyed {len(channels.frames)} timesteps on {obj.name}")
    return True
