"""Head objects in Blender: finding them, reading their rig, and re-posing them.

A head object keeps its model file, identity and pose as custom properties (names in
:mod:`...core.for_blender.head_rig`), one shape key per expression component and a last shape key,
"MoGaFace pose", that the handlers (frame change, edits) rewrite from the core's FLAME
evaluation. The mesh then shows exactly what the core computes for the current expression
values and pose properties, while the expression sliders stay ordinary shape keys.
"""

from __future__ import annotations

import bpy

from ..dependencies import FILE_MODULES, LazyModule, missing_modules

np = LazyModule("numpy")  # imported on first use: registering needs no numpy

# The same values as core.for_blender.head_rig's constants, here so that registering and drawing
# never import the core (whose packages may be missing).
MODEL_PATH_PROPERTY = "mogaface_model_path"
POSE_KEY_NAME = "MoGaFace pose"
AVATAR_PATH_PROPERTY = "mogaface_avatar_path"


def is_head(obj) -> bool:
    """Whether ``obj`` is a MoGaFace head (a mesh with a model path and its shape keys)."""
    return (
        obj is not None
        and obj.type == "MESH"
        and MODEL_PATH_PROPERTY in obj
        and obj.data.shape_keys is not None
        and POSE_KEY_NAME in obj.data.shape_keys.key_blocks
    )


def head_objects(scene) -> list:
    return [obj for obj in scene.objects if is_head(obj)]


def rig_of(obj):
    """The core :class:`HeadRig` of a head object (model loaded once per file)."""
    from ...core.for_blender.head_rig import SHAPE_PROPERTY, STATIC_OFFSET_PROPERTY, HeadRig, load_head_model

    shape = np.asarray(obj.get(SHAPE_PROPERTY, []), np.float64)
    offset = obj.get(STATIC_OFFSET_PROPERTY)
    if offset is not None:
        offset = np.asarray(offset, np.float64).reshape(-1, 3)
    model = load_head_model(obj[MODEL_PATH_PROPERTY], None if offset is None else len(offset))
    return HeadRig(model, shape, offset)


def expression_values(obj, n_expr: int) -> np.ndarray:
    """The current values of the expression shape keys (key blocks 1…n_expr, in model order)."""
    blocks = obj.data.shape_keys.key_blocks
    values = np.zeros(len(blocks), np.float32)
    blocks.foreach_get("value", values)
    return values[1 : 1 + n_expr].astype(np.float64)


def pose_values(obj) -> dict:
    """The pose custom properties as FLAME parameters."""
    from ...core.for_blender.head_rig import POSE_PROPERTIES

    return {name: np.asarray(obj.get(prop, [0.0] * size), np.float64) for name, (prop, size) in POSE_PROPERTIES.items()}


# The inputs each head was last posed with (by session id), so edits re-pose only what changed.
_posed_inputs: dict = {}


def _inputs(obj, n_expr: int) -> tuple:
    pose = pose_values(obj)
    values = np.concatenate([expression_values(obj, n_expr), *pose.values()])
    return (obj[MODEL_PATH_PROPERTY], *values.tolist())


def update_head(obj, only_if_changed: bool = False) -> bool:
    """Rewrite the pose shape key of one head for its current expression values and pose.

    With ``only_if_changed``, nothing is written when the inputs equal those of the last
    update; returns whether the key was written.
    """
    rig = rig_of(obj)
    inputs = _inputs(obj, rig.model.n_expr)
    if only_if_changed and _posed_inputs.get(obj.session_uid) == inputs:
        return False
    co = rig.pose_key(expression_values(obj, rig.model.n_expr), pose_values(obj))
    key = obj.data.shape_keys
    key.key_blocks[POSE_KEY_NAME].data.foreach_set("co", co.astype(np.float32).reshape(-1))
    key.update_tag()
    obj.data.update_tag()
    _posed_inputs[obj.session_uid] = inputs
    return True


_reported: set = set()


def _update_heads(scene, only_if_changed: bool) -> None:
    heads = head_objects(scene)
    if not heads or missing_modules(FILE_MODULES):
        return
    from ...core.errors import MogafaceError

    for obj in heads:
        try:
            update_head(obj, only_if_changed)
        except (MogafaceError, OSError, ValueError, KeyError) as error:
            message = f"MoGaFace: cannot pose {obj.name!r}: {error}"
            if message not in _reported:
                _reported.add(message)
                print(message)


@bpy.app.handlers.persistent
def update_heads_on_frame_change(scene, depsgraph=None):
    """``frame_change_post`` handler: re-pose every head of the scene. Never raises.

    A head that cannot be evaluated (missing model file, missing packages) keeps its last
    pose; the problem is printed once per object and message.
    """
    _update_heads(scene, only_if_changed=False)


@bpy.app.handlers.persistent
def update_heads_on_edit(scene, depsgraph=None):
    """``depsgraph_update_post`` handler: re-pose heads whose sliders or pose were edited.

    Compares each head's inputs with those it was last posed with, so its own write (which
    triggers another depsgraph update) ends the cycle instead of repeating it.
    """
    _update_heads(scene, only_if_changed=True)
