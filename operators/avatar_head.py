"""A head with an avatar, read for the core: which heads have one, what a head shows at a frame
(identity, expression values and pose, keyframes included), its camera, its render request.

Every place the avatar appears (Render Frame/Animation, the viewport, the F12 layer, PLY export,
Gaussians to Mesh) reads the head through these; the maths is the core's (``core.for_blender``).
"""

from __future__ import annotations

import bpy

from .common import dependencies_ready
from .dependencies import LazyModule
from .handlers.heads import AVATAR_PATH_PROPERTY, expression_values, head_objects, is_head, pose_values, rig_of

np = LazyModule("numpy")  # imported on first use: registering needs no numpy

BACKGROUND_PROPERTY = "mogaface_avatar_background"


def avatar_heads(scene) -> list:
    return [obj for obj in head_objects(scene) if AVATAR_PATH_PROPERTY in obj]


def head_with_avatar(operator, context, name: str):
    """The named head, else the active one, else the scene's only head with an avatar, once the core's
    packages import (an avatar is of no use without them); else None, reported."""
    if not dependencies_ready(operator, context):
        return None
    obj = bpy.data.objects.get(name) if name else context.active_object
    if not (is_head(obj) and AVATAR_PATH_PROPERTY in obj) and not name:
        heads = avatar_heads(context.scene)
        obj = heads[0] if len(heads) == 1 else obj
    if not is_head(obj) or AVATAR_PATH_PROPERTY not in obj:
        label = name or getattr(obj, "name", "nothing")
        operator.report({"ERROR"}, f"{label} is not a head with an avatar: use Load Avatar first")
        return None
    return obj


def camera_of(scene, camera_obj, head):
    """The OpenCV camera of a Blender camera object, relative to the head object's placement."""
    from ..core.for_blender.cameras import opencv_camera

    data = camera_obj.data
    render = scene.render
    scale = render.resolution_percentage / 100.0
    resolution = (max(1, round(render.resolution_x * scale)), max(1, round(render.resolution_y * scale)))
    relative = np.array(head.matrix_world.inverted_safe() @ camera_obj.matrix_world)
    return opencv_camera(relative, data.lens, data.sensor_width, data.sensor_height, data.sensor_fit,
                         data.shift_x, data.shift_y, resolution,
                         (render.pixel_aspect_x, render.pixel_aspect_y), camera_id=camera_obj.name)


def head_values(head, frame: float | None = None) -> dict:
    """What the head shows: identity, expression values and pose, unfitted.

    ``frame=None``: as shown now (after ``frame_set``). A frame number: what its keyframes give
    at that frame (F-curves evaluated, the timeline untouched), as renders of other frames need.
    """
    from ..core.for_blender.head_rig import SHAPE_PROPERTY, STATIC_OFFSET_PROPERTY

    n_expr = rig_of(head).model.n_expr
    values = {"shape": np.asarray(head.get(SHAPE_PROPERTY, []), np.float64),
              "expr": expression_values(head, n_expr), **pose_values(head)}
    offset = head.get(STATIC_OFFSET_PROPERTY)
    if offset is not None:
        values["static_offset"] = np.asarray(offset, np.float64)
    if frame is not None:
        _apply_fcurves(head, frame, values, n_expr)
    return values


def _apply_fcurves(head, frame: float, values: dict, n_expr: int) -> None:
    """Overwrite ``values`` with the head's F-curves (expression keys, pose properties) at ``frame``."""
    from ..core.for_blender.head_rig import POSE_PROPERTIES
    from .animation import id_fcurves

    by_property = {prop: name for name, (prop, _) in POSE_PROPERTIES.items()}
    for fcurve in id_fcurves(head):
        name = by_property.get(fcurve.data_path[2:-2]) if fcurve.data_path.startswith('["') else None
        if name is not None and fcurve.array_index < len(values[name]):
            values[name][fcurve.array_index] = fcurve.evaluate(frame)
    blocks = head.data.shape_keys.key_blocks
    index = {block.name: i - 1 for i, block in enumerate(blocks[1:1 + n_expr], start=1)}
    for fcurve in id_fcurves(head.data.shape_keys):
        if fcurve.data_path.startswith('key_blocks["') and fcurve.data_path.endswith('"].value'):
            i = index.get(fcurve.data_path[len('key_blocks["'):-len('"].value')])
            if i is not None:
                values["expr"][i] = fcurve.evaluate(frame)


def head_params(head, avatar) -> dict:
    """The head's FLAME parameters as it is shown now (after ``frame_set``), fitted to the avatar."""
    from ..core.for_blender.render import fitted_params

    return fitted_params(head_values(head), avatar)


def head_request(scene, head, camera, frame: int, transparent: bool = False, keyed: bool = False):
    """The render request of the head's avatar seen by ``camera`` (a core Camera): as shown now,
    or with ``keyed`` as its keyframes give at ``frame``."""
    from ..core.for_blender.render import RenderRequest

    background = None if transparent else tuple(head.get(BACKGROUND_PROPERTY, (1.0, 1.0, 1.0)))
    scale = float(np.cbrt(abs(np.linalg.det(np.array(head.matrix_world)[:3, :3])))) or 1.0
    values = head_values(head, frame if keyed else None)
    return RenderRequest(head[AVATAR_PATH_PROPERTY], values, camera, background, scale, frame)


def render_head(context, head, camera_obj, frame: int):
    """Render the head's avatar at ``frame`` from ``camera_obj``: the core's ``RenderResult``."""
    from ..core.for_blender.render import render

    scene = context.scene
    scene.frame_set(frame)
    return render(head_request(scene, head, camera_of(scene, camera_obj, head), frame))
