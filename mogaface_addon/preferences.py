"""Add-on preferences: the worker's Python, threads, the torch package index, dependencies."""

from __future__ import annotations

import bpy
from bpy.props import IntProperty, StringProperty

from ..operators.dependencies import missing_modules, top_package
from ..operators.install_dependencies import last_install_progress
from .text import wrapped_label

#: The CPU-only torch build's index (the same as core.for_blender.dependencies.DEFAULT_TORCH_INDEX, here so
#: that registering never imports the core).
DEFAULT_TORCH_INDEX = "https://download.pytorch.org/whl/cpu"


class MoGaFacePreferences(bpy.types.AddonPreferences):
    """Settings shared by every scene: how worker processes are started and packages installed."""

    bl_idname = top_package()

    python_path: StringProperty(
        name="Python",
        subtype="FILE_PATH",
        default="",
        description="Interpreter for training workers (empty: Blender's own Python with the installed packages)",
    )
    threads: IntProperty(name="Threads", default=0, min=0, max=1024, description="CPU threads for workers (0: all)")
    launcher: StringProperty(
        name="Launcher",
        default="",
        description="Start training through this command line instead of the Python above, e.g. "
                    "'torchrun --nproc_per_node 2' (data-parallel; other machines are yours to set up)",
    )
    torch_index: StringProperty(
        name="Torch Index",
        default=DEFAULT_TORCH_INDEX,
        description="Package index of the torch build Install Dependencies downloads (default: the CPU-only "
        "build; e.g. https://download.pytorch.org/whl/cu126 for CUDA, a mirror, or empty for PyPI's torch). "
        "A torch 2.6 or newer that Blender's Python already has is used instead",
    )

    def draw(self, context):
        layout = self.layout
        layout.prop(self, "python_path")
        layout.prop(self, "threads")
        layout.prop(self, "launcher")
        layout.prop(self, "torch_index")
        if draw_dependencies(layout):
            layout.operator("mogaface.install_dependencies", text="Reinstall Dependencies", icon="IMPORT")


def draw_dependencies(layout) -> bool:
    """Draw a running install, or what is missing and the button; True if every package imports."""
    progress = last_install_progress()
    from ..operators.install_dependencies import current_install

    if current_install() is not None:
        box = layout.box()
        box.label(text="Installing Python packages", icon="IMPORT")
        box.progress(factor=progress.fraction, text=progress.message)
        box.operator("mogaface.install_dependencies_cancel", icon="CANCEL")
        return False
    missing = missing_modules()
    if progress is not None and progress.state != "done":
        wrapped_label(layout, bpy.context, progress.message, icon="ERROR" if progress.state == "failed" else "INFO")
    if not missing:
        from ..core.metrics.lpips_weights import installed

        if not installed():  # packages from an older install: training works, its LPIPS is not scored
            box = layout.box()
            wrapped_label(box, bpy.context, "LPIPS weights missing: runs are scored without LPIPS", icon="INFO")
            box.operator("mogaface.install_dependencies", icon="IMPORT")
        return True
    box = layout.box()
    box.alert = True
    context = bpy.context
    wrapped_label(box, context, f"Missing: {', '.join(missing)}", icon="ERROR")
    wrapped_label(box, context, "Training and the avatar need them")
    box.operator("mogaface.install_dependencies", icon="IMPORT")
    box.label(text="Runs in the background")
    return False
