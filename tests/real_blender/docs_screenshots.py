"""The screenshots of docs/blender.md: a demo-preset avatar in the real Blender program, in a window.

Run by hand through scripts/docs_screenshots.sh (not in CI), inside Blender
(``blender --python docs_screenshots.py -- JSON``); the window helpers are ui_check's. The scene:
the demo's capture cameras, the run's head keyed by its tracking, the avatar loaded, a small cube
in front of the cheek and a backdrop behind the head (seen from the held-out camera), the rig's
cameras hidden. Shots (crops of the X screen, 256 colours, ``IMAGES/blender_*.png``): the 3D
viewport in a 3/4 view (Solid), F12's Render Result and Render Frame's image in the Image Editor,
under Standard; the same view with the head's Draw set to GPU beside Draw set to CPU Exact; the
viewport in Material Preview under Standard and AgX, and F12 under AgX. The
viewport's pixels are read back against the core render (ui_check's lines), with the head's
bounds drawn in front and, for the record, in the scene's depth as before.
"""

import math
import os
import pathlib
import subprocess
import sys

import bpy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import ui_check as ui  # noqa: E402 - reads the same JSON argument (work, images)

RUN = pathlib.Path(ui.ARGS["run"])
CAPTURE = ui.ARGS["capture"]
FRAME = ui.ARGS.get("frame", 1)


def extension_module(*attributes):
    """The extension's module that has ``attributes`` (modules move; their contents stay)."""
    for name, module in sorted(sys.modules.items()):
        if name.startswith(ui.MODULE + ".") and module is not None and all(hasattr(module, a) for a in attributes):
            return module
    raise AssertionError(f"no module of the extension has {attributes}")


def crop_shot(name, window, x, y, width, height, long_side=900):
    """The screen's rectangle (Blender's coordinates: from the window's bottom left) as
    ``IMAGES/NAME.png``, downscaled to ``long_side`` pixels."""
    ui.IMAGES.mkdir(parents=True, exist_ok=True)
    screen = ui.WORK / "screen.png"
    subprocess.run(["import", "-window", "root", "-depth", "8", str(screen)], check=True, timeout=60)
    screen_height = int(subprocess.run(["identify", "-format", "%h", str(screen)], check=True,
                                       capture_output=True, text=True).stdout)
    top = screen_height - window.y - y - height
    path = ui.IMAGES / f"{name}.png"
    scale = min(1.0, long_side / max(width, height))
    subprocess.run(["convert", str(screen), "-crop", f"{width}x{height}+{window.x + x}+{top}", "+repage",
                    "-resize", f"{100 * scale:.2f}%", "-colors", "256", "-strip", str(path)], check=True, timeout=60)
    ui.log(f"screenshot {path.name} ({path.stat().st_size // 1024} KB)")


def install_dependencies():
    """Install Dependencies as a user clicks it, when packages are missing (beside Debian's torch)."""
    deps = extension_module("missing_modules", "site_packages")
    install = extension_module("current_install", "last_install_progress")
    if not deps.missing_modules():
        return
    bpy.context.preferences.system.use_online_access = True
    bpy.context.preferences.addons[ui.MODULE].preferences.torch_index = ui.ARGS["torch_index"]
    with ui.override():
        bpy.ops.mogaface.install_dependencies("INVOKE_DEFAULT")
    yield from ui.wait_until(lambda: install.current_install() is None, 3600, "install")
    ui.check(deps.missing_modules() == [], f"missing after the install: {install.last_install_progress()}")


