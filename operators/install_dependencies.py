"""Install the core's pinned packages into the extension's user folder (needs online access)."""

from __future__ import annotations

import bpy

from . import dependencies

OFFLINE_MESSAGE = "Online access is off: allow it in Preferences › System › Network, then try again"


class MOGAFACE_OT_install_dependencies(bpy.types.Operator):
    """Download torch, numpy, numba and the other pinned packages into the extension's user folder"""

    bl_idname = "mogaface.install_dependencies"
    bl_label = "Install Dependencies"
    bl_options = {"INTERNAL"}

    def execute(self, context):
        if not dependencies.online_access():
            self.report({"ERROR"}, OFFLINE_MESSAGE)
            return {"CANCELLED"}
        target = dependencies.site_packages(create=True)
        if target is None:
            self.report({"ERROR"}, "Only an installed extension has a user folder to install into")
            return {"CANCELLED"}
        from ..core.dependencies import install

        window = context.window
        if window is not None:
            window.cursor_modal_set("WAIT")
        try:
            ok, message = install(dependencies.interpreter(context), target)
        finally:
            if window is not None:
                window.cursor_modal_restore()
        if not ok:
            self.report({"ERROR"}, message)
            return {"CANCELLED"}
        dependencies.add_site_packages()
        self.report({"INFO"}, message)
        return {"FINISHED"}
