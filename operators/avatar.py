"""``mogaface.load_avatar``, ``render_frame``, ``render_animation``, ``export_ply``.

A trained avatar is linked to a head object (its path is a custom property of the head). A
render reads what the head shows at a frame (expression shape-key values and pose properties,
i.e. what the keyframes give), the active camera converted back to OpenCV, and calls the core's
one render; the image goes into ``bpy.data.images``. All maths is in ``core.scene_conversion``.
"""

from __future__ import annotations

import os

import bpy
from bpy.props import BoolProperty, EnumProperty, IntProperty, StringProperty

from .common import clear_status_text, core_or_report, redraw_areas, run_core
from .dependencies import LazyModule
from .handlers.head_rig import AVATAR_PATH_PROPERTY, expression_values, head_objects, is_head, pose_values, rig_of

np = LazyModule("numpy")  # imported on first use: registering needs no numpy

BACKGROUND_PROPERTY = "mogaface_avatar_background"
#: Blender's name of the scene-linear colour space of float images (OCIO role ``scene_linear``).
SCENE_LINEAR = "Linear Rec.709"


def avatar_heads(scene) -> list:
    return [obj for obj in head_objects(scene) if AVATAR_PATH_PROPERTY in obj]


def _head_with_avatar(operator, context, name: str):
    """The named head, else the active one, else the scene's only head with an avatar; or report."""
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
    from ..core import scene_conversion as sc

    data = camera_obj.data
    render = scene.render
    scale = render.resolution_percentage / 100.0
    resolution = (max(1, round(render.resolution_x * scale)), max(1, round(render.resolution_y * scale)))
    relative = np.array(head.matrix_world.inverted_safe() @ camera_obj.matrix_world)
    return sc.opencv_camera(relative, data.lens, data.sensor_width, data.sensor_height, data.sensor_fit,
                            data.shift_x, data.shift_y, resolution,
                            (render.pixel_aspect_x, render.pixel_aspect_y), camera_id=camera_obj.name)


def head_values(head, frame: float | None = None) -> dict:
    """What the head shows: identity, expression values and pose, unfitted.

    ``frame=None``: as shown now (after ``frame_set``). A frame number: what its keyframes give
    at that frame (F-curves evaluated, the timeline untouched), as renders of other frames need.
    """
    from ..core import scene_conversion as sc

    n_expr = rig_of(head).model.n_expr
    values = {"shape": np.asarray(head.get(sc.SHAPE_PROPERTY, []), np.float64),
              "expr": expression_values(head, n_expr), **pose_values(head)}
    offset = head.get(sc.STATIC_OFFSET_PROPERTY)
    if offset is not None:
        values["static_offset"] = np.asarray(offset, np.float64)
    if frame is not None:
        _apply_fcurves(head, frame, values, n_expr)
    return values


def _apply_fcurves(head, frame: float, values: dict, n_expr: int) -> None:
    """Overwrite ``values`` with the head's F-curves (expression keys, pose properties) at ``frame``."""
    from ..core.scene_conversion import POSE_PROPERTIES
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
    from ..core.scene_render import fitted_params

    return fitted_params(head_values(head), avatar)


def head_request(scene, head, camera, frame: int, transparent: bool = False, keyed: bool = False):
    """The render request of the head's avatar seen by ``camera`` (a core Camera): as shown now,
    or with ``keyed`` as its keyframes give at ``frame``."""
    from ..core import scene_conversion as sc
    from ..core.scene_render import RenderRequest

    background = None if transparent else tuple(head.get(BACKGROUND_PROPERTY, (1.0, 1.0, 1.0)))
    scale = float(np.cbrt(abs(np.linalg.det(np.array(head.matrix_world)[:3, :3])))) or 1.0
    values = head_values(head, frame if keyed else None)
    return RenderRequest(head[sc.AVATAR_PATH_PROPERTY], values, camera, background, scale, frame)


def render_head(context, head, camera_obj, frame: int):
    """Render the head's avatar at ``frame`` from ``camera_obj``: the core's ``RenderResult``."""
    from ..core.scene_render import render

    scene = context.scene
    scene.frame_set(frame)
    return render(head_request(scene, head, camera_of(scene, camera_obj, head), frame))


