"""What the extension registers with Blender, in order; unregistered in reverse.

Imports nothing beyond ``bpy`` (no numpy, torch or core): a Blender without numpy can enable the
extension, and the panel then offers *Install Dependencies*.

Besides the classes: the ``Scene.mogaface`` settings, the handlers that re-pose heads
(``frame_change_post``, ``depsgraph_update_post``) and the extension's user site-packages folder
on ``sys.path``. :func:`unregister` removes every one of them, ends the extension's threads, and
leaves each scene as it would be without the extension (:mod:`..operators.handlers.suspend`);
:func:`register` brings the avatars back.
"""

import bpy

from ..operators.common import stop_background_threads
from ..operators.compositor import MOGAFACE_OT_setup_render_layer
from ..operators.dependencies import add_site_packages, remove_site_packages
from ..operators.export import MOGAFACE_OT_export_ply
from ..operators.footage import MOGAFACE_OT_drive_from_footage, MOGAFACE_OT_footage_cancel, MOGAFACE_OT_track_footage
from ..operators.gaussian_points import MOGAFACE_OT_gaussians_to_mesh
from ..operators.handlers import viewport
from ..operators.handlers.heads import update_heads_on_edit, update_heads_on_frame_change
from ..operators.handlers.render_layers import render_avatar_layers
from ..operators.handlers.suspend import (
    resume_after_load,
    resume_pending,
    resume_when_data_is_ready,
    suspend_scenes,
)
from ..operators.import_capture import MOGAFACE_OT_import_capture, MOGAFACE_OT_use_capture_camera
from ..operators.import_head import MOGAFACE_OT_import_head
from ..operators.import_tracking import MOGAFACE_OT_import_tracking
from ..operators.improve_tracking import MOGAFACE_OT_improve_tracking, MOGAFACE_OT_improve_tracking_cancel
from ..operators.install_dependencies import (
    MOGAFACE_OT_install_dependencies,
    MOGAFACE_OT_install_dependencies_cancel,
    cancel_running_install,
)
from ..operators.jobs import cancel_child_jobs
from ..operators.load_avatar import MOGAFACE_OT_load_avatar
from ..operators.render import (
    MOGAFACE_OT_render_animation,
    MOGAFACE_OT_render_cancel,
    MOGAFACE_OT_render_frame,
    cancel_render_job,
)
from ..operators.train import MOGAFACE_OT_train, MOGAFACE_OT_train_cancel
from . import panels
from .preferences import MoGaFacePreferences
from .properties import MoGaFaceSceneSettings

CLASSES: list = [
    MoGaFaceSceneSettings,
    MoGaFacePreferences,
    MOGAFACE_OT_import_capture,
    MOGAFACE_OT_use_capture_camera,
    MOGAFACE_OT_import_head,
    MOGAFACE_OT_import_tracking,
    MOGAFACE_OT_track_footage,
    MOGAFACE_OT_drive_from_footage,
    MOGAFACE_OT_footage_cancel,
    MOGAFACE_OT_improve_tracking,
    MOGAFACE_OT_improve_tracking_cancel,
    MOGAFACE_OT_train,
    MOGAFACE_OT_train_cancel,
    MOGAFACE_OT_load_avatar,
    MOGAFACE_OT_render_frame,
    MOGAFACE_OT_render_animation,
    MOGAFACE_OT_export_ply,
    MOGAFACE_OT_render_cancel,
    MOGAFACE_OT_setup_render_layer,
    MOGAFACE_OT_gaussians_to_mesh,
    MOGAFACE_OT_install_dependencies,
    MOGAFACE_OT_install_dependencies_cancel,
    panels.MOGAFACE_PT_main,
    panels.MOGAFACE_PT_capture,
    panels.MOGAFACE_PT_head,
    panels.MOGAFACE_PT_training,
    panels.MOGAFACE_PT_avatar,
    panels.MOGAFACE_PT_reenactment,
]

HANDLERS = (  # resume_pending first: a scene is resumed before it is posed, drawn or rendered
    (bpy.app.handlers.frame_change_post, resume_pending),
    (bpy.app.handlers.depsgraph_update_post, resume_pending),
    (bpy.app.handlers.render_pre, resume_pending),
    (bpy.app.handlers.frame_change_post, update_heads_on_frame_change),
    (bpy.app.handlers.depsgraph_update_post, update_heads_on_edit),
    (bpy.app.handlers.render_pre, render_avatar_layers),
    (bpy.app.handlers.load_post, resume_after_load),
)


def register():
    add_site_packages()  # packages installed by mogaface.install_dependencies
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Scene.mogaface = bpy.props.PointerProperty(type=MoGaFaceSceneSettings)
    viewport.register()
    for handlers, function in HANDLERS:
        if function not in handlers:
            handlers.append(function)
    resume_when_data_is_ready()


def _same_function(a, b) -> bool:
    """Equal, or the same function of a reloaded copy of this module (add-on reload)."""
    same_name = getattr(a, "__qualname__", None) == b.__qualname__
    return a is b or (same_name and getattr(a, "__module__", None) == b.__module__)


def unregister():
    cancel_child_jobs()  # a training or tracking child never outlives the extension
    cancel_render_job()
    cancel_running_install()
    try:
        suspend_scenes()
    except Exception as error:  # noqa: BLE001 - unregistering must go on whatever a scene holds
        print(f"MoGaFace: the scenes could not be left without the avatars: {error}")
    viewport.unregister()
    for handlers, function in HANDLERS:
        for registered in [h for h in handlers if _same_function(h, function)]:
            handlers.remove(registered)
    if hasattr(bpy.types.Scene, "mogaface"):
        del bpy.types.Scene.mogaface
    for cls in reversed(CLASSES):
        if getattr(cls, "is_registered", False):
            bpy.utils.unregister_class(cls)
    stop_background_threads()
    remove_site_packages()
