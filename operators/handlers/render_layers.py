"""The avatar layers of Blender's renders, filled before each render (the ``render_pre`` handler).

``mogaface.setup_render_layer`` (:mod:`..compositor`) puts two float images per head with an
avatar into the compositor; before every render Blender makes, :func:`render_avatar_layers`
renders each layer at that frame from the scene camera with the core's one render request into
those images. Blender 5.0 keeps the compositor in a node group, 4.2–4.4 in ``scene.node_tree``:
:func:`compositor_tree` finds either.
"""

from __future__ import annotations

import bpy

from ..dependencies import LazyModule
from ..images import SCENE_LINEAR

np = LazyModule("numpy")  # imported on first use: registering needs no numpy

NODE_TAG = "mogaface_layer_head"  # custom property on our nodes: the head they show
#: Depth written where the avatar is absent (finite: Z Combine compares numbers).
FAR = 1.0e10


def compositor_tree(scene, create: bool = True):
    """The scene's compositor node tree (made if missing and ``create``)."""
    if hasattr(scene, "compositing_node_group"):  # Blender 5.0+
        tree = scene.compositing_node_group
        if tree is None and create:
            tree = bpy.data.node_groups.new(f"{scene.name} Compositing", "CompositorNodeTree")
            scene.compositing_node_group = tree
        return tree
    if create:
        scene.use_nodes = True
    return scene.node_tree


def layer_image(head, kind: str, create: bool = True):
    """The float image of ``head``'s avatar layer: ``kind`` "rgba" (premultiplied, scene linear)
    or "depth" (distance in every colour channel, non-colour data)."""
    name = f"MoGaFace layer {head.name} {kind}"
    image = bpy.data.images.get(name)
    if image is None and create:
        image = bpy.data.images.new(name, 4, 4, alpha=True, float_buffer=True)
        image.colorspace_settings.name = "Non-Color" if kind == "depth" else SCENE_LINEAR
        image.alpha_mode = "PREMUL"
        image.use_fake_user = False
    return image


def layer_heads(scene) -> list:
    """Heads whose avatar layer is in the scene's compositor."""
    tree = compositor_tree(scene, create=False)
    if tree is None:
        return []
    names = {node[NODE_TAG] for node in tree.nodes if NODE_TAG in node}
    return [obj for obj in scene.objects if obj.name in names]


def layer_pixels(result) -> tuple[np.ndarray, np.ndarray]:
    """A transparent render as the compositor wants it, in Blender's flat pixel order (rows from
    the bottom): :func:`core.for_blender.render.blender_rgba`, and the depth (:data:`FAR` where the
    avatar is not)."""
    from ...core.for_blender.render import blender_rgba

    rgba = blender_rgba(result)
    depth = np.where(np.isfinite(result.depth), result.depth, FAR)[..., None]
    depth = np.concatenate([np.repeat(depth, 3, axis=2), np.ones_like(depth)], axis=2)
    return tuple(np.ascontiguousarray(a[::-1], np.float32).reshape(-1) for a in (rgba, depth))


def fill_image(image, width: int, height: int, pixels) -> None:
    if tuple(image.size) != (width, height):
        image.scale(width, height)
    image.pixels.foreach_set(pixels)
    image.update()


def render_layer(scene, head) -> None:
    """Render ``head``'s avatar layer at the scene's frame from its camera into the layer images."""
    from ...core.for_blender.render import render
    from ..avatar_head import camera_of, head_request

    frame = scene.frame_current
    request = head_request(scene, head, camera_of(scene, scene.camera, head), frame, transparent=True, keyed=True)
    result = render(request)
    height, width = result.alpha.shape
    for kind, pixels in zip(("rgba", "depth"), layer_pixels(result)):
        fill_image(layer_image(head, kind), width, height, pixels)


_reported: set = set()


@bpy.app.handlers.persistent
def render_avatar_layers(scene, depsgraph=None):
    """``render_pre`` handler: render every avatar layer of the scene for the frame about to render.

    Never raises (a handler must not): a layer that cannot be rendered keeps its last image and
    the problem is printed once.
    """
    if scene.camera is None:
        return
    for head in layer_heads(scene):
        try:
            render_layer(scene, head)
        except Exception as error:  # noqa: BLE001 - reported, never raised in a handler
            message = f"MoGaFace: cannot render the avatar layer of {head.name!r}: {error}"
            if message not in _reported:
                _reported.add(message)
                print(message)