def blender_pixels(rgba) -> np.ndarray:
    """``(H,W,4)`` top row first → Blender's flat pixel order (rows from the bottom), float32."""
    return np.ascontiguousarray(np.asarray(rgba, np.float32)[::-1]).reshape(-1)


def store_image(name: str, result):
    """Write a render into the float image datablock ``name`` (packed into the .blend).

    Its pixels are :func:`core.scene_render.blender_rgba`'s: scene-linear, premultiplied, as
    Blender's float buffers hold them, so the view transform "Standard" shows the core's sRGB.
    """
    from ..core.scene_render import blender_rgba

    rgba = blender_rgba(result)
    height, width = rgba.shape[:2]
    image = bpy.data.images.get(name)
    if image is not None and tuple(image.size) != (width, height):
        bpy.data.images.remove(image)
        image = None
    if image is None:
        image = bpy.data.images.new(name, width, height, alpha=True, float_buffer=True)
    image.colorspace_settings.name = SCENE_LINEAR
    image.alpha_mode = "PREMUL"
    image.pixels.foreach_set(blender_pixels(rgba))
    image.file_format = "OPEN_EXR"
    image.use_fake_user = True  # an image no one uses would not be saved in the .blend
    image.pack()
    image.update()
    return image


#: The smallest Image Editor (pixels) a render is shown in; a smaller one is passed over.
MIN_IMAGE_EDITOR = (400, 300)
#: The smallest render window opened for it (Blender sizes its render window to the scene's resolution).
RENDER_WINDOW = (640, 480)


def image_editor_area(window_manager, min_size=(1, 1)):
    """The largest Image Editor area of the open windows at least ``min_size`` pixels, and its window."""
    found = [(area.width * area.height, area, window) for window in getattr(window_manager, "windows", ())
             for area in window.screen.areas
             if area.type == "IMAGE_EDITOR" and area.width >= min_size[0] and area.height >= min_size[1]]
    if not found:
        return None, None
    _, area, window = max(found, key=lambda item: item[0])
    return area, window


def show_image(context, image):
    """Show ``image`` whole in an Image Editor big enough to see it (at least :data:`MIN_IMAGE_EDITOR`):
    the largest one open, else one opened as Blender opens its render view (Preferences ›
    Interface › Render In, a new window by default). Returns the area, or None without a window
    (background mode)."""
    area, window = image_editor_area(context.window_manager, MIN_IMAGE_EDITOR)
    main_window = context.window or next(iter(getattr(context.window_manager, "windows", ())), None)
    if area is None and main_window is not None and not bpy.app.background:
        # Blender sizes its render window to the scene's resolution: a 48-pixel capture would get
        # a window too small to see. Ask for one at least RENDER_WINDOW (the setting is restored).
        render = context.scene.render
        percent = render.resolution_percentage
        side = max(RENDER_WINDOW[0] / max(render.resolution_x, 1), RENDER_WINDOW[1] / max(render.resolution_y, 1))
        render.resolution_percentage = min(32767, max(percent, int(np.ceil(100 * side))))
        try:
            with context.temp_override(window=main_window):
                bpy.ops.render.view_show("INVOKE_DEFAULT")
        finally:
            render.resolution_percentage = percent
    if area is None:
        area, window = image_editor_area(context.window_manager)  # the one just opened, or a small one
    if area is not None:
        area.spaces.active.image = image
        region = next((r for r in area.regions if r.type == "WINDOW"), None)
        if window is not None and region is not None and not bpy.app.background:
            with context.temp_override(window=window, area=area, region=region):
                bpy.ops.image.view_all(fit_view=True)
        area.tag_redraw()
    return area


def show_image_soon(image_name: str) -> None:
    """:func:`show_image` from a timer: a modal handler must not open the render window itself
    (Blender then called the finished handler once more)."""
    def show():
        image = bpy.data.images.get(image_name)
        if image is not None:
            show_image(bpy.context, image)

    bpy.app.timers.register(show, first_interval=0.0)


