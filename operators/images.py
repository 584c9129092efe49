"""Renders as Blender images: float image datablocks, shown in an Image Editor, saved as files."""

from __future__ import annotations

import os

import bpy

from .dependencies import LazyModule

np = LazyModule("numpy")  # imported on first use: registering needs no numpy

#: Blender's name of the scene-linear colour space of float images (OCIO role ``scene_linear``).
SCENE_LINEAR = "Linear Rec.709"


def blender_pixels(rgba) -> np.ndarray:
    """``(H,W,4)`` top row first → Blender's flat pixel order (rows from the bottom), float32."""
    return np.ascontiguousarray(np.asarray(rgba, np.float32)[::-1]).reshape(-1)


def store_image(name: str, result):
    """Write a render into the float image datablock ``name`` (packed into the .blend).

    Its pixels are :func:`core.for_blender.render.blender_rgba`'s: scene-linear, premultiplied, as
    Blender's float buffers hold them, so the view transform "Standard" shows the core's sRGB.
    """
    from ..core.for_blender.render import blender_rgba

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
    """Save a render, atomically, through the core: EXR holds :func:`core.for_blender.render.blender_rgba`
    (scene-linear, premultiplied, as Blender writes EXR); PNG the same pixels as 8-bit sRGB with
    straight alpha, i.e. the core's own sRGB colours (what "Standard" shows)."""
    from ..core.for_blender.render import blender_rgba, srgb_from_blender
    from ..core.io.image import write_exr, write_png

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
