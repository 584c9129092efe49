"""The avatar in Blender's own renders (F12, Ctrl F12), Cycles and EEVEE alike.

``mogaface.setup_render_layer`` sets up the compositor once: per head with an avatar, two
Image nodes (the avatar layer's RGBA, scene-linear premultiplied from
:func:`core.for_blender.render.blender_rgba`, and its depth), an Alpha Over node that lays the layer
over the render (premultiplied: ``avatar + (1 - alpha) · render``) and a Z Combine node that
takes that blend where the avatar is nearer than the render layer's Depth pass and the render
elsewhere; the result goes to the compositor's output. (Z Combine's own "Use Alpha" mixes with
straight alpha, which would darken the avatar's premultiplied edges; it stays off.) Before every render Blender makes (``render_pre``), :func:`render_avatar_layers`
renders each avatar layer at that frame from the scene camera with the core's one render
request into those two float images, so F12 and animation renders show the avatar without any
MoGaFace button.

The layers are float image datablocks filled in memory, not files: Blender's compositor reads
them directly, and no EXR writer has to live in Blender's process (the pip ``OpenEXR`` module
and the OpenEXR library Blender links can clash there).

Blender 5.0 keeps the compositor in a node group (``scene.compositing_node_group``, output
through a Group Output node); 4.2–4.4 in ``scene.node_tree`` (``use_nodes``, a Composite node).
Both are handled here and in :mod:`.handlers.render_layers` (the ``render_pre`` handler), and only there.
"""

from __future__ import annotations

import bpy

from .common import dependencies_ready, run_core
from .handlers.render_layers import NODE_TAG, compositor_tree, layer_image, render_avatar_layers


def _output_socket(tree):
    """The input socket of the compositor's final image (Group Output or Composite)."""
    if hasattr(bpy.types, "CompositorNodeComposite"):
        node = next((n for n in tree.nodes if n.bl_idname == "CompositorNodeComposite"), None)
        node = node or tree.nodes.new("CompositorNodeComposite")
        return node.inputs[0]
    if not any(item.item_type == "SOCKET" and item.in_out == "OUTPUT" for item in tree.interface.items_tree):
        tree.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
    node = next((n for n in tree.nodes if n.bl_idname == "NodeGroupOutput"), None)
    node = node or tree.nodes.new("NodeGroupOutput")
    return node.inputs[0]


def _set_option(node, socket: str, attribute: str, value) -> None:
    """A node option: an input socket in Blender 5.0, a property before."""
    if socket in node.inputs:
        node.inputs[socket].default_value = value
    else:
        setattr(node, attribute, value)


def setup_layer(scene, heads) -> list:
    """Build (or rebuild) the compositor chain for ``heads``; returns the Z Combine nodes."""
    tree = compositor_tree(scene)
    for node in [n for n in tree.nodes if NODE_TAG in n]:
        tree.nodes.remove(node)
    for view_layer in scene.view_layers:
        view_layer.use_pass_z = True
    layers = next((n for n in tree.nodes if n.bl_idname == "CompositorNodeRLayers"), None)
    if layers is None:
        layers = tree.nodes.new("CompositorNodeRLayers")
        layers.location = (-600, 0)
    output = _output_socket(tree)
    image, depth = layers.outputs["Image"], layers.outputs["Depth"]
    combines = []
    for index, head in enumerate(heads):
        nodes = []
        for kind in ("rgba", "depth"):
            node = tree.nodes.new("CompositorNodeImage")
            node.image = layer_image(head, kind)
            node.label = f"MoGaFace {head.name} {kind}"
            node.location = (-600 + 250 * index, -350 - 200 * len(nodes))
            nodes.append(node)
        over = tree.nodes.new("CompositorNodeAlphaOver")
        over.label = f"MoGaFace {head.name} over"
        over.location = (-300 + 250 * index, -200)
        _set_option(over, "Straight Alpha", "use_premultiply", False)  # the layer is premultiplied
        if hasattr(over, "premul"):
            over.premul = 0.0
        background, foreground = (over.inputs["Background"], over.inputs["Foreground"]) \
            if "Foreground" in over.inputs else (over.inputs[1], over.inputs[2])  # 4.2-4.5: Fac, Image, Image
        tree.links.new(image, background)
        tree.links.new(nodes[0].outputs["Image"], foreground)
        combine = tree.nodes.new("CompositorNodeZcombine")
        combine.label = f"MoGaFace {head.name}"
        combine.location = (-300 + 250 * index, 0)
        _set_option(combine, "Use Alpha", "use_alpha", False)
        _set_option(combine, "Anti-Alias", "use_antialias_z", False)  # the avatar's alpha is its edge
        tree.links.new(image, combine.inputs[0])
        tree.links.new(depth, combine.inputs[1])
        tree.links.new(over.outputs[0], combine.inputs[2])
        tree.links.new(nodes[1].outputs["Image"], combine.inputs[3])
        for node in (over, *nodes, combine):
            node[NODE_TAG] = head.name
        image, depth = combine.outputs[0], combine.outputs[1]
        combines.append(combine)
    tree.links.new(image, output)
    return combines


class MOGAFACE_OT_setup_render_layer(bpy.types.Operator):
    """Show the avatars in Blender's renders (F12): an avatar layer per head, merged by depth in the compositor"""

    bl_idname = "mogaface.setup_render_layer"
    bl_label = "Avatar in Renders"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        from .avatar_head import avatar_heads

        if not dependencies_ready(self, context):
            return {"CANCELLED"}
        scene = context.scene
        heads = avatar_heads(scene)
        if not heads:
            self.report({"ERROR"}, "No head with an avatar in the scene: use Load Avatar first")
            return {"CANCELLED"}
        if run_core(self, setup_layer, scene, heads) is None:
            return {"CANCELLED"}
        for head in heads:
            head.hide_render = True  # the avatar stands in for the mesh in renders
        if scene.camera is not None:
            run_core(self, render_avatar_layers, scene)
        names = ", ".join(head.name for head in heads)
        hint = "" if scene.view_settings.view_transform == "Standard" else \
            " (View Transform 'Standard' shows the avatar's colours as trained)"
        self.report({"INFO"}, f"Renders now show the avatar of {names}; the head mesh is hidden from renders{hint}")
        return {"FINISHED"}