def write_files(folder: str, stem: str, result, file_format: str) -> list[str]:
    """Save a render, atomically, through the core: EXR holds :func:`core.scene_render.blender_rgba`
    (scene-linear, premultiplied, as Blender writes EXR); PNG the same pixels as 8-bit sRGB with
    straight alpha, i.e. the core's own sRGB colours (what "Standard" shows)."""
    from ..core.io.image import write_exr, write_png
    from ..core.scene_render import blender_rgba, srgb_from_blender

    rgba = blender_rgba(result)
    folder = bpy.path.abspath(folder)
    os.makedirs(folder, exist_ok=True)
    paths = []
    if file_format in ("PNG", "BOTH"):
        path = os.path.join(folder, f"{stem}.png")
        alpha = rgba[..., 3:4]
        straight = np.divide(srgb_from_blender(rgba), alpha, out=np.zeros_like(rgba[..., :3]), where=alpha > 0)
        write_png(path, np.concatenate([straight, alpha], axis=2))
        paths.append(path)
    if file_format in ("EXR", "BOTH"):
        path = os.path.join(folder, f"{stem}.exr")
        write_exr(path, rgba[..., :3], rgba[..., 3])
        paths.append(path)
    return paths


def _located_avatar(core, path: str):
    """The avatar file, its training background and the loaded avatar (thread-safe core work)."""
    from .dependencies import preload_native_libraries

    preload_native_libraries()  # the first load imports torch: its libraries, without the GIL
    found, background = core.avatar_location(path)
    return found, background, core.load_avatar(found)


class MOGAFACE_OT_load_avatar(bpy.types.Operator):
    """Link a trained avatar (run folder or avatar.pt) to a head, for rendering and export.
    It loads in the background; Blender stays usable"""

    bl_idname = "mogaface.load_avatar"
    bl_label = "Load Avatar"
    bl_options = {"REGISTER", "UNDO"}

    filepath: StringProperty(name="Avatar", subtype="FILE_PATH", description="Run folder or avatar.pt")
    target: StringProperty(name="Head", description="Head object (empty: the active object)")

    _timer = None
    _future = None

    def invoke(self, context, event):
        if self.filepath:
            return self.execute(context)
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        obj = bpy.data.objects.get(self.target) if self.target else context.active_object
        if not is_head(obj):
            self.report({"ERROR"}, f"{self.target or getattr(obj, 'name', 'nothing')} is not a MoGaFace head")
            return {"CANCELLED"}
        core = core_or_report(self, context)
        if core is None:
            return {"CANCELLED"}
        self.target = obj.name
        path = bpy.path.abspath(self.filepath)
        if bpy.app.background or context.window is None:  # timers never run headless: load here
            return self._link(context, run_core(self, _located_avatar, core, path))
        from .render_job import executor

        # Reading the file and importing torch take seconds: a thread does it, a timer collects it.
        self._future = executor().submit(_located_avatar, core, path)
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.05, window=context.window)
        wm.modal_handler_add(self)
        context.workspace.status_text_set(f"MoGaFace: loading the avatar {os.path.basename(path.rstrip(os.sep))}")
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type != "TIMER" or not self._future.done():
            return {"PASS_THROUGH"}
        context.window_manager.event_timer_remove(self._timer)
        clear_status_text()
        return self._link(context, run_core(self, self._future.result))

    def _link(self, context, loaded) -> set:
        """Link a loaded avatar to the head (main thread), or report why not."""
        from ..core import scene_conversion as sc

        obj = bpy.data.objects.get(self.target)
        if loaded is None:
            return {"CANCELLED"}
        if not is_head(obj):
            self.report({"ERROR"}, f"{self.target} was removed while its avatar loaded")
            return {"CANCELLED"}
        path, background, avatar = loaded
        vertices = avatar.flame.n_vertices
        if vertices != len(obj.data.vertices):
            self.report({"ERROR"}, f"{path}: the avatar's head has {vertices} vertices, {obj.name} has "
                        f"{len(obj.data.vertices)}: import the avatar's head model (head.pkl beside it)")
            return {"CANCELLED"}
        obj[sc.AVATAR_PATH_PROPERTY] = str(path)
        obj[BACKGROUND_PROPERTY] = list(background)
        if getattr(obj, "mogaface_show_avatar", False):
            obj.display_type = "BOUNDS"  # the avatar is drawn in the viewport; the mesh would cover it
        context.scene.mogaface.avatar_file = str(path)
        redraw_areas(context, ("VIEW_3D", "PROPERTIES"))
        self.report({"INFO"}, f"{obj.name}: avatar with {len(avatar.gaussians)} Gaussians")
        return {"FINISHED"}