def build_scene():
    """The demo's capture, the run's head keyed by its tracking, its avatar; a cube and a backdrop."""
    from mathutils import Vector

    for name in ("Cube",):
        if name in bpy.data.objects:
            bpy.data.objects.remove(bpy.data.objects[name])
    tracking = RUN / "flame_param_corrected"
    tracking = tracking if tracking.is_dir() else RUN / "flame_param"
    identity = sorted((RUN / "flame_param").glob("*.npz"))
    with ui.override():
        ui.check(bpy.ops.mogaface.import_capture(filepath=CAPTURE) == {"FINISHED"}, "import capture")
        ui.check(bpy.ops.mogaface.import_head(filepath=str(RUN / "head.pkl"),
                                              shape_file=str(identity[0]) if identity else "") == {"FINISHED"},
                 "import head")
        head = bpy.context.active_object
        ui.check(bpy.ops.mogaface.import_tracking(directory=str(tracking), target=head.name) == {"FINISHED"},
                 "import tracking")
        result = bpy.ops.mogaface.load_avatar("INVOKE_DEFAULT", filepath=str(RUN), target=head.name)
        ui.check(result in ({"RUNNING_MODAL"}, {"FINISHED"}), f"load avatar gave {result}")
    yield from ui.wait_until(lambda: "mogaface_avatar_path" in head, 300, "load avatar")  # in a thread
    scene = bpy.context.scene
    scene.frame_set(FRAME)
    held_out = next(o for o in scene.objects if o.get("mogaface_camera_id") == ui.ARGS["camera"])
    ui.check(extension_module("apply_render_settings").apply_render_settings(scene, held_out), "capture camera")
    scene.render.resolution_percentage = 200

    bpy.context.view_layer.update()
    centre = sum((head.matrix_world @ v.co for v in head.data.vertices), Vector()) / len(head.data.vertices)
    eye = held_out.matrix_world.translation
    forward = (centre - eye).normalized()
    right = forward.cross(Vector((0.0, 0.0, 1.0))).normalized()
    up = right.cross(forward)
    bpy.ops.mesh.primitive_cube_add(size=0.07, location=centre - forward * 0.11 + right * 0.07 - up * 0.03)
    cube = bpy.context.active_object
    cube.rotation_euler = (0.3, 0.2, 0.5)
    material = bpy.data.materials.new("Cube")
    material.diffuse_color = (0.8, 0.25, 0.04, 1.0)
    material.use_nodes = True
    material.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.8, 0.25, 0.04, 1.0)
    cube.data.materials.append(material)
    bpy.ops.mesh.primitive_plane_add(size=1.5, location=centre + forward * 0.3)
    backdrop = bpy.context.active_object
    backdrop.rotation_euler = forward.to_track_quat("Z", "Y").to_euler()
    light_grey = bpy.data.materials.new("Backdrop")
    light_grey.use_nodes = True
    shader = light_grey.node_tree.nodes["Principled BSDF"]
    shader.inputs["Base Color"].default_value = shader.inputs["Emission Color"].default_value = (0.5, 0.55, 0.6, 1)
    shader.inputs["Emission Strength"].default_value = 1.0
    backdrop.data.materials.append(light_grey)
    for obj in scene.objects:
        obj.select_set(obj == head)
        if obj.type == "CAMERA":  # the rig's cameras hidden in the viewport (H), as a user tidies up
            obj.hide_set(True)
    bpy.context.view_layer.objects.active = head
    return head, held_out


def still_viewport(viewport, region):
    """A generator step: until the avatar in the view is the still image at the region's size."""

    def ready():
        ui.window_and_view()[1].tag_redraw()
        states = [s for s in viewport._views.values() if s.image is not None]
        return bool(states) and all(s.future is None for s in viewport._views.values()) and \
            (states[0].image.width, states[0].image.height) == (region.width, region.height)

    yield from ui.wait_until(ready, 600, "the still viewport at the region's size")
    yield 1.0


def draw_switch_shots(head, viewport):
    """The same view drawn by the GPU (Draw: GPU) and by the splat engine (Draw: CPU Exact), side by
    side in ``IMAGES/blender_viewport_gpu.png``; the switch back to Both after."""
    window, area, region = ui.window_and_view()

    def gpu_drawn():
        area.tag_redraw()
        return any(s.gpu is not None and s.gpu.order.packed is not None for s in viewport._views.values())

    # the view alone: the toolbar, the sidebar and the headers overlap the region
    widths = {r.type: (r.width, r.height) for r in area.regions}
    left, right = widths.get("TOOLS", (0, 0))[0], widths.get("UI", (0, 0))[0]
    top = widths.get("HEADER", (0, 0))[1] + widths.get("TOOL_HEADER", (0, 0))[1]
    halves = []
    for mode in ("GPU", "CPU"):
        setattr(head, viewport.DRAW_PROPERTY, mode)
        if mode == "GPU":
            yield from ui.wait_until(gpu_drawn, 120, "the GPU draw in the viewport")
        else:
            yield from still_viewport(viewport, region)
        area.tag_redraw()
        yield 1.5
        name = f"draw-{mode.lower()}"
        crop_shot(name, window, region.x + left, region.y, region.width - left - right, region.height - top, 560)
        halves.append(ui.IMAGES / f"{name}.png")
    setattr(head, viewport.DRAW_PROPERTY, "BOTH")
    path = ui.IMAGES / "blender_viewport_gpu.png"
    subprocess.run(["convert", str(halves[0]), "-size", "8x1", "xc:white", str(halves[1]), "+append",
                    "+dither", "-colors", "256", "-strip", f"PNG8:{path}"], check=True, timeout=60)
    ui.log(f"screenshot {path.name} ({path.stat().st_size // 1024} KB)")


