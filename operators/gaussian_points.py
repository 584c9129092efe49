"""``mogaface.gaussians_to_mesh``: the posed Gaussians of a frame range as point meshes.

One object per frame in a collection, parented to the head (so its transform applies), each a
mesh of vertices only with point attributes ``scale``, ``rotation`` (quaternion), ``opacity``
and ``color`` that Geometry Nodes reads by name. Over a range, each object is visible on its
own frame only (keyed visibility), the usual way of an imported sequence.
"""

from __future__ import annotations

import bpy
from bpy.props import BoolProperty, IntProperty, StringProperty

from .common import run_core
from .dependencies import LazyModule

np = LazyModule("numpy")  # imported on first use: registering needs no numpy

ATTRIBUTES = (("scale", "FLOAT_VECTOR", "vector"), ("rotation", "QUATERNION", "value"),
              ("opacity", "FLOAT", "value"), ("color", "FLOAT_COLOR", "color"))


def points_mesh(name: str, points: dict):
    """A vertex-only mesh with the points' positions and attributes (replacing one of that name)."""
    old = bpy.data.meshes.get(name)
    if old is not None:
        bpy.data.meshes.remove(old)
    mesh = bpy.data.meshes.new(name)
    positions = points["position"]
    mesh.vertices.add(len(positions))
    mesh.vertices.foreach_set("co", positions.reshape(-1))
    for attribute, kind, field in ATTRIBUTES:
        layer = mesh.attributes.new(attribute, kind, "POINT")
        layer.data.foreach_set(field, np.ascontiguousarray(points[attribute], np.float32).reshape(-1))
    mesh.update()
    return mesh


def _key_visibility(obj, frame: int, frames: list) -> None:
    """Show ``obj`` on ``frame`` only (keys just before and after it)."""
    for key_frame in sorted({frame - 1, frame, frame + 1} & set(range(frames[0] - 1, frames[-1] + 2))):
        hidden = key_frame != frame
        obj.hide_viewport = obj.hide_render = hidden
        obj.keyframe_insert("hide_viewport", frame=key_frame)
        obj.keyframe_insert("hide_render", frame=key_frame)
    obj.hide_viewport = obj.hide_render = False


class MOGAFACE_OT_gaussians_to_mesh(bpy.types.Operator):
    """Add the avatar's posed Gaussians of a frame (or range) as point meshes with attributes for Geometry Nodes"""

    bl_idname = "mogaface.gaussians_to_mesh"
    bl_label = "Gaussians to Mesh"
    bl_options = {"REGISTER", "UNDO"}

    head: StringProperty(name="Head", description="Head object with an avatar (empty: the active one)")
    use_range: BoolProperty(name="Frame Range", default=False, description="One point mesh per frame of the range")
    frame_start: IntProperty(name="Start", default=0, description="First frame (0: the scene's)")
    frame_end: IntProperty(name="End", default=0, description="Last frame (0: the scene's)")

    def execute(self, context):
        from ..core.for_blender.points import gaussian_points
        from .avatar_head import head_values, head_with_avatar

        head = head_with_avatar(self, context, self.head)
        if head is None:
            return {"CANCELLED"}
        scene = context.scene
        if self.use_range:
            frames = list(range(self.frame_start or scene.frame_start, (self.frame_end or scene.frame_end) + 1))
        else:
            frames = [scene.frame_current]
        if not frames:
            self.report({"ERROR"}, "Empty frame range")
            return {"CANCELLED"}
        name = f"MoGaFace Gaussians {head.name}"
        collection = bpy.data.collections.get(name) or bpy.data.collections.new(name)
        if collection.name not in scene.collection.children:
            scene.collection.children.link(collection)
        path = head["mogaface_avatar_path"]
        for frame in frames:
            points = run_core(self, gaussian_points, path, head_values(head, frame))
            if points is None:
                return {"CANCELLED"}
            label = f"{name} {frame:04d}"
            obj = bpy.data.objects.get(label)
            mesh = points_mesh(label, points)
            if obj is None:
                obj = bpy.data.objects.new(label, mesh)
                collection.objects.link(obj)
            else:
                obj.data = mesh
            obj.parent = head
            obj.matrix_parent_inverse.identity()
            obj["mogaface_frame"] = frame
            if len(frames) > 1:
                _key_visibility(obj, frame, frames)
        self.report({"INFO"}, f"{len(frames)} point mesh(es) of {len(points['position'])} Gaussians in {name}")
        return {"FINISHED"}
