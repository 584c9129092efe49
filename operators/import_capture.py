"""``mogaface.import_capture``: a capture folder's cameras, first-view images and timeline."""

from __future__ import annotations

import os

import bpy
from bpy.props import BoolProperty, StringProperty
from mathutils import Matrix

from .common import OpensFileBrowser, dependencies_ready, run_core
from .dependencies import FILE_MODULES

COLLECTION_NAME = "MoGaFace Capture"


def ensure_collection(scene, name: str):
    """The collection ``name`` linked under the scene's root, created if missing."""
    collection = bpy.data.collections.get(name)
    if collection is None:
        collection = bpy.data.collections.new(name)
    if collection.name not in scene.collection.children:
        scene.collection.children.link(collection)
    return collection


def apply_render_settings(scene, camera_object) -> bool:
    """Make the scene's resolution and pixel aspect those of a capture camera; False if not one.

    Blender keeps resolution and pixel aspect per scene, not per camera, so each capture
    camera remembers its own and this puts them back when it becomes the active camera.
    """
    size = camera_object.get("mogaface_resolution")
    aspect = camera_object.get("mogaface_pixel_aspect")
    if camera_object.type != "CAMERA" or size is None or aspect is None:
        return False
    render = scene.render
    render.resolution_x, render.resolution_y = int(size[0]), int(size[1])
    render.resolution_percentage = 100
    render.pixel_aspect_x, render.pixel_aspect_y = float(aspect[0]), float(aspect[1])
    scene.camera = camera_object
    return True


def _load_image(path):
    if path is None or not os.path.isfile(path):
        return None
    try:
        return bpy.data.images.load(path, check_existing=True)
    except RuntimeError:
        return None


def capture_cameras(collection) -> dict:
    """The capture cameras already in ``collection``, by camera id."""
    objects = collection.objects
    return {obj["mogaface_camera_id"]: obj for obj in objects if obj.type == "CAMERA" and "mogaface_camera_id" in obj}


def build_camera(settings, collection, existing=None):
    """One Blender camera object from core ``BlenderCamera`` settings (``existing`` is updated)."""
    if existing is not None:
        data = existing.data
        data.background_images.clear()
    else:
        data = bpy.data.cameras.new(settings.name)
    data.type = "PERSP"
    data.sensor_fit = settings.sensor_fit
    data.sensor_width = settings.sensor_width
    data.lens = settings.lens
    data.shift_x = settings.shift_x
    data.shift_y = settings.shift_y
    data.clip_start = 0.01
    data.clip_end = 1000.0
    image = _load_image(settings.image_path)
    if image is not None:
        background = data.background_images.new()
        background.image = image
        background.frame_method = "STRETCH"
        background.alpha = 1.0
        data.show_background_images = True
    obj = existing or bpy.data.objects.new(settings.name, data)
    obj.matrix_world = Matrix(settings.matrix_world.tolist())
    obj["mogaface_camera_id"] = settings.camera_id
    obj["mogaface_resolution"] = list(settings.resolution)
    obj["mogaface_pixel_aspect"] = list(settings.pixel_aspect)
    if existing is None:
        collection.objects.link(obj)
    return obj


def subject_points(centre) -> list[tuple]:
    """A box the size of a head around ``centre``: what a view framing the subject shows (the
    cameras, metres away, stay reachable with View All)."""
    from ..core.for_blender.cameras import HEAD_RADIUS

    return [tuple(c + HEAD_RADIUS * sign * (axis == i) for i, c in enumerate(centre))
            for axis in range(3) for sign in (-1, 1)]


def default_cube_around(scene, point):
    """The startup file's 2 m cube, untouched, if it encloses ``point`` (it would hide the head), else None."""
    cube = scene.objects.get("Cube")
    if cube is None or cube.type != "MESH" or len(cube.data.vertices) != 8 or not cube.visible_get():
        return None
    if any(abs(d - 2.0) > 1e-4 for d in cube.dimensions):
        return None
    inside = all(abs(p - c) <= 1.0 for p, c in zip(point, cube.matrix_world.translation))
    return cube if inside else None


