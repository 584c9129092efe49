"""The "MoGaFace" tab of the 3D View sidebar: one sub-panel per stage of the workflow.

Capture → Head → Training → Avatar → Reenactment. A stage whose operator is not part of this
version draws its settings and a greyed "not available yet" line; once an operator with the
expected idname is registered (see ``STAGE_OPERATORS``) its button appears in that place.
"""

from __future__ import annotations

import bpy

from ..operators.handlers.heads import is_head
from .preferences import draw_dependencies
from .text import wrapped_label

# Operators that later stages provide: (idname, button text), by panel.
STAGE_OPERATORS = {
    "training": (("mogaface.train", "Train"),),
    "avatar": (
        ("mogaface.load_avatar", "Load Avatar"),
        ("mogaface.render_frame", "Render Frame"),
        ("mogaface.render_animation", "Render Animation"),
        ("mogaface.export_ply", "Export PLY"),
        ("mogaface.setup_render_layer", "Avatar in Renders"),
        ("mogaface.gaussians_to_mesh", "Gaussians to Mesh"),
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
        layout.separator()
        layout.prop_search(settings, "footage_clip", bpy.data, "movieclips")
        if draw_footage_progress(layout, context):
            return
        layout.operator("mogaface.track_footage", icon="TRACKER").movie_clip = settings.footage_clip
        wrapped_label(layout, context, "Your own clip or photos: tracked here, then the camera, the head and the "
                      "footage come in as a capture to train on.")


def draw_footage_progress(layout, context) -> bool:
    """A running footage job's bar and Cancel (True), else nothing; a failed one's message."""
    from ..operators import footage

    running, progress = draw_running_job(layout, footage, "mogaface.footage_cancel")
    if running:
        return True
    if progress is not None and progress.state == "failed":
        wrapped_label(layout, context, progress.message, icon="ERROR")
    return False


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
            wrapped_label(layout, context, "Select a head to edit its pose and expressions")
            return
        draw_pose(layout, obj)
        key = obj.data.shape_keys
        layout.template_list("MESH_UL_shape_keys", "", key, "key_blocks", obj, "active_shape_key_index", rows=4)


#: The pose properties as labelled rows: (property, first index, count, label).
POSE_ROWS = (
    ("mogaface_rotation", 0, 3, "Rotation"),
    ("mogaface_translation", 0, 3, "Translation"),
    ("mogaface_neck_pose", 0, 3, "Neck"),
    ("mogaface_jaw_pose", 0, 3, "Jaw"),
    ("mogaface_eyes_pose", 0, 3, "Left Eye"),
    ("mogaface_eyes_pose", 3, 3, "Right Eye"),
)


def draw_pose(layout, obj) -> None:
    """The head's pose as named rows of three values (axis-angle, or metres for translation)."""
    column = layout.column(align=True)
    for prop, first, count, text in POSE_ROWS:
        if prop not in obj or len(obj[prop]) < first + count:
            continue
        row = column.row(align=True)
        row.label(text=text)
        for index in range(first, first + count):
            row.prop(obj, f'["{prop}"]', index=index, text="")


def preset_description(settings) -> str:
    """The one-line description of the scene's training preset."""
    from ..operators.train import PRESET_ITEMS

    return next((description for key, _, description in PRESET_ITEMS if key == settings.preset), "")


class MOGAFACE_PT_training(_SubPanel, bpy.types.Panel):
    bl_label = "Training"  # open: its button is the next step after an import, its progress shows here

    def draw(self, context):
        layout = self.layout
        settings = context.scene.mogaface
        layout.prop(settings, "run_folder")
        layout.prop(settings, "preset")
        wrapped_label(layout, context, preset_description(settings), icon="INFO")
        layout.prop(settings, "iterations")
        layout.prop(settings, "minutes")
        layout.prop(settings, "seed")
        layout.prop(settings, "camera_rounds")
        if settings.camera_rounds > 0:
            layout.prop(settings, "cameras_from_landmarks")
            layout.prop(settings, "camera_centres_measured")
        layout.prop(settings, "camera_delays")
        from ..operators import train

        running, progress = draw_running_job(layout, train, "mogaface.train_cancel")
        if running:
            return
        if operator_available("mogaface.train"):
            op = layout.operator("mogaface.train", icon="PLAY")
            op.preset, op.steps, op.minutes = settings.preset, settings.iterations, settings.minutes
        else:
            draw_stage_operators(layout, "training")
        if progress is not None:
            wrapped_label(layout, context, progress.message, icon="ERROR" if progress.state == "failed" else "INFO")


def draw_running_job(layout, job_module, cancel: str):
    """``(running, last progress)`` of the child job an operator module follows (its
    ``current_worker`` and ``last_progress``); while it runs, its bar and the ``cancel`` button."""
    progress = job_module.last_progress()
    running = job_module.current_worker() is not None
    if running:
        draw_worker_progress(layout, progress)
        layout.operator(cancel, icon="CANCEL")
    return running, progress


def draw_worker_progress(layout, progress) -> None:
    """A child job's bar (step and ETA: short enough for the sidebar at its default width), and its
    loss and PSNR on the line below."""
    layout.progress(factor=progress.fraction, text=progress.bar_text())
    detail = progress.detail_text()
    if detail:
        layout.label(text=detail)


class MOGAFACE_PT_avatar(_SubPanel, bpy.types.Panel):
    bl_label = "Avatar"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        settings = context.scene.mogaface
        layout.prop(settings, "avatar_file")
        if operator_available("mogaface.load_avatar"):
            layout.operator("mogaface.load_avatar", icon="SHADERFX").filepath = settings.avatar_file
        obj = context.active_object
        if is_head(obj) and "mogaface_avatar_path" in obj and hasattr(obj, "mogaface_show_avatar"):
            box = layout.box()
            box.prop(obj, "mogaface_show_avatar", text="Show in Viewport")
            column = box.column(align=True)
            column.active = obj.mogaface_show_avatar
            if hasattr(obj, "mogaface_viewport_draw"):
                column.prop(obj, "mogaface_viewport_draw", text="Draw")
            column.prop(settings, "viewport_resolution", text="Resolution")
            column.prop(settings, "viewport_navigate_resolution")
            draw_gpu_unavailable(column, context)
        draw_render_buttons(layout, context)


def draw_gpu_unavailable(layout, context) -> None:
    """The line saying the viewport's GPU draw cannot run here (the CPU image is drawn instead)."""
    from ..operators.handlers.gpu_draw import software_renderer, unavailable

    reason = unavailable()
    if reason is not None:
        wrapped_label(layout, context, f"GPU draw unavailable, the CPU image is shown: {reason}", icon="INFO")
    elif software_renderer():
        wrapped_label(layout, context, "Software OpenGL: Both shows the CPU image, drawn off the interface thread",
                      icon="INFO")


def draw_render_buttons(layout, context) -> None:
    """Render buttons, or the running animation render's progress and Cancel."""
    from ..operators.render import current_render_job

    job = current_render_job()
    if job is not None:
        layout.progress(factor=job.fraction, text=f"Rendering {job.text()}")
        layout.operator("mogaface.render_cancel", icon="CANCEL")
        return
    icons = {"mogaface.render_frame": "RENDER_STILL", "mogaface.render_animation": "RENDER_ANIMATION",
             "mogaface.export_ply": "EXPORT", "mogaface.setup_render_layer": "NODE_COMPOSITING",
             "mogaface.gaussians_to_mesh": "POINTCLOUD_DATA"}
    for idname, text in STAGE_OPERATORS["avatar"][1:]:
        if operator_available(idname):
            layout.operator(idname, text=text, icon=icons.get(idname, "NONE"))


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
        wrapped_label(layout, context, "Keys the active head's expressions and pose; another subject's tracking "
                      "reenacts this head.")
        draw_improve_tracking(layout, context)
        layout.separator()
        draw_drive_from_footage(layout, context)


def draw_drive_from_footage(layout, context) -> None:
    """Drive from Footage on the active head with the scene's tolerance and Keep Head Still."""
    settings = context.scene.mogaface
    layout.prop(settings, "drive_tolerance")
    layout.prop(settings, "drive_keep_head_still")
    if draw_footage_progress(layout, context):
        return
    row = layout.row()
    row.enabled = is_head(context.active_object)
    op = row.operator("mogaface.drive_from_footage", icon="CAMERA_DATA")
    op.movie_clip = settings.footage_clip
    op.tolerance = settings.drive_tolerance
    op.keep_head_still = settings.drive_keep_head_still
    wrapped_label(layout, context, "A performance clip (webcam, phone) tracked with this head's shape and keyed "
                  "on it at the scene's frame rate.")


def draw_improve_tracking(layout, context) -> None:
    """Improve Tracking with the scene's run, or the running improvement's progress and Cancel."""
    from ..operators import improve_tracking

    running, progress = draw_running_job(layout, improve_tracking, "mogaface.improve_tracking_cancel")
    if running:
        return
    row = layout.row()
    row.enabled = is_head(context.active_object) and bool(context.scene.mogaface.run_folder)
    row.operator("mogaface.improve_tracking", icon="MOD_WAVE")
    wrapped_label(layout, context, "Refines every timestep from the capture's views with the run's refiner, "
                  "then keys the head with it.")
    if progress is not None and progress.state != "done":
        wrapped_label(layout, context, progress.message, icon="ERROR" if progress.state == "failed" else "INFO")