class _RenderBase:
    head: StringProperty(name="Head", description="Head object with an avatar (empty: the active one)")
    directory: StringProperty(name="Folder", subtype="DIR_PATH", description="Also save files here (empty: none)")
    file_format: EnumProperty(
        name="Files", default="PNG",
        items=(("PNG", "PNG", "8-bit sRGB with alpha"), ("EXR", "EXR", "linear float with alpha"),
               ("BOTH", "Both", "PNG and EXR")),
    )

    def _prepare(self, context):
        camera = context.scene.camera
        if camera is None or camera.type != "CAMERA":
            self.report({"ERROR"}, "The scene has no active camera")
            return None
        if core_or_report(self, context) is None:
            return None
        head = _head_with_avatar(self, context, self.head)
        return None if head is None else (head, camera)

    def _request(self, context, head, camera, frame: int):
        """The request of ``frame`` (main thread: it moves the scene to that frame)."""
        scene = context.scene
        scene.frame_set(frame)
        return head_request(scene, head, camera_of(scene, camera, head), frame)

    def _store(self, camera, result):
        """Put a finished render into its image (and files); returns the image or None."""
        from ..core import scene_conversion as sc

        frame = result.request.frame
        image = store_image(sc.render_image_name(camera.name, frame), result)
        if self.directory:
            written = run_core(self, write_files, self.directory, f"{camera.name}_{frame:04d}".replace(" ", "_"),
                               result, self.file_format)
            if written is None:
                return None
        return image

    def _render(self, context, head, camera, frame: int):
        from ..core.scene_render import render

        result = run_core(self, lambda: render(self._request(context, head, camera, frame)))
        return None if result is None else self._store(camera, result)


class MOGAFACE_OT_render_frame(_RenderBase, bpy.types.Operator):
    """Render the avatar at the current frame from the active camera into an image"""

    bl_idname = "mogaface.render_frame"
    bl_label = "Render Frame"
    bl_options = {"REGISTER"}

    def execute(self, context):
        prepared = self._prepare(context)
        if prepared is None:
            return {"CANCELLED"}
        image = self._render(context, *prepared, context.scene.frame_current)
        if image is None:
            return {"CANCELLED"}
        show_image(context, image)
        self.report({"INFO"}, f"Rendered {image.name}")
        return {"FINISHED"}


#: The one running Render Animation job (a RenderJob), for the panel's progress and Cancel.
_animation = {"job": None}


def current_render_job():
    return _animation["job"]


class MOGAFACE_OT_render_animation(_RenderBase, bpy.types.Operator):
    """Render the avatar at every frame of the scene's range from the active camera into images,
    in the background with progress (Esc or Cancel stops it)"""

    bl_idname = "mogaface.render_animation"
    bl_label = "Render Animation"
    bl_options = {"REGISTER"}

    frame_start: IntProperty(name="Start", default=0, description="First frame (0: the scene's)")
    frame_end: IntProperty(name="End", default=0, description="Last frame (0: the scene's)")
    frame_step: IntProperty(name="Step", default=1, min=1)

    _timer = None

    def _job(self, context):
        if _animation["job"] is not None:
            self.report({"ERROR"}, "An animation is already being rendered: cancel it first")
            return None
        prepared = self._prepare(context)
        if prepared is None:
            return None
        head, camera = prepared
        scene = context.scene
        start = self.frame_start or scene.frame_start
        end = self.frame_end or scene.frame_end
        frames = list(range(start, end + 1, self.frame_step))
        if not frames:
            self.report({"ERROR"}, f"Empty frame range {start}..{end}")
            return None
        images = []

        def make_request(frame):  # the keys at that frame: the timeline stays where the user left it
            return head_request(scene, head, camera_of(scene, camera, head), frame, keyed=True)

        def on_result(result):
            image = self._store(camera, result)
            if image is None:
                job.cancel()
            else:
                images.append(image)

        from .render_job import RenderJob

        job = RenderJob(frames, make_request, on_result)
        job.images = images
        _animation["job"] = job
        return job

    def _finish(self, context, job) -> set:
        _animation["job"] = None
        if job.error is not None:
            self.report({"ERROR"}, job.error)
            return {"CANCELLED"}
        if job.images:
            if bpy.app.background or context.window is None:
                show_image(context, job.images[-1])
            else:
                show_image_soon(job.images[-1].name)
        frames = job.frames
        if job.cancelled:
            self.report({"WARNING"}, f"Render cancelled after {job.done} of {len(frames)} frames")
            return {"CANCELLED"}
        self.report({"INFO"}, f"Rendered {len(frames)} frames ({frames[0]}..{frames[-1]})")
        return {"FINISHED"}

    def execute(self, context):
        job = self._job(context)
        if job is None:
            return {"CANCELLED"}
        if bpy.app.background or context.window is None:  # timers never run headless
            return self._finish(context, job.run())
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.05, window=context.window)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def invoke(self, context, event):
        return self.execute(context)

    def modal(self, context, event):
        job = _animation["job"]
        if event.type == "ESC" and job is not None:
            job.cancel()
        if event.type not in ("TIMER", "ESC"):
            return {"PASS_THROUGH"}
        running = job is not None and job.step()
        if running:
            context.workspace.status_text_set(f"MoGaFace rendering: {job.text()} (Esc to cancel)")
            redraw_areas(context)
            return {"PASS_THROUGH"}
        context.window_manager.event_timer_remove(self._timer)
        clear_status_text()
        if job is None:  # finished already
            return {"CANCELLED"}
        return self._finish(context, job)


