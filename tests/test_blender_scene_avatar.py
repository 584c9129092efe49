"""The avatar in the Blender scene (bpy module): the viewport's render request, the compositor's
avatar layer in F12 renders, the Gaussians as point meshes, and the panel's fixes.

The avatar is made here, not trained: the procedural head with one opaque, randomly coloured
Gaussian per triangle, saved as an ``avatar.pt`` beside its head model (what a run writes).
"""

import importlib
import pathlib
import shutil
import time
import types

import test_blender_addon as addon_test  # sets Blender's user folders to a temporary one first

# isort: split

import bpy  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
import torch  # noqa: E402
from mathutils import Matrix, Vector  # noqa: E402

from mogaface.core.avatar.avatar import Avatar  # noqa: E402
from mogaface.core.avatar.gaussians import rgb_to_sh_dc  # noqa: E402
from mogaface.core.for_blender.axes import FLAME_TO_BLENDER, flame_to_blender  # noqa: E402
from mogaface.core.for_blender.render import blender_rgba, render_image_name  # noqa: E402

MODULE = addon_test.MODULE
SIZE = 64


def ops(name: str):
    return importlib.import_module(f"{MODULE}.operators.{name}")


def make_avatar(folder: pathlib.Path, head_pkl: pathlib.Path) -> pathlib.Path:
    folder.mkdir()
    shutil.copy(head_pkl, folder / "head.pkl")
    avatar = Avatar.initial(folder / "head.pkl", max_sh_degree=0)
    g = avatar.gaussians
    with torch.no_grad():
        g.opacity_logit.fill_(5.0)
        colors = torch.rand(len(g), 1, 3, generator=torch.Generator().manual_seed(0)) * 0.8 + 0.1
        g.sh_dc.copy_(rgb_to_sh_dc(colors))
    avatar.save(folder / "avatar.pt")
    return folder


def look_at(obj, target: Vector, eye: Vector) -> None:
    obj.location = eye
    obj.rotation_euler = (target - eye).to_track_quat("-Z", "Y").to_euler()
    bpy.context.view_layer.update()


@pytest.fixture(scope="module")
def scene(tmp_path_factory, procedural_head_pkl):
    root = tmp_path_factory.mktemp("scene_avatar")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    addon_test.build_and_install(root / "dist")
    folder = make_avatar(root / "avatar", procedural_head_pkl)
    assert bpy.ops.mogaface.import_head(filepath=str(folder / "head.pkl")) == {"FINISHED"}
    head = bpy.context.active_object
    assert bpy.ops.mogaface.load_avatar(filepath=str(folder)) == {"FINISHED"}
    # keys: frame 1 neutral, frame 2 an expression and an open jaw
    block = head.data.shape_keys.key_blocks[1]
    for frame, value, jaw in ((1, 0.0, 0.0), (2, 3.0, 0.35)):
        block.value = value
        block.keyframe_insert("value", frame=frame)
        head["mogaface_jaw_pose"] = [jaw, 0.0, 0.0]
        head.keyframe_insert('["mogaface_jaw_pose"]', index=0, frame=frame)
    scn = bpy.context.scene
    scn.frame_start, scn.frame_end = 1, 2
    scn.frame_set(1)
    centre = sum((head.matrix_world @ v.co for v in head.data.vertices), Vector()) / len(head.data.vertices)
    camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scn.collection.objects.link(camera)
    look_at(camera, centre, centre + Vector((0.0, -0.75, 0.05)))
    scn.camera = camera
    scn.render.resolution_x = scn.render.resolution_y = SIZE
    scn.render.resolution_percentage = 100
    return {"root": root, "folder": folder, "head": head, "camera": camera, "centre": centre}


def camera_matrices(camera, width=SIZE, height=SIZE):
    depsgraph = bpy.context.evaluated_depsgraph_get()
    projection = camera.calc_matrix_camera(depsgraph, x=width, y=height)
    return camera.matrix_world.inverted(), projection


def camera_render(scene_data, frame=1):
    from mogaface.core.for_blender.render import render

    avatar_head = ops("avatar_head")
    scn, head = bpy.context.scene, scene_data["head"]
    camera = avatar_head.camera_of(scn, scene_data["camera"], head)
    return render(avatar_head.head_request(scn, head, camera, frame, transparent=True, keyed=True))


def viewport_render(scene_data, frame=1, size=(SIZE, SIZE)):
    from mogaface.core.for_blender.render import render

    view, projection = camera_matrices(scene_data["camera"], *size)
    bpy.context.scene.frame_set(frame)
    request, view_cam = ops("handlers.viewport").viewport_request(scene_data["head"], view, projection, size, frame)
    return render(request), view_cam, np.array(projection)


# -- the viewport's render request ----------------------------------------------------------------


