"""MoGaFace: animatable Gaussian head avatars from multi-view captures.

The repository root is both the Python package ``mogaface`` and the Blender
extension. Importing the package never imports ``bpy``; Blender calls
:func:`register` / :func:`unregister`, which pull in the add-on layer only then.
"""

__version__ = "0.1.0"


def register():
    from .mogaface_addon import registration

    registration.register()


def unregister():
    from .mogaface_addon import registration

    registration.unregister()