class MOGAFACE_OT_render_cancel(bpy.types.Operator):
    """Stop rendering the animation after the current frame"""

    bl_idname = "mogaface.render_cancel"
    bl_label = "Cancel Rendering"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        return _animation["job"] is not None

    def execute(self, context):
        _animation["job"].cancel()
        return {"FINISHED"}


def cancel_render_job() -> None:
    """Stop a running animation render (the extension is being disabled)."""
    job = _animation["job"]
    if job is not None:
        job.cancel()
        _animation["job"] = None
        clear_status_text()


class MOGAFACE_OT_export_ply(bpy.types.Operator):
    """Export the avatar's posed Gaussians (world space) as a 3DGS .ply, for a frame or a range"""

    bl_idname = "mogaface.export_ply"
    bl_label = "Export PLY"
    bl_options = {"REGISTER"}

    filepath: StringProperty(name="File", subtype="FILE_PATH",
                             description="Output .ply; with a range, the frame number is added to the name")
    filter_glob: StringProperty(default="*.ply", options={"HIDDEN"})
    head: StringProperty(name="Head", description="Head object with an avatar (empty: the active one)")
    use_range: BoolProperty(name="Frame Range", default=False, description="Export every frame of the range")
    frame_start: IntProperty(name="Start", default=0, description="First frame (0: the scene's)")
    frame_end: IntProperty(name="End", default=0, description="Last frame (0: the scene's)")

    def invoke(self, context, event):
        if self.filepath:
            return self.execute(context)
        self.filepath = "avatar.ply"
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        if not self.filepath:
            self.report({"ERROR"}, "No output file given")
            return {"CANCELLED"}
        if core_or_report(self, context) is None:
            return {"CANCELLED"}
        head = _head_with_avatar(self, context, self.head)
        if head is None:
            return {"CANCELLED"}
        from ..core import scene_conversion as sc
        from ..core.avatar.export import export_world_ply

        scene = context.scene
        path = bpy.path.abspath(self.filepath)
        if not path.lower().endswith(".ply"):
            path += ".ply"
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        if self.use_range:
            frames = list(range(self.frame_start or scene.frame_start, (self.frame_end or scene.frame_end) + 1))
        else:
            frames = [scene.frame_current]
        current, written = scene.frame_current, []
        try:
            for frame in frames:
                scene.frame_set(frame)
                avatar = run_core(self, sc.load_avatar, head[sc.AVATAR_PATH_PROPERTY])
                if avatar is None:
                    return {"CANCELLED"}
                out = path if not self.use_range else f"{path[:-4]}_{frame:04d}.ply"
                if run_core(self, export_world_ply, avatar, head_params(head, avatar), out) is None:
                    return {"CANCELLED"}
                written.append(out)
        finally:
            scene.frame_set(current)
        self.report({"INFO"}, f"Wrote {written[0]}" if len(written) == 1 else f"Wrote {len(written)} PLY files")
        return {"FINISHED"}
