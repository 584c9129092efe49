"""Disabling the extension leaves every scene as it would be without it; enabling it brings the avatars back.

While the extension is enabled, a head with an avatar is drawn as its bounds (the avatar covers
it, :func:`.viewport.display_for_avatar`) and hidden from renders, and the compositor lays each
avatar layer over the render. Without the extension none of that holds: the layers would keep
the last frame they were filled for (F12 at frame 5 showing frame 20's avatar) and the head
would stay an empty box. :func:`suspend_scenes` (at unregister) mutes those compositor nodes and
gives each head its own display and render visibility back, marking what it changed;
:func:`resume_scenes` (at register, and when a file saved meanwhile is opened) undoes exactly
what was marked, so a node or a head the user changed by hand stays as it is.
"""

from __future__ import annotations

import bpy

from .heads import AVATAR_PATH_PROPERTY, is_head
from .render_layers import NODE_TAG, compositor_tree

#: Custom property on what :func:`suspend_scenes` changed: a node (True) or a head (its settings).
SUSPENDED = "mogaface_suspended"

#: The head settings the extension changes while its avatar is shown, and their values without it.
HEAD_SETTINGS = {"display_type": "TEXTURED", "show_in_front": False, "hide_render": False}


def _layer_nodes(scene) -> list:
    tree = compositor_tree(scene, create=False)
    return [node for node in tree.nodes if NODE_TAG in node] if tree is not None else []


def suspend_scenes() -> None:
    """Mute the avatar layers and give every head with an avatar its plain display back."""
    for scene in bpy.data.scenes:
        for node in _layer_nodes(scene):
            if not node.mute and SUSPENDED not in node:
                node.mute = True  # a muted Z Combine passes the render through
                node[SUSPENDED] = True
    for obj in bpy.data.objects:
        if is_head(obj) and AVATAR_PATH_PROPERTY in obj and SUSPENDED not in obj:
            obj[SUSPENDED] = {name: getattr(obj, name) for name in HEAD_SETTINGS}
            for name, value in HEAD_SETTINGS.items():
                setattr(obj, name, value)


#: Whether this registration has resumed the scenes yet (registering may not read ``bpy.data``).
_state = {"resumed": False}


def resume_scenes() -> None:
    """Undo :func:`suspend_scenes` where it left its mark."""
    for scene in bpy.data.scenes:
        for node in _layer_nodes(scene):
            if node.get(SUSPENDED):
                node.mute = False
                del node[SUSPENDED]
    for obj in bpy.data.objects:
        saved = obj.get(SUSPENDED)
        if saved is None:
            continue
        for name in HEAD_SETTINGS:
            if name in saved:
                setattr(obj, name, saved[name])
        del obj[SUSPENDED]
    _state["resumed"] = True  # only once it ran: registering may stop it at the first bpy.data


@bpy.app.handlers.persistent
def resume_after_load(_file=None) -> None:
    """``load_post``: a file saved while the extension was disabled gets its avatars back."""
    resume_scenes()


@bpy.app.handlers.persistent
def resume_pending(_scene=None, _depsgraph=None) -> None:
    """``render_pre``, ``frame_change_post``, ``depsgraph_update_post``, first in line: the scenes
    are resumed before anything draws or renders them, whenever registering could not."""
    if not _state["resumed"]:
        resume_scenes()


def resume_when_data_is_ready() -> None:
    """At register: now if ``bpy.data`` can be read; else (Blender reads no data while it enables an
    extension) from a timer, or the first handler above, whichever runs first."""
    _state["resumed"] = False
    try:
        resume_scenes()
    except AttributeError:  # bpy.data is not readable while registering
        bpy.app.timers.register(lambda: resume_pending() and None, first_interval=0.0)