def test_viewport_request_renders_what_the_scene_camera_renders(scene):
    """The view/projection matrices of the camera give the same picture as the camera's lens settings."""
    by_view, _, _ = viewport_render(scene)
    by_camera = camera_render(scene)
    assert by_view.alpha.max() > 0.99 and 0.1 < (by_view.alpha > 0.5).mean() < 0.9  # the head is in view
    assert np.abs(by_view.rgba - by_camera.rgba).max() < 1e-4
    assert np.allclose(by_view.depth, by_camera.depth, rtol=1e-4, equal_nan=True)
    head = scene["head"]
    saved, saved_camera = head.matrix_world.copy(), scene["camera"].matrix_world.copy()
    try:  # the head moved and scaled, the camera (unscaled, as views are) with it: the same picture
        head.matrix_world = Matrix.Translation((0.2, 0.1, -0.3)) @ Matrix.Scale(2.0, 4) @ saved
        location, rotation, _ = (head.matrix_world @ saved.inverted() @ saved_camera).decompose()
        scene["camera"].matrix_world = Matrix.LocRotScale(location, rotation, None)
        moved, _, _ = viewport_render(scene)
    finally:
        scene["camera"].matrix_world = saved_camera
        head.matrix_world = saved
        bpy.context.view_layer.update()
    assert np.abs(moved.rgba - by_view.rgba).max() < 1e-3
    inside = np.isfinite(by_view.depth)
    assert np.allclose(moved.depth[inside], 2.0 * by_view.depth[inside], rtol=1e-3)


