"""``mogaface.import_head``: a FLAME-format head as a mesh with expression shape keys and a pose rig."""

from __future__ import annotations

import bpy
from bpy.props import StringProperty

from .common import OpensFileBrowser, dependencies_ready, run_core
from .dependencies import FILE_MODULES, LazyModule
from .handlers.heads import MODEL_PATH_PROPERTY, POSE_KEY_NAME

np = LazyModule("numpy")  # imported on first use: registering needs no numpy


def build_mesh(name: str, head):
    """A mesh with the model's vertices and triangles in their order, and its UVs if any."""
    mesh = bpy.data.meshes.new(name)
    n_faces = len(head.faces)
    mesh.vertices.add(len(head.basis))
    mesh.vertices.foreach_set("co", head.basis.astype(np.float32).reshape(-1))
    mesh.loops.add(3 * n_faces)
    mesh.loops.foreach_set("vertex_index", head.faces.astype(np.int32).reshape(-1))
    mesh.polygons.add(n_faces)
    mesh.polygons.foreach_set("loop_start", np.arange(0, 3 * n_faces, 3, dtype=np.int32))
    mesh.update(calc_edges=True)
    if head.loop_uvs is not None:
        layer = mesh.uv_layers.new(name="UVMap")
        layer.data.foreach_set("uv", head.loop_uvs.astype(np.float32).reshape(-1))
    return mesh


def build_material(name: str, head):
    """A material whose base colour is the model's texture (packed into the .blend)."""
    width, height = head.texture_size
    image = bpy.data.images.new(f"{name} texture", width, height, alpha=False)
    image.pixels.foreach_set(head.texture_pixels)
    image.pack()
    material = bpy.data.materials.new(name)
    if material.node_tree is None:  # Blender < 5: materials start without nodes
        material.use_nodes = True
    nodes = material.node_tree.nodes
    shader = next((n for n in nodes if n.type == "BSDF_PRINCIPLED"), None) or nodes.new("ShaderNodeBsdfPrincipled")
    texture = nodes.new("ShaderNodeTexImage")
    texture.image = image
    texture.location = (shader.location.x - 300, shader.location.y)
    material.node_tree.links.new(texture.outputs["Color"], shader.inputs["Base Color"])
    return material


def add_pose_properties(obj) -> None:
    """The pose as animatable custom vectors on the object (FLAME axis-angle, translation in m)."""
    from ..core.for_blender.head_rig import POSE_PROPERTIES

    for name, (prop, size) in POSE_PROPERTIES.items():
        obj[prop] = [0.0] * size
        unit = "metres" if name == "translation" else "axis-angle, radians, FLAME axes"
        obj.id_properties_ui(prop).update(description=f"FLAME {name} ({unit})", soft_min=-3.0, soft_max=3.0)


def build_head(context, head):
    """The head object: mesh, material, shape keys (basis, expressions, pose) and properties."""
    from ..core.for_blender.head_rig import EXPRESSION_SLIDER_RANGE, SHAPE_PROPERTY, STATIC_OFFSET_PROPERTY

    mesh = build_mesh(head.name, head)
    if head.texture_pixels is not None:
        mesh.materials.append(build_material(head.name, head))
    obj = bpy.data.objects.new(head.name, mesh)
    context.collection.objects.link(obj)
    obj.shape_key_add(name="Basis", from_mix=False)
    for name, co in zip(head.expression_names, head.expression_keys):
        block = obj.shape_key_add(name=name, from_mix=False)
        block.slider_min = -EXPRESSION_SLIDER_RANGE
        block.slider_max = EXPRESSION_SLIDER_RANGE
        block.data.foreach_set("co", co.astype(np.float32).reshape(-1))
    pose = obj.shape_key_add(name=POSE_KEY_NAME, from_mix=False)
    pose.data.foreach_set("co", head.pose_key.astype(np.float32).reshape(-1))
    pose.value = 1.0
    obj[MODEL_PATH_PROPERTY] = head.model_path
    obj[SHAPE_PROPERTY] = head.rig.shape.tolist()
    if head.rig.static_offset is not None:
        obj[STATIC_OFFSET_PROPERTY] = head.rig.static_offset.reshape(-1).tolist()
    add_pose_properties(obj)
    for other in context.view_layer.objects:
        other.select_set(False)
    obj.select_set(True)
    context.view_layer.objects.active = obj
    return obj


class MOGAFACE_OT_import_head(OpensFileBrowser, bpy.types.Operator):
    """Import a FLAME-format head (.pkl/.npz) with one shape key per expression and a pose rig"""

    bl_idname = "mogaface.import_head"
    bl_label = "Import Head"
    bl_options = {"REGISTER", "UNDO"}

    filepath: StringProperty(name="Head File", subtype="FILE_PATH", description="FLAME-format model (.pkl or .npz)")
    filter_glob: StringProperty(default="*.pkl;*.npz", options={"HIDDEN"})
    shape_file: StringProperty(
        name="Identity File",
        subtype="FILE_PATH",
        description="Optional flame_param .npz whose shape (and static offset) sets the identity",
    )

    def execute(self, context):
        if not dependencies_ready(self, context, needs=FILE_MODULES):
            return {"CANCELLED"}
        shape_file = bpy.path.abspath(self.shape_file) if self.shape_file else None
        from ..core.for_blender.head_rig import head_import

        head = run_core(self, head_import, bpy.path.abspath(self.filepath), shape_file)
        if head is None:
            return {"CANCELLED"}
        obj = build_head(context, head)
        context.scene.mogaface.head_file = head.model_path
        counts = f"{len(head.basis)} vertices, {len(head.expression_names)} expressions"
        self.report({"INFO"}, f"Imported {obj.name}: {counts}")
        return {"FINISHED"}
