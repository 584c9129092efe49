"""What the extension registers with Blender, in order; unregistered in reverse."""

import bpy  # noqa: F401  (this module is only imported by Blender's register())

CLASSES: list = []


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