def viewport_shots(head, viewport):
    from mathutils import Euler

    window, area, region = ui.window_and_view()
    with ui.override():
        bpy.ops.view3d.view_selected()
    region_3d = area.spaces.active.region_3d
    region_3d.view_rotation = Euler((math.radians(78), 0.0, math.radians(-35))).to_quaternion()
    region_3d.view_distance *= 1.25
    yield from ui.close_render_windows()
    yield from still_viewport(viewport, region)
    crop_shot("blender_viewport", window, area.x, area.y, area.width, area.height)
    yield from draw_switch_shots(head, viewport)
    yield from still_viewport(viewport, region)
    yield from ui.viewport_pixels(head, viewport)  # the pixels lines; overlays off, then on
    shading = area.spaces.active.shading
    shading.type = "MATERIAL"  # EEVEE draws the scene's objects through the view transform
    for transform in ("Standard", "AgX"):
        bpy.context.scene.view_settings.view_transform = transform
        area.tag_redraw()
        yield 8.0
        suffix = "" if transform == "Standard" else "_agx"
        crop_shot(f"blender_viewport_material{suffix}", window, area.x, area.y, area.width, area.height)
    bpy.context.scene.view_settings.view_transform = "Standard"
    shading.type = "SOLID"
    area.tag_redraw()
    yield 1.0

    # For the record, the same with the head's bounds in the scene's depth (as before they were
    # drawn in front): their front edges cut the face.
    shown_display = viewport.display_for_avatar

    def bounds_in_scene_depth(obj):
        shown_display(obj)
        obj.show_in_front = False

    viewport.display_for_avatar = bounds_in_scene_depth
    head.show_in_front = False
    try:
        area.tag_redraw()
        yield 1.5
        crop_shot("before-bounds-in-scene-depth", window, area.x, area.y, area.width, area.height)
        ui.log("the pixels below: the head's bounds in the scene's depth (the display before)")
        yield from ui.viewport_pixels(head, viewport)
    finally:
        viewport.display_for_avatar = shown_display
        shown_display(head)


def f12_shots():
    """F12 (EEVEE) with the avatar layer, its Render Result shown in the big area as an Image Editor."""
    with ui.override():
        ui.check(bpy.ops.mogaface.setup_render_layer() == {"FINISHED"}, "avatar in renders")
        bpy.ops.render.render()
    window, area, _ = ui.window_and_view()
    area.ui_type = "IMAGE_EDITOR"
    area.spaces.active.image = bpy.data.images["Render Result"]
    area.spaces.active.show_region_ui = False
    yield 1.0
    region = next(r for r in area.regions if r.type == "WINDOW")
    with bpy.context.temp_override(window=window, area=area, region=region):
        bpy.ops.image.view_all(fit_view=True)
    for transform in ("Standard", "AgX"):
        bpy.context.scene.view_settings.view_transform = transform
        area.tag_redraw()
        yield 1.5
        suffix = "" if transform == "Standard" else "_agx"
        crop_shot(f"blender_f12{suffix}", window, area.x, area.y, area.width, area.height)
    bpy.context.scene.view_settings.view_transform = "Standard"
    area.ui_type = "VIEW_3D"
    yield 1.0


def render_frame_shot(head):
    """Render Frame: the avatar alone from the scene camera, shown in the largest Image Editor (here
    the big area, switched to one as a user does; else Blender opens a window for it)."""
    window, area, _ = ui.window_and_view()
    area.ui_type = "IMAGE_EDITOR"
    yield 1.0
    with bpy.context.temp_override(window=window, area=area):
        ui.check(bpy.ops.mogaface.render_frame(head=head.name) == {"FINISHED"}, "render frame")
    ui.check(area.spaces.active.image is not None and area.spaces.active.image.name.startswith("MoGaFace "),
             f"Render Frame's image is not in the Image Editor: {area.spaces.active.image}")
    area.tag_redraw()
    yield 2.0
    crop_shot("blender_render_frame", window, area.x, area.y, area.width, area.height)
    area.ui_type = "VIEW_3D"
    yield 1.0


def stages():
    yield from ui.show_panel()
    yield 2.0
    yield from install_dependencies()
    head, _ = yield from build_scene()
    viewport = extension_module("shown_heads", "SHOW_PROPERTY", "viewport_request")
    yield from ui.show_panel()
    yield from viewport_shots(head, viewport)
    yield from f12_shots()
    yield from render_frame_shot(head)


ui.RUNNER = stages()

if __name__ == "__main__":
    bpy.app.timers.register(ui.step, first_interval=2.0)