def frame_views(context, points) -> None:
    """Point every perspective 3D view of the open windows at ``points`` (a head-sized box around
    where the capture's cameras look), as View Selected would, without changing the selection.
    Nothing happens without a window (background mode)."""
    from ..core.for_blender.render import view_framing

    for window in getattr(context.window_manager, "windows", ()):
        for area in window.screen.areas:
            region = next((r for r in area.regions if r.type == "WINDOW"), None)
            if area.type != "VIEW_3D" or region is None:
                continue
            space = area.spaces.active
            view = space.region_3d
            if view.view_perspective == "CAMERA":
                continue
            centre, distance = view_framing([tuple(p) for p in points], space.lens, region.width, region.height)
            view.view_location = tuple(centre)
            view.view_distance = distance
            view.view_perspective = "PERSP"
            area.tag_redraw()


class MOGAFACE_OT_import_capture(OpensFileBrowser, bpy.types.Operator):
    """Import a capture's cameras (exact intrinsics and poses), first-view images and timeline"""

    bl_idname = "mogaface.import_capture"
    bl_label = "Import Capture"
    bl_options = {"REGISTER", "UNDO"}

    filepath: StringProperty(name="Capture Folder", subtype="DIR_PATH", description="Folder with transforms_train.json")
    filter_folder: BoolProperty(default=True, options={"HIDDEN"})
    refined_cameras: StringProperty(
        name="Refined Cameras", subtype="FILE_PATH", default="",
        description="A training run's cameras_refined.json (camera refinement): the cameras it names take its "
                    "poses; empty: the capture's calibration")
    use_standard_view: BoolProperty(
        name="Standard View Transform", default=True,
        description="Set the scene's view transform to Standard: captures and the avatar are display-referred "
                    "sRGB, and Standard shows their colours as captured (AgX or Filmic would tone-map them)")
    hide_default_cube: BoolProperty(
        name="Hide the Default Cube", default=True,
        description="Hide the startup file's 2 m cube when the head is inside it (it would hide the head); "
                    "Alt H shows it again")

    def execute(self, context):
        if not dependencies_ready(self, context, needs=FILE_MODULES):
            return {"CANCELLED"}
        folder = bpy.path.abspath(self.filepath)
        if os.path.isfile(folder):  # a file of the capture was picked: use its folder
            folder = os.path.dirname(folder)
        refined = bpy.path.abspath(self.refined_cameras) if self.refined_cameras else None
        from ..core.for_blender.cameras import capture_scene

        description = run_core(self, capture_scene, folder, refined)
        if description is None:
            return {"CANCELLED"}
        scene = context.scene
        collection = ensure_collection(scene, COLLECTION_NAME)
        known = capture_cameras(collection)  # importing again updates these in place
        cameras = [build_camera(s, collection, known.get(s.camera_id)) for s in description.cameras]
        if cameras:
            apply_render_settings(scene, cameras[0])
        scene.frame_start = description.frame_start
        scene.frame_end = description.frame_end
        scene.frame_set(description.frame_start)
        scene.mogaface.capture_folder = description.root
        message = f"Imported {len(cameras)} cameras, {description.n_timesteps} timesteps"
        if self.use_standard_view and scene.view_settings.view_transform != "Standard":
            message += f"; view transform {scene.view_settings.view_transform} -> Standard (the captured colours)"
            scene.view_settings.view_transform = "Standard"
            scene.view_settings.look = "None"
        cube = default_cube_around(scene, description.subject_centre) if self.hide_default_cube else None
        if cube is not None:
            cube.hide_set(True)
            cube.hide_render = True
            message += "; the default cube hidden (the head is inside it: Alt H shows it)"
        frame_views(context, subject_points(description.subject_centre))
        if refined:
            message += " (refined poses from the run)"
        if description.moving_cameras:
            message += (f"; {len(description.moving_cameras)} cameras move between sequences (a union dataset): "
                        "placed as in the first sequence")
        self.report({"INFO"}, message)
        return {"FINISHED"}


class MOGAFACE_OT_use_capture_camera(bpy.types.Operator):
    """Make the active capture camera the scene camera, with its own resolution and pixel aspect"""

    bl_idname = "mogaface.use_capture_camera"
    bl_label = "Use Capture Camera"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        obj = context.active_object
        return obj is not None and obj.type == "CAMERA" and "mogaface_resolution" in obj

    def execute(self, context):
        apply_render_settings(context.scene, context.active_object)
        return {"FINISHED"}
