"""Add-on preferences: the Python interpreter for worker processes, thread count, dependencies."""

from __future__ import annotations

import sys

import bpy
from bpy.props import IntProperty, StringProperty

from ..operators.dependencies import install_command, missing_modules, top_package
from .text import wrapped_label


class MoGaFacePreferences(bpy.types.AddonPreferences):
    """Settings shared by every scene: how worker processes are started."""

    bl_idname = top_package()

    python_path: StringProperty(
        name="Python",
        subtype="FILE_PATH",
        default=sys.executable,
        description="Interpreter for training and rendering workers (needs torch, numpy, numba)",
    )
    threads: IntProperty(name="Threads", default=0, min=0, max=1024, description="CPU threads for workers (0: all)")
    launcher: StringProperty(
        name="Launcher",
        default="",
        description="Start training through this command line instead of the Python above, e.g. "
                    "'torchrun --nproc_per_node 2' (data-parallel; other machines are yours to set up)",
    )

    def draw(self, context):
        layout = self.layout
        layout.prop(self, "python_path")
        layout.prop(self, "threads")
        layout.prop(self, "launcher")
        if draw_dependencies(layout, self.python_path):
            layout.operator("mogaface.install_dependencies", text="Reinstall Dependencies", icon="IMPORT")


def draw_dependencies(layout, python: str) -> bool:
    """Draw what is missing in this Python and the command that installs it; True if all is there."""
    missing = missing_modules()
    if not missing:
        return True
    box = layout.box()
    box.alert = True
    context = bpy.context
    wrapped_label(box, context, f"Missing Python packages: {', '.join(missing)}", icon="ERROR")
    box.operator("mogaface.install_dependencies", icon="IMPORT")
    wrapped_label(box, context, "or install them yourself, then restart Blender:")
    wrapped_label(box, context, install_command(missing, python))
    return False