def test_viewport_depth_meets_the_mesh_and_is_what_opengl_writes(scene):
    result, view_cam, projection = viewport_render(scene)
    image = ops("handlers.viewport").viewport_image(result, view_cam, projection)
    depth_window = image.depth.reshape(SIZE, SIZE)[::-1]  # back to top row first
    rgba = image.rgba.reshape(SIZE, SIZE, 4)[::-1]
    straight = np.divide(result.rgb, result.alpha[..., None], out=np.zeros_like(result.rgb),
                         where=result.alpha[..., None] > 0)
    srgb_decoded = np.where(straight > 0.04045, ((straight + 0.055) / 1.055) ** 2.4, straight / 12.92)
    opaque = result.alpha >= ops("handlers.viewport").OPAQUE_ALPHA  # drawn with alpha 1: nothing shows through
    shown_alpha = np.where(opaque, 1.0, result.alpha)
    assert np.allclose(rgba[..., :3], srgb_decoded * shown_alpha[..., None], atol=1e-5)  # linear, premultiplied
    assert np.allclose(rgba[..., 3], shown_alpha) and opaque.sum() > 50 and (~opaque & (result.alpha > 0.1)).any()
    assert (depth_window[result.alpha < 1 / 255] == 1.0).all()
    camera, scn = scene["camera"], bpy.context.scene
    depsgraph = bpy.context.evaluated_depsgraph_get()
    view = camera.matrix_world.inverted()
    checked = 0
    for row, col in ((SIZE // 2, SIZE // 2), (SIZE // 2 - 8, SIZE // 2 + 5), (SIZE // 2 + 6, SIZE // 2 - 4)):
        if result.alpha[row, col] < 0.99:
            continue
        # the mesh surface through that pixel's centre, by Blender's own ray cast
        ndc = Vector(((col + 0.5) / SIZE * 2 - 1, 1 - (row + 0.5) / SIZE * 2, 0.5, 1.0))
        far = (Matrix(projection) @ view).inverted() @ ndc
        origin = camera.matrix_world.translation
        hit, location, *_ = scn.ray_cast(depsgraph, origin, (far.xyz / far.w - origin).normalized())
        assert hit
        planar = -(view @ location).z
        assert abs(result.depth[row, col] - planar) < 0.01  # Gaussians lie on the triangles
        clip = Matrix(projection) @ Vector((0.0, 0.0, -float(result.depth[row, col]), 1.0))
        assert abs(depth_window[row, col] - (0.5 * clip.z / clip.w + 0.5)) < 1e-5  # what OpenGL would write
        checked += 1
    assert checked >= 2


def test_an_orthographic_view_draws_the_avatar_where_the_mesh_is(scene):
    camera = scene["camera"]
    camera.data.type = "ORTHO"
    camera.data.ortho_scale = 0.4
    try:
        result, view_cam, projection = viewport_render(scene)
        image = ops("handlers.viewport").viewport_image(result, view_cam, projection)
        depth_window = image.depth.reshape(SIZE, SIZE)[::-1]
        view = camera.matrix_world.inverted()
        origin = camera.matrix_world.translation
        direction = (camera.matrix_world.to_3x3() @ Vector((0, 0, -1))).normalized()
        hit, location, *_ = bpy.context.scene.ray_cast(bpy.context.evaluated_depsgraph_get(), origin, direction)
    finally:
        camera.data.type = "PERSP"
    assert hit and result.alpha[SIZE // 2, SIZE // 2] > 0.99
    clip = Matrix(projection) @ view @ location.to_4d()  # orthographic: window depth is linear in distance
    assert abs(depth_window[SIZE // 2, SIZE // 2] - (0.5 * clip.z / clip.w + 0.5)) < 1e-3


def fake_view(camera, width, height):
    view, projection = camera_matrices(camera, width, height)
    region = types.SimpleNamespace(width=width, height=height)
    return region, types.SimpleNamespace(view_matrix=view, window_matrix=projection)


def settle(state, timeout=900.0):  # the first render compiles the extension copy's kernels
    start = time.monotonic()
    while state.future is not None and not state.future.done():
        assert time.monotonic() - start < timeout
        time.sleep(0.02)


def test_the_view_refreshes_on_frame_keys_head_and_view_and_sharpens_when_still(scene):
    viewport = ops("handlers.viewport")
    scn, head, camera = bpy.context.scene, scene["head"], scene["camera"]
    scn.mogaface.viewport_resolution, scn.mogaface.viewport_navigate_resolution = 100, 32
    region, region_3d = fake_view(camera, 64, 64)
    state = viewport.ViewState()
    scn.frame_set(1)
    now = 100.0

    def update(at):
        viewport.update_view(state, head, region, region_3d, scn, now=at)
        submitted = state.future is not None
        settle(state)
        viewport.update_view(state, head, region, region_3d, scn, now=at)  # collects
        return submitted

    assert update(now)  # a new view: rendered while "navigating", at the lower resolution
    assert (state.image.width, state.image.height) == (32, 32)
    assert update(now + viewport.SETTLE_S + 0.01)  # still: full resolution
    first = state.image
    assert (first.width, first.height) == (64, 64)
    assert not update(now + 5)  # nothing changed: nothing rendered
    scn.frame_set(2)  # other keys
    assert update(now + 6) and state.image.key != first.key
    assert np.abs(state.image.rgba - first.rgba).max() > 0.1
    scn.frame_set(1)
    assert update(now + 7) and np.allclose(state.image.rgba, first.rgba, atol=1e-6)
    head.location.x += 0.01  # the head moved
    bpy.context.view_layer.update()
    try:
        assert update(now + 8)
    finally:
        head.location.x -= 0.01
        bpy.context.view_layer.update()
    head.data.shape_keys.key_blocks[1].value = 1.5  # an edited (unkeyed) expression value
    try:
        assert update(now + 9)
    finally:
        scn.frame_set(1)
    region, region_3d = fake_view(camera, 54, 64)  # the view changed: navigating, then still at its own size
    assert update(now + 10) and (state.image.width, state.image.height) == (27, 32)
    assert update(now + 11 + viewport.SETTLE_S) and (state.image.width, state.image.height) == (54, 64)
    scn.mogaface.viewport_resolution = 50
    try:
        assert update(now + 12 + viewport.SETTLE_S) and (state.image.width, state.image.height) == (27, 32)
    finally:
        scn.mogaface.viewport_resolution = 100


def test_shown_heads_follow_the_per_object_switch(scene):
    viewport = ops("handlers.viewport")
    head = scene["head"]
    # shown: the mesh as its bounds, in front (its edges never cut the avatar, drawn after the overlays)
    assert viewport.shown_heads(bpy.context.scene) == [head] and head.display_type == "BOUNDS"
    assert head.show_in_front and not head.hide_select
    head.mogaface_show_avatar = False
    try:
        assert viewport.shown_heads(bpy.context.scene) == [] and head.display_type == "TEXTURED"
        assert not head.show_in_front
    finally:
        head.mogaface_show_avatar = True
    assert head.display_type == "BOUNDS" and head.show_in_front


def test_render_request_key_names_what_changes_the_picture(scene):
    avatar_head = ops("avatar_head")
    scn, head = bpy.context.scene, scene["head"]
    camera = avatar_head.camera_of(scn, scene["camera"], head)
    one = avatar_head.head_request(scn, head, camera, 1, transparent=True, keyed=True)
    again = avatar_head.head_request(scn, head, camera, 1, transparent=True, keyed=True)
    other = avatar_head.head_request(scn, head, camera, 2, transparent=True, keyed=True)
    assert one.key() == again.key() != other.key()
    assert other.params["jaw_pose"][0] == pytest.approx(0.35, abs=1e-6) and other.params["expr"][0] == pytest.approx(3.0)
    assert bpy.context.scene.frame_current == 1  # keyed values never move the timeline


# -- F12: the compositor's avatar layer -----------------------------------------------------------


def read_exr(path):
    import OpenEXR

    with OpenEXR.File(str(path)) as exr:
        channels = exr.channels()
        if "RGBA" in channels:
            return np.asarray(channels["RGBA"].pixels, np.float32)
        return np.stack([channels[c].pixels for c in "RGBA" if c in channels], axis=-1).astype(np.float32)


def add_plane(name, size, location, color):
    bpy.ops.mesh.primitive_plane_add(size=size, location=location, rotation=(np.pi / 2, 0.0, 0.0))
    plane = bpy.context.active_object
    plane.name = name
    material = bpy.data.materials.new(name)
    if not material.node_tree:  # Blender 5.0 gives every new material its nodes
        material.use_nodes = True
    emission = material.node_tree.nodes.new("ShaderNodeEmission")
    emission.inputs["Color"].default_value = (*color, 1.0)
    output = next(n for n in material.node_tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    material.node_tree.links.new(emission.outputs[0], output.inputs["Surface"])
    plane.data.materials.append(material)
    return plane


def test_setup_builds_the_compositor_and_f12_renders_show_the_avatar_in_depth(scene, tmp_path):
    import addon_utils

    layers = ops("handlers.render_layers")
    scn, head, centre = bpy.context.scene, scene["head"], scene["centre"]
    addon_utils.enable("cycles")
    scn.render.engine = "CYCLES"
    scn.cycles.samples = 1
    scn.cycles.use_denoising = False
    scn.view_settings.view_transform = "Standard"
    # a green wall behind the head, a blue card in front of its left half (seen from the camera)
    wall = add_plane("Wall", 2.0, centre + Vector((0.0, 0.3, 0.0)), (0.0, 1.0, 0.0))
    card = add_plane("Card", 0.5, centre + Vector((-0.25, -0.3, 0.0)), (0.0, 0.0, 1.0))
    bpy.context.view_layer.objects.active = head

    def render_to(name):
        scn.render.filepath = str(tmp_path / name)
        scn.render.image_settings.file_format = "OPEN_EXR"
        bpy.ops.render.render(write_still=True)
        return read_exr(tmp_path / name)

    try:
        head.hide_render = True
        scn.frame_set(2)
        scene_only = render_to("scene_only.exr")  # Blender's own picture of the wall and the card
        assert bpy.ops.mogaface.setup_render_layer() == {"FINISHED"}
        tree = layers.compositor_tree(scn, create=False)
        combine = next(n for n in tree.nodes if n.bl_idname == "CompositorNodeZcombine")
        assert combine.inputs[0].links[0].from_node.bl_idname == "CompositorNodeRLayers"
        assert combine.inputs[1].links[0].from_socket.name == "Depth"
        over = combine.inputs[2].links[0].from_node  # the layer over the render, premultiplied
        assert over.bl_idname == "CompositorNodeAlphaOver" and not over.inputs["Straight Alpha"].default_value
        assert over.inputs["Foreground"].links[0].from_node.image.name == f"MoGaFace layer {head.name} rgba"
        assert combine.inputs[3].links[0].from_node.image.name == f"MoGaFace layer {head.name} depth"
        assert not combine.inputs["Use Alpha"].default_value
        assert combine.outputs[0].links and scn.view_layers[0].use_pass_z and head.hide_render
        frames = {}
        for frame in (1, 2):
            scn.frame_set(frame)
            frames[frame] = render_to(f"f12_{frame}.exr")
        layer_image = layers.layer_image(head, "rgba", create=False)  # frame 2's, by the render_pre handler
        layer = np.zeros(len(layer_image.pixels), np.float32)
        layer_image.pixels.foreach_get(layer)
        layer = layer.reshape(SIZE, SIZE, 4)[::-1]
    finally:
        for plane in (wall, card):
            bpy.data.objects.remove(plane)
        scn.frame_set(1)
    expected = camera_render(scene, frame=2)
    alpha = expected.alpha
    assert np.abs(layer[..., 3] - alpha).max() < 1e-5
    image = frames[2]
    card = np.isclose(scene_only[..., :3], (0.0, 0.0, 1.0), atol=0.02).all(axis=2)
    wall = np.isclose(scene_only[..., :3], (0.0, 1.0, 0.0), atol=0.02).all(axis=2)
    inside = alpha > 0.99
    for axis in (0, 1):  # one pixel in from every edge: Z Combine anti-aliases the edges between depths
        inside &= np.roll(inside, 1, axis) & np.roll(inside, -1, axis)
    edge = lambda mask: mask & np.roll(mask, 1, 0) & np.roll(mask, -1, 0) & np.roll(mask, 1, 1) & np.roll(mask, -1, 1)
    avatar_only, card_over_avatar = inside & edge(wall), inside & edge(card)
    assert avatar_only.sum() > 50 and card_over_avatar.sum() > 20 and ((alpha < 1e-3) & wall).sum() > 50
    linear = np.where(expected.rgb > 0.04045, ((expected.rgb + 0.055) / 1.055) ** 2.4, expected.rgb / 12.92)
    assert np.abs(image[avatar_only][:, :3] - linear[avatar_only]).max() < 0.02  # the avatar over the wall
    # its semi-transparent edges too: premultiplied over the wall, neither darkened nor whitened
    layer_rgba = blender_rgba(expected)  # a transparent render: premultiplied
    over_wall = edge(wall) & (alpha > 0.05) & (alpha < 0.95)
    assert over_wall.sum() > 10
    blended = layer_rgba[..., :3] + (1 - alpha[..., None]) * scene_only[..., :3]
    assert np.abs(image[over_wall][:, :3] - blended[over_wall]).max() < 0.02
    empty = edge(alpha < 1e-3) & (edge(card) | edge(wall))
    assert np.abs(image[empty] - scene_only[empty]).max() < 0.02  # the scene alone where the avatar is not
    assert np.allclose(image[card_over_avatar][:, :3], (0.0, 0.0, 1.0), atol=0.02)  # the card in front hides it
    assert np.abs(frames[1][avatar_only] - frames[2][avatar_only]).max() > 0.1  # each frame its own keys


# -- the Gaussians as scene data ------------------------------------------------------------------


def test_gaussians_to_mesh_writes_point_meshes_geometry_nodes_can_read(scene, tmp_path):
    import trimesh

    scn, head = bpy.context.scene, scene["head"]
    bpy.context.view_layer.objects.active = head
    assert bpy.ops.mogaface.gaussians_to_mesh(use_range=True, frame_start=1, frame_end=2) == {"FINISHED"}
    objects = [bpy.data.objects[f"MoGaFace Gaussians {head.name} {f:04d}"] for f in (1, 2)]
    avatar = Avatar.load(scene["folder"] / "avatar.pt")
    for frame, obj in zip((1, 2), objects):
        mesh = obj.data
        assert len(mesh.vertices) == len(avatar.gaussians) and len(mesh.polygons) == 0 and obj.parent == head
        kinds = {a.name: (a.data_type, a.domain) for a in mesh.attributes}
        assert kinds["scale"] == ("FLOAT_VECTOR", "POINT") and kinds["rotation"] == ("QUATERNION", "POINT")
        assert kinds["opacity"] == ("FLOAT", "POINT") and kinds["color"] == ("FLOAT_COLOR", "POINT")
        # against the 3DGS PLY of the same frame, read by trimesh
        scn.frame_set(frame)
        ply = tmp_path / f"f{frame}.ply"
        assert bpy.ops.mogaface.export_ply(filepath=str(ply)) == {"FINISHED"}
        cloud = trimesh.load(ply)
        co = np.zeros(len(mesh.vertices) * 3, np.float32)
        mesh.vertices.foreach_get("co", co)
        assert np.abs(co.reshape(-1, 3) - flame_to_blender(np.asarray(cloud.vertices))).max() < 1e-5
        vertex = cloud.metadata["_ply_raw"]["vertex"]["data"]
        quat = np.zeros(len(mesh.vertices) * 4, np.float32)
        mesh.attributes["rotation"].data.foreach_get("value", quat)
        ply_quat = np.stack([vertex[f"rot_{i}"] for i in range(4)], axis=1)
        ply_quat /= np.linalg.norm(ply_quat, axis=1, keepdims=True)
        from scipy.spatial.transform import Rotation

        ours = Rotation.from_quat(quat.reshape(-1, 4)[:, [1, 2, 3, 0]]).as_matrix()
        theirs = FLAME_TO_BLENDER @ Rotation.from_quat(ply_quat[:, [1, 2, 3, 0]]).as_matrix()
        assert np.abs(ours - theirs).max() < 1e-4
        opacity = np.zeros(len(mesh.vertices), np.float32)
        mesh.attributes["opacity"].data.foreach_get("value", opacity)
        assert np.allclose(opacity, 1 / (1 + np.exp(-vertex["opacity"])), atol=1e-4)
    scn.frame_set(1)
    assert not objects[0].hide_get() and not objects[0].hide_viewport and objects[1].hide_viewport
    scn.frame_set(2)
    assert objects[0].hide_viewport and not objects[1].hide_viewport and objects[0].hide_render
    scn.frame_set(1)


# -- panel fixes ----------------------------------------------------------------------------------


def test_presets_include_mogaface_with_a_description_in_panel_operator_and_script(scene):
    import subprocess
    import sys

    from mogaface.core.train.config import PRESETS

    train = ops("train")
    items = {key: description for key, _, description in train.PRESET_ITEMS}
    assert {"mogaface", "mogaface-demo"} <= set(items) <= set(PRESETS)
    assert all(len(text) > 10 for text in items.values())
    for rna in (bpy.context.scene.mogaface.bl_rna, bpy.ops.mogaface.train.get_rna_type()):
        enum = rna.properties["preset"].enum_items
        assert {e.identifier: e.description for e in enum} == items
    bpy.context.scene.mogaface.preset = "mogaface-demo"
    panels = importlib.import_module(MODULE + ".mogaface_addon.panels")
    assert panels.preset_description(bpy.context.scene.mogaface) == items["mogaface-demo"]
    script = addon_test.ROOT / "scripts" / "mogaface_blend.py"
    result = subprocess.run([sys.executable, str(script), "--help"], capture_output=True, text=True, timeout=60)
    assert "mogaface-demo" in result.stdout
    spec = importlib.util.spec_from_file_location("mogaface_blend_script", script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert [name for name, _ in module.PRESETS] == list(items)
    args = module.build_parser().parse_args(["cap", "--run", "r", "--blend", "b", "--preset", "mogaface"])
    assert args.preset == "mogaface"


def test_render_frame_shows_its_image_in_an_image_editor(scene):
    area = bpy.context.window.screen.areas[0]
    old = area.type
    area.type = "IMAGE_EDITOR"
    try:
        bpy.context.scene.frame_set(1)
        assert bpy.ops.mogaface.render_frame() == {"FINISHED"}
        assert area.spaces.active.image.name == render_image_name("Camera", 1)
    finally:
        area.type = old
    assert ops("images").image_editor_area(bpy.context.window_manager) == (None, None)
    assert ops("images").image_editor_area(bpy.context.window_manager, (10**6, 10**6)) == (None, None)


def test_render_animation_job_renders_each_frames_keys_and_cancels(scene):
    scn = bpy.context.scene
    scn.frame_set(1)
    assert bpy.ops.mogaface.render_animation(frame_start=1, frame_end=2) == {"FINISHED"}
    assert scn.frame_current == 1 and ops("render").current_render_job() is None
    animated = addon_test_image(render_image_name("Camera", 2))
    scn.frame_set(2)
    assert bpy.ops.mogaface.render_frame() == {"FINISHED"}
    assert np.abs(addon_test_image(render_image_name("Camera", 2)) - animated).max() < 1e-6
    scn.frame_set(1)
    # a job cancelled after its first frame stops there
    seen = []
    job = ops("jobs").RenderJob(range(1, 6), lambda frame: frame, seen.append, render=lambda request: request)
    while job.step():
        if seen:
            job.cancel()
        time.sleep(0.005)
    assert job.cancelled and job.done == 1 and seen == [1] and job.finished


def addon_test_image(name):
    image = bpy.data.images[name]
    pixels = np.zeros(len(image.pixels), np.float32)
    image.pixels.foreach_get(pixels)
    return pixels


def test_a_finished_training_fills_the_avatar_field(scene, tmp_path):
    train = ops("train")
    from mogaface.core.for_blender.worker import Progress

    run = tmp_path / "run"
    run.mkdir()
    (run / "avatar.pt").write_bytes(b"")
    settings = bpy.context.scene.mogaface
    settings.avatar_file = ""
    reports = []
    operator = types.SimpleNamespace(report=lambda kind, text: reports.append(text))
    train._job["worker"] = types.SimpleNamespace(run=run)
    assert train.finish_job(operator, Progress(state="done", message="finished"), settings) == {"FINISHED"}
    assert settings.avatar_file == str(run / "avatar.pt") and train.current_worker() is None


def test_disabling_mid_training_clears_the_status_bar(scene, monkeypatch):
    train = ops("train")
    cleared, calls = [], []
    workspace_type = type(bpy.context.window.workspace)
    monkeypatch.setattr(ops("jobs"), "clear_status_text", lambda: cleared.append(True))
    worker = types.SimpleNamespace(cancel=lambda: calls.append("cancel"), kill=lambda: calls.append("kill"),
                                   wait=lambda **kwargs: calls.append("wait"))
    train._job["worker"] = worker
    ops("jobs").cancel_child_jobs()
    assert cleared == [True] and calls == ["cancel", "wait", "kill"] and train.current_worker() is None
    common = ops("common")
    bpy.context.window.workspace.status_text_set("MoGaFace training: step 3/10")
    common.clear_status_text()  # runs over every window's workspace without error
    assert workspace_type is type(bpy.context.window.workspace)


class Recorder:
    """Stands in for a UILayout: records labels and properties (with their index)."""

    def __init__(self, log):
        self.log, self.active, self.enabled, self.alert = log, True, True, False

    def _child(self, *args, **kwargs):
        return Recorder(self.log)

    row = column = box = _child

    def label(self, text="", icon="NONE"):
        self.log.append(("label", text))

    def prop(self, data, name, text=None, index=-1, **kwargs):
        self.log.append(("prop", name, index))

    def operator(self, idname, text=None, icon="NONE"):
        self.log.append(("operator", idname))
        return types.SimpleNamespace()

    def template_list(self, *args, **kwargs):
        pass

    def progress(self, **kwargs):
        self.log.append(("progress", kwargs.get("text")))


def test_pose_rows_are_labelled(scene):
    panels = importlib.import_module(MODULE + ".mogaface_addon.panels")
    log = []
    panels.draw_pose(Recorder(log), scene["head"])
    labels = [entry[1] for entry in log if entry[0] == "label"]
    assert labels == ["Rotation", "Translation", "Neck", "Jaw", "Left Eye", "Right Eye"]
    eyes = [entry[2] for entry in log if entry[:2] == ("prop", '["mogaface_eyes_pose"]')]
    assert eyes == [0, 1, 2, 3, 4, 5]


def test_long_texts_wrap_to_the_width():
    text_module = importlib.import_module(MODULE + ".mogaface_addon.text")
    command = '"/home/someone/blender-4.3/4.3/python/bin/python3.11" -m pip install numba torch --target /x/y'
    lines = text_module.wrap_lines(command, 240)
    chars = int(240 / text_module.CHAR_PX) - 3
    assert len(lines) > 1 and all(len(line) <= chars for line in lines)
    assert "".join(lines).replace(" ", "") == command.replace(" ", "")
    assert text_module.wrap_lines(command, 240, ui_scale=2.0) != lines


def test_import_tracking_asks_before_replacing_keys(scene):
    import_tracking = ops("import_tracking")
    head = scene["head"]
    count = import_tracking.existing_keys(head)
    assert count == 4  # two expression keys, two jaw keys
    asked, executed = [], []
    wm = types.SimpleNamespace(invoke_confirm=lambda op, event, **kw: asked.append(kw) or {"RUNNING_MODAL"})
    context = types.SimpleNamespace(window_manager=wm)
    fake = types.SimpleNamespace(directory="/some/flame_param", target=head.name, _target=lambda ctx: head,
                                 execute=lambda ctx: executed.append(True) or {"FINISHED"})
    assert import_tracking.MOGAFACE_OT_import_tracking.invoke(fake, context, None) == {"RUNNING_MODAL"}
    assert asked and str(count) in asked[0]["message"] and not executed
    plain = bpy.data.objects.new("Plain", None)
    fake._target = lambda ctx: plain
    assert import_tracking.MOGAFACE_OT_import_tracking.invoke(fake, context, None) == {"FINISHED"} and executed
    bpy.data.objects.remove(plain)


def test_improve_tracking_asks_before_replacing_keys_and_shows_its_progress(scene, monkeypatch):
    improving = ops("improve_tracking")
    head = scene["head"]
    count = ops("import_tracking").existing_keys(head)
    asked, executed = [], []
    wm = types.SimpleNamespace(invoke_confirm=lambda op, event, **kw: asked.append(kw) or {"RUNNING_MODAL"})
    fake = types.SimpleNamespace(target=head.name, _target=lambda ctx: head,
                                 execute=lambda ctx: executed.append(True) or {"FINISHED"})
    context = types.SimpleNamespace(window_manager=wm)
    assert improving.MOGAFACE_OT_improve_tracking.invoke(fake, context, None) == {"RUNNING_MODAL"}
    assert count and str(count) in asked[0]["message"] and not executed

    from mogaface.core.for_blender.worker import Progress

    panels = importlib.import_module(MODULE + ".mogaface_addon.panels")
    running = types.SimpleNamespace(progress=Progress(state="running", stage="offsets", step=3, steps=50))
    monkeypatch.setitem(improving._job, "worker", running)
    log = []
    panels.draw_improve_tracking(Recorder(log), bpy.context)
    assert ("progress", "offsets 3/50 · compiling") in log and ("operator", "mogaface.improve_tracking_cancel") in log
    assert bpy.ops.mogaface.improve_tracking_cancel.poll()
    monkeypatch.setitem(improving._job, "worker", None)
    monkeypatch.setitem(improving._job, "last", Progress(state="failed", message="improving the tracking failed"))
    log = []
    panels.draw_improve_tracking(Recorder(log), bpy.context)
    assert ("operator", "mogaface.improve_tracking") in log and ("label", "improving the tracking failed") in log


def test_one_heavy_job_at_a_time_training_or_improving(scene, monkeypatch):
    """Training and Improve Tracking each take every core, and improving reads the run a training
    may be rewriting: while one runs, neither starts, with the running one named."""
    improving, train = ops("improve_tracking"), ops("train")
    reports = []
    fake = types.SimpleNamespace(report=lambda kind, text: reports.append((kind, text)))
    monkeypatch.setitem(train._job, "worker", types.SimpleNamespace())
    assert improving.MOGAFACE_OT_improve_tracking.execute(fake, bpy.context) == {"CANCELLED"}
    assert train.MOGAFACE_OT_train._start(fake, bpy.context) is None
    assert reports == [({"ERROR"}, "Training is running: wait for it or cancel it first")] * 2
    monkeypatch.setitem(train._job, "worker", None)
    monkeypatch.setitem(improving._job, "worker", types.SimpleNamespace())
    reports.clear()
    assert train.MOGAFACE_OT_train._start(fake, bpy.context) is None
    assert reports == [({"ERROR"}, "Improving the tracking is running: wait for it or cancel it first")]


def test_the_refined_folder_keyed_is_the_one_in_the_place_of_the_scenes_tracking():
    improving = ops("improve_tracking")
    folders = ["/r/out/seqA/flame_param", "/r/out/seqB/flame_param"]
    assert improving.folder_to_key(folders, "/r/out", "/c/cap", "/c/cap/seqB/flame_param") == folders[1]
    assert improving.folder_to_key(folders, "/r/out", "/c/cap", "/elsewhere/flame_param") == folders[0]
    assert improving.folder_to_key(folders[:1], "/r/out", "", "") == folders[0]


def test_file_operators_run_at_once_with_a_path_and_browse_without(scene):
    """Load Avatar, Import Capture, Import Head and Export PLY share one invoke (operators/common.py)."""
    common = ops("common")
    for module, name in (("load_avatar", "load_avatar"), ("import_capture", "import_capture"),
                         ("import_head", "import_head"), ("export", "export_ply")):
        operator = getattr(ops(module), f"MOGAFACE_OT_{name}")
        assert issubclass(operator, common.OpensFileBrowser) and "invoke" not in vars(operator), name
        browsed, executed = [], []
        wm = types.SimpleNamespace(fileselect_add=lambda op: browsed.append(op.filepath))
        fake = types.SimpleNamespace(filepath="/given/file", suggested_name=operator.suggested_name,
                                     execute=lambda ctx: executed.append(True) or {"FINISHED"})
        context = types.SimpleNamespace(window_manager=wm)
        assert operator.invoke(fake, context, None) == {"FINISHED"} and executed and not browsed, name
        fake.filepath, executed[:] = "", []
        assert operator.invoke(fake, context, None) == {"RUNNING_MODAL"} and not executed, name
        assert browsed == [operator.suggested_name], name
    assert ops("export").MOGAFACE_OT_export_ply.suggested_name == "avatar.ply"


def test_disabling_leaves_the_scene_as_without_the_extension_and_enabling_brings_the_avatar_back(scene):
    """Disabled: the avatar layers are muted (F12 renders the scene alone, never a stale layer), the
    head is its textured mesh again, and no thread of the extension stays; enabled: all as before."""
    import threading

    scn, head = bpy.context.scene, scene["head"]
    bpy.context.view_layer.objects.active = head
    assert bpy.ops.mogaface.setup_render_layer() == {"FINISHED"}
    head.mogaface_show_avatar = True
    ops("common").background_thread("render").submit(time.sleep, 0.01).result()
    before = {"display_type": head.display_type, "show_in_front": head.show_in_front, "hide_render": head.hide_render}
    assert before == {"display_type": "BOUNDS", "show_in_front": True, "hide_render": True}
    layers = ops("handlers.render_layers")
    tree = layers.compositor_tree(scn, create=False)
    tagged = [node.name for node in tree.nodes if layers.NODE_TAG in node]
    assert bpy.ops.preferences.addon_disable(module=MODULE) == {"FINISHED"}
    try:
        assert all(tree.nodes[name].mute for name in tagged)
        combine = next(tree.nodes[name] for name in tagged if tree.nodes[name].bl_idname == "CompositorNodeZcombine")
        assert combine.inputs[0].links[0].from_node.bl_idname == "CompositorNodeRLayers"  # what a muted one passes
        assert (head.display_type, head.show_in_front, head.hide_render) == ("TEXTURED", False, False)
        def extension_threads():  # the training command's signal watcher (mogaface-cancel) is this process's, not Blender's
            return [t.name for t in threading.enumerate()
                    if t.name.startswith("mogaface-") and t.name != "mogaface-cancel"]

        deadline = time.monotonic() + 5
        while extension_threads() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not extension_threads()
    finally:
        assert bpy.ops.preferences.addon_enable(module=MODULE) == {"FINISHED"}
    assert not any(tree.nodes[name].mute for name in tagged)
    assert {name: getattr(head, name) for name in before} == before
    assert "mogaface_suspended" not in head and not any("mogaface_suspended" in tree.nodes[n] for n in tagged)


def test_a_registration_that_cannot_read_the_data_resumes_at_the_first_handler(scene, monkeypatch):
    """Blender enables an extension with ``bpy.data`` unreadable (``RestrictBlend``; the real
    Blender does, the module here lets it through, so it is stood in for): the scenes are resumed by
    the first handler that runs (a frame change, a render), not lost."""
    suspend = ops("handlers.suspend")
    head = scene["head"]
    head.mogaface_show_avatar = True
    suspend.suspend_scenes()
    assert head.display_type == "TEXTURED" and "mogaface_suspended" in head
    monkeypatch.setattr(suspend, "bpy", types.SimpleNamespace(app=bpy.app))  # no bpy.data, as in register()
    suspend.resume_when_data_is_ready()
    monkeypatch.setattr(suspend, "bpy", bpy)
    assert head.display_type == "TEXTURED"
    bpy.context.scene.frame_set(bpy.context.scene.frame_current)  # frame_change_post: resume_pending
    assert head.display_type == "BOUNDS" and "mogaface_suspended" not in head
