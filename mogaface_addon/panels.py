"""The "MoGaFace" tab of the 3D View sidebar: one sub-panel per stage of the workflow.

Capture → Head → Training → Avatar → Reenactment. A stage whose operator is not part of this
version draws its settings and a greyed "not available yet" line; once an operator with the
expected idname is registered (see ``STAGE_OPERATORS``) its button appears in that place.
"""

from __future__ import annotations

import bpy

from ..operators.head_rig import is_head
from .preferences import draw_dependencies

# Operators that later stages provide: (idname, button text), by panel.
STAGE_OPERATORS = {
    "training": (("mogaface.train", "Train"),),
    "avatar": (
        ("mogaface.load_avatar", "Load Avatar"),
        ("mogaface.render_frame", "Render Frame"),
        ("mogaface.render_animation", "Render Animation"),
        ("mogaface.export_ply", "Export PLY"),
    ),
}


def operator_available(idname: str) -> bool:
    """Whether an operator ``module.name`` is registered right now."""
    module, name = idname.split(".")
    return hasattr(bpy.types, f"{module.upper()}_OT_{name}")


def draw_stage_operators(layout, stage: str) -> None:
    for idname, text in STAGE_OPERATORS[stage]:
        if operator_available(idname):
            layout.operator(idname, text=text)
        else:
            row = layout.row()
            row.enabled = False
            row.label(text=f"{text}: not available yet", icon="TIME")


class _Panel:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "MoGaFace"


class MOGAFACE_PT_main(_Panel, bpy.types.Panel):
    """The tab's header: dependency status."""

    bl_label = "MoGaFace"
    bl_idname = "MOGAFACE_PT_main"

    def draw(self, context):
        if draw_dependencies(self.layout):
            self.layout.label(text="Python packages: ready", icon="CHECKMARK")


class _SubPanel(_Panel):
    bl_parent_id = "MOGAFACE_PT_main"


class MOGAFACE_PT_capture(_SubPanel, bpy.types.Panel):
    bl_label = "Capture"

    def draw(self, context):
        layout = self.layout
        settings = context.scene.mogaface
        layout.prop(settings, "capture_folder")
        op = layout.operator("mogaface.import_capture", icon="OUTLINER_OB_CAMERA")
        op.filepath = settings.capture_folder
        layout.operator("mogaface.use_capture_camera", icon="VIEW_CAMERA")


class MOGAFACE_PT_head(_SubPanel, bpy.types.Panel):
    bl_label = "Head"

    def draw(self, context):
        layout = self.layout
        settings = context.scene.mogaface
        layout.prop(settings, "head_file")
        layout.prop(settings, "identity_file")
        op = layout.operator("mogaface.import_head", icon="USER")
        op.filepath = settings.head_file
        op.shape_file = settings.identity_file
        obj = context.active_object
        if not is_head(obj):
            layout.label(text="Select a head to edit its pose and expressions")
            return
        column = layout.column(align=True)
        for prop, text in (
            ("mogaface_rotation", "Rotation"),
            ("mogaface_translation", "Translation"),
            ("mogaface_neck_pose", "Neck"),
            ("mogaface_jaw_pose", "Jaw"),
            ("mogaface_eyes_pose", "Eyes"),
        ):
            if prop in obj:
                column.prop(obj, f'["{prop}"]', text=text)
        key = obj.data.shape_keys
        layout.template_list("MESH_UL_shape_keys", "", key, "key_blocks", obj, "active_shape_key_index", rows=4)


class MOGAFACE_PT_training(_SubPanel, bpy.types.Panel):
    bl_label = "Training"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        settings = context.scene.mogaface
        layout.prop(settings, "run_folder")
        layout.prop(settings, "preset")
        layout.prop(settings, "iterations")
        layout.prop(settings, "seed")
        from ..operators.train import current_worker, last_progress

        progress = last_progress()
        if current_worker() is not None:
            layout.progress(factor=progress.fraction, text=progress.text())
            layout.operator("mogaface.train_cancel", icon="CANCEL")
            return
        if operator_available("mogaface.train"):
            op = layout.operator("mogaface.train", icon="PLAY")
            op.preset, op.steps = settings.preset, settings.iterations
        else:
            draw_stage_operators(layout, "training")
        if progress is not None:
            layout.label(text=progress.message, icon="ERROR" if progress.state == "failed" else "INFO")


class MOGAFACE_PT_avatar(_SubPanel, bpy.types.Panel):
    bl_label = "Avatar"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        layout.prop(context.scene.mogaface, "avatar_file")
        if operator_available("mogaface.load_avatar"):
            layout.operator("mogaface.load_avatar", icon="SHADERFX").filepath = context.scene.mogaface.avatar_file
        for idname, text in STAGE_OPERATORS["avatar"][1:]:
            if operator_available(idname):
                layout.operator(idname, text=text)


class MOGAFACE_PT_reenactment(_SubPanel, bpy.types.Panel):
    bl_label = "Reenactment"

    def draw(self, context):
        layout = self.layout
        settings = context.scene.mogaface
        layout.prop(settings, "tracking_folder")
        row = layout.row()
        row.enabled = is_head(context.active_object)
        op = row.operator("mogaface.import_tracking", icon="ANIM")
        op.directory = settings.tracking_folder
        layout.label(text="Keys the active head's expressions and pose;")
        layout.label(text="another subject's tracking reenacts this head.")
