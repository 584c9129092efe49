"""Bulk keyframes: F-curves written whole, through an action slot's channelbag where there is one."""

from __future__ import annotations

import bpy

# Keyframe_points.foreach_set("interpolation") takes the enum's integer value.
_LINEAR = bpy.types.Keyframe.bl_rna.properties["interpolation"].enum_items["LINEAR"].value


def fcurve_container(id_data, action_name: str):
    """Where F-curves of ``id_data`` live: its action slot's channelbag (Blender ≥ 4.4) or the action.

    Reuses an action already assigned, so other animation on the datablock is kept.
    """
    anim = id_data.animation_data or id_data.animation_data_create()
    action = anim.action
    if action is None:
        action = bpy.data.actions.new(action_name)
        anim.action = action
    if not hasattr(action, "slots"):  # Blender 4.2/4.3: F-curves on the action itself
        return action
    from bpy_extras import anim_utils

    slot = anim.action_slot
    if slot is None:
        slot = action.slots.new(id_type=id_data.id_type, name=id_data.name)
        anim.action_slot = slot
    return anim_utils.action_ensure_channelbag_for_slot(action, slot)


def write_fcurve(container, data_path: str, index: int, co, group: str | None = None):
    """Replace the F-curve ``data_path[index]`` with linear keys at ``co`` (flat frame, value pairs)."""
    old = container.fcurves.find(data_path, index=index)
    if old is not None:
        container.fcurves.remove(old)
    if group is not None and hasattr(container, "groups"):
        fcurve = container.fcurves.new(data_path, index=index)
        found = container.groups.get(group) or container.groups.new(group)
        fcurve.group = found
    else:
        fcurve = container.fcurves.new(data_path, index=index)
    count = len(co) // 2
    fcurve.keyframe_points.add(count)
    fcurve.keyframe_points.foreach_set("co", co)
    fcurve.keyframe_points.foreach_set("interpolation", [_LINEAR] * count)
    fcurve.update()
    return fcurve


def id_fcurves(id_data) -> list:
    """The F-curves animating ``id_data``: of its action slot's channelbag (Blender ≥ 4.4) or its action."""
    anim = getattr(id_data, "animation_data", None)
    action = anim.action if anim is not None else None
    if action is None:
        return []
    if not hasattr(action, "slots"):  # Blender 4.2/4.3
        return list(action.fcurves)
    from bpy_extras import anim_utils

    if anim.action_slot is None:
        return []
    channelbag = anim_utils.action_get_channelbag_for_slot(action, anim.action_slot)
    return [] if channelbag is None else list(channelbag.fcurves)
