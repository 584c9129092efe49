"""The avatar, live in the 3D viewport: a draw handler that shows our splat engine's render.

Each redraw of a 3D view builds the render request of every shown avatar from the view's own
matrices (:func:`viewport_request`); a request that differs from the last one goes to a render
thread, and the view keeps drawing the last finished image (:class:`ViewportImage`) until the new
one arrives (a timer then asks for a redraw). While the view moves, requests are made at a
lower resolution; once it has been still for :data:`SETTLE_S`, at the region's own pixel size
(``region.width``/``height`` are device pixels, HiDPI included), so one render pixel is one screen
pixel and the image is sharp.

The image is drawn as a full-view quad through Blender's ``gpu`` module; its fragment shader
writes the avatar's depth as fragment depth, so scene geometry in front hides it and geometry
behind it is hidden. Everything up to the pixel buffer (:func:`viewport_image`) is plain data and
runs without a window; only :func:`draw_image` needs a GPU context.

Beside that exact image, the GPU draws the Gaussians themselves (:mod:`.gpu_draw`) at the
speed of the view: a per-head switch (:data:`DRAW_PROPERTY`) picks the GPU draw, the CPU image,
or both: the GPU while the view moves, during playback and until the CPU image of the resting
view arrives, then that image. Where the GPU draw cannot run, the CPU image is drawn.
"""

from __future__ import annotations

import dataclasses
import time

import bpy
from bpy.props import BoolProperty, EnumProperty

from ..common import background_thread
from ..dependencies import LazyModule
from . import gpu_draw
from .heads import AVATAR_PATH_PROPERTY, is_head

np = LazyModule("numpy")  # imported on first use: registering needs no numpy

#: Seconds a view must be still before it is drawn at full resolution.
SETTLE_S = 0.3
#: Per-object switch (registered on ``bpy.types.Object``).
SHOW_PROPERTY = "mogaface_show_avatar"
#: Per-object choice of the draw (registered on ``bpy.types.Object``): GPU, CPU or BOTH.
DRAW_PROPERTY = "mogaface_viewport_draw"
DRAW_MODES = (
    ("BOTH", "Both", "The GPU draw while the view moves or plays, the exact CPU image once it rests "
                     "(the CPU image alone on a software OpenGL, where the GPU draw would hold the interface)"),
    ("GPU", "GPU", "Always the GPU draw of the Gaussians (interactive; per-Gaussian colour decoding)"),
    ("CPU", "CPU Exact", "Always the CPU render of the splat engine (exact; slower to follow the view)"),
)


@dataclasses.dataclass
class ViewportImage:
    """What the draw uploads: ``rgba`` premultiplied and ``depth`` window depths in [0, 1], both
    flat float32 in OpenGL row order (bottom row first), ``width`` x ``height``; ``key`` names the
    request it answers."""

    width: int
    height: int
    rgba: np.ndarray
    depth: np.ndarray
    key: str


#: Alpha from which the avatar counts as opaque in the viewport: drawn with alpha 1, so nothing
#: behind it (the grid, a camera's lines) shows through the face.
OPAQUE_ALPHA = 0.98


def draw_size(region_width: int, region_height: int, max_side: int | None = None,
              percent: int = 100) -> tuple[int, int]:
    """The render size for a region: ``percent`` of its own, and the longer side at most ``max_side``."""
    factor = percent / 100.0
    if max_side is not None:
        factor = min(factor, max_side / max(region_width, region_height, 1))
    factor = min(1.0, factor)
    return max(1, round(region_width * factor)), max(1, round(region_height * factor))


def viewport_request(head, view_matrix, projection, size: tuple[int, int], frame: int = 0):
    """The render request of ``head``'s avatar seen by a 3D view, and the view's camera.

    ``view_matrix``/``projection``: ``RegionView3D.view_matrix`` / ``window_matrix``.
    """
    from ...core.for_blender.render import RenderRequest, view_camera
    from ..avatar_head import head_values

    view = view_camera(np.array(view_matrix), np.array(projection), np.array(head.matrix_world), *size)
    request = RenderRequest(head[AVATAR_PATH_PROPERTY], head_values(head), view.camera, None, view.scale, frame)
    return request, view


def viewport_image(result, view, projection) -> ViewportImage:
    """A finished render as the draw's pixel buffers (rows flipped, depth in window units).

    The colours are :func:`core.for_blender.render.blender_rgba`'s, as everywhere. A ``POST_VIEW``
    handler draws into the view's overlay buffer, which holds linear values encoded as sRGB and
    is laid over the scene after its view transform: the avatar is shown with the core's sRGB
    colours under every view transform, exactly as the capture photo a camera shows as its
    background image (checked in Blender 4.3 by reading the screen back).
    """
    from ...core.for_blender.render import blender_rgba, depth_buffer_values

    height, width = result.alpha.shape
    rgba = blender_rgba(result)
    opaque = rgba[..., 3] >= OPAQUE_ALPHA
    rgba[opaque] /= rgba[opaque][:, 3:4]  # alpha 1, the colour unchanged
    rgba = np.ascontiguousarray(rgba[::-1], np.float32).reshape(-1)
    depth = depth_buffer_values(result.depth - view.depth_offset, projection)
    return ViewportImage(width, height, rgba, np.ascontiguousarray(depth[::-1]).reshape(-1), result.request.key())


def shown_heads(scene) -> list:
    """Heads of ``scene`` whose avatar is switched on for the viewport."""
    from ..avatar_head import avatar_heads

    return [obj for obj in avatar_heads(scene) if getattr(obj, SHOW_PROPERTY, False) and obj.visible_get()]


class ViewState:
    """One (view, head) pair: the request in flight and the last finished image."""

    def __init__(self):
        self.image: ViewportImage | None = None
        self.texture = None  # (key, color texture, depth texture)
        self.future = None
        self.pending_key: str | None = None
        self.view_key = None
        self.view_changed = 0.0
        self.error: str | None = None
        self.gpu = None  # gpu_draw.GpuSplats, made in a GPU context
        self.posing = gpu_draw.Posing()

    def submit(self, request, view, projection) -> None:
        from ...core.for_blender.render import render

        projection = np.array(projection)

        def work():
            return viewport_image(render(request), view, projection)

        self.pending_key = request.key()
        self.future = background_thread("viewport").submit(work)

    def collect(self) -> bool:
        """Take a finished render; True if a new image arrived."""
        from ...core.errors import MogafaceError

        if self.future is None or not self.future.done():
            return False
        future, self.future = self.future, None
        try:
            self.image, self.error = future.result(), None
        except (MogafaceError, OSError, ValueError) as error:
            self.error = str(error)
            print(f"MoGaFace viewport: {error}")
        return True


_views: dict = {}
def update_view(state: ViewState, head, region, region_3d, scene, now: float | None = None,
                submit: bool = True) -> str:
    """Collect a finished image and, if the view, frame or head changed, ask for a new one
    (unless ``submit`` is False). Returns the key of the image the view wants now."""
    now = time.monotonic() if now is None else now
    state.collect()
    view_matrix, projection = np.array(region_3d.view_matrix), np.array(region_3d.window_matrix)
    moving = track_view(state, view_matrix, projection, region, now)
    settings = scene.mogaface
    size = draw_size(region.width, region.height, settings.viewport_navigate_resolution) if moving else \
        draw_size(region.width, region.height, percent=settings.viewport_resolution)
    request, view = viewport_request(head, view_matrix, projection, size, scene.frame_current)
    key = request.key()
    shown = state.image.key if state.image is not None else None
    if submit and state.future is None and key not in (shown, state.pending_key):
        state.submit(request, view, projection)
    return key


def track_view(state: ViewState, view_matrix, projection, region, now: float) -> bool:
    """Note when the view last changed; True while it moves (changed within :data:`SETTLE_S`)."""
    view_key = (view_matrix.round(6).tobytes(), projection.round(6).tobytes(), region.width, region.height)
    if view_key != state.view_key:
        state.view_key, state.view_changed = view_key, now
    return now - state.view_changed < SETTLE_S


def draw_gpu(state: ViewState, head, region, region_3d, scene) -> bool:
    """The GPU draw of the head's Gaussians at the region's size; False while it cannot draw
    (no GPU draw here, or the first frame still being posed)."""
    if gpu_draw.program() is None:
        return False
    view_matrix, projection = np.array(region_3d.view_matrix), np.array(region_3d.window_matrix)
    request, view = viewport_request(head, view_matrix, projection, (region.width, region.height),
                                     scene.frame_current)
    splats = state.posing.latest(request.avatar_path, request.params, scene.frame_current)
    if state.posing.error is not None and state.error != state.posing.error:
        state.error = state.posing.error  # reported once; the last posed frame (or the CPU image) stays
        print(f"MoGaFace viewport: {head.name}: posing for the GPU draw: {state.posing.error}")
    if splats is None:
        return False
    if state.gpu is None:
        state.gpu = gpu_draw.GpuSplats()
    return state.gpu.draw(splats, view, projection, region.width, region.height, state.posing.frame)


def gpu_allowed(mode: str) -> bool:
    """Whether a head's draw may use the GPU: not in "CPU" mode, not where the GPU draw cannot run,
    and not in "BOTH" on a software OpenGL, where the CPU image off the interface thread keeps the
    interface responsive ("GPU" still forces it)."""
    if mode == "CPU" or gpu_draw.unavailable() is not None:
        return False
    return mode == "GPU" or not gpu_draw.software_renderer()


def gpu_first(mode: str, gpu_ok: bool, moving: bool, playing: bool) -> bool:
    """Whether the GPU draw is the one shown now and no CPU render is asked: always in "GPU"
    mode, while the view moves or plays in "BOTH"; never in "CPU" or where the GPU cannot."""
    return gpu_ok and mode != "CPU" and (mode == "GPU" or moving or playing)


def draw_head(state: ViewState, head, region, region_3d, scene, playing: bool) -> None:
    """Draw one head by its switch (:func:`gpu_first`); in "BOTH" the resting view shows the GPU
    draw until the CPU image of that view arrives, then that image."""
    mode = getattr(head, DRAW_PROPERTY, "BOTH")
    gpu_ok = gpu_allowed(mode)
    moving = track_view(state, np.array(region_3d.view_matrix), np.array(region_3d.window_matrix), region,
                        time.monotonic())
    interactive = gpu_first(mode, gpu_ok, moving, playing)
    key = update_view(state, head, region, region_3d, scene, submit=not interactive)
    exact = state.image is not None and state.image.key == key and not interactive
    if gpu_ok and not exact and draw_gpu(state, head, region, region_3d, scene):
        return
    draw_image(state)


# -- drawing --------------------------------------------------------------------------------------

_shader = {}

_VERTEX = """
void main()
{
  uv = pos * 0.5 + 0.5;
  gl_Position = vec4(pos, 0.0, 1.0);
}
"""

_FRAGMENT = """
void main()
{
  vec4 color = texture(color_tex, uv);
  if (color.a < 1.0 / 255.0) {
    discard;
  }
  gl_FragDepth = texture(depth_tex, uv).r;
  fragColor = color;
}
"""


def _quad():
    """The full-view quad and its shader (built once, in a GPU context)."""
    if not _shader:
        import gpu
        from gpu_extras.batch import batch_for_shader

        info = gpu.types.GPUShaderCreateInfo()
        interface = gpu.types.GPUStageInterfaceInfo("mogaface_avatar_interface")
        interface.smooth("VEC2", "uv")
        info.vertex_in(0, "VEC2", "pos")
        info.vertex_out(interface)
        info.sampler(0, "FLOAT_2D", "color_tex")
        info.sampler(1, "FLOAT_2D", "depth_tex")
        info.fragment_out(0, "VEC4", "fragColor")
        if hasattr(info, "depth_write"):  # Blender 4.4+; 4.2/4.3 write gl_FragDepth without the hint
            info.depth_write("ANY")
        info.vertex_source(_VERTEX)
        info.fragment_source(_FRAGMENT)
        shader = gpu.shader.create_from_info(info)
        quad = ((-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0))
        _shader["shader"] = shader
        _shader["batch"] = batch_for_shader(shader, "TRI_FAN", {"pos": quad})
    return _shader["shader"], _shader["batch"]


def textures(image: ViewportImage):
    """GPU textures of an image's colour and depth."""
    import gpu

    size = (image.width, image.height)
    color = gpu.types.GPUTexture(size, format="RGBA32F", data=gpu.types.Buffer("FLOAT", image.rgba.size, image.rgba))
    depth = gpu.types.GPUTexture(size, format="R32F", data=gpu.types.Buffer("FLOAT", image.depth.size, image.depth))
    return color, depth


def draw_image(state: ViewState) -> None:
    """Draw the state's last image over the view, depth-tested against the scene."""
    import gpu

    image = state.image
    if image is None:
        return
    if state.texture is None or state.texture[0] != image.key:
        state.texture = (image.key, *textures(image))
    _, color, depth = state.texture
    shader, batch = _quad()
    gpu.state.depth_test_set("LESS_EQUAL")
    gpu.state.depth_mask_set(True)
    gpu.state.blend_set("ALPHA_PREMULT")
    shader.bind()
    shader.uniform_sampler("color_tex", color)
    shader.uniform_sampler("depth_tex", depth)
    batch.draw(shader)
    gpu.state.blend_set("NONE")
    gpu.state.depth_mask_set(False)
    gpu.state.depth_test_set("NONE")


def draw_avatars() -> None:
    """``SpaceView3D`` draw handler (``POST_VIEW``): every shown avatar of the scene. Never raises."""
    context = bpy.context
    region, region_3d, scene = context.region, context.region_data, context.scene
    if region is None or region_3d is None or scene is None or not hasattr(scene, "mogaface"):
        return
    try:
        heads = shown_heads(scene)
    except ReferenceError:
        return
    screen = context.screen
    playing = bool(screen is not None and screen.is_animation_playing)
    for head in heads:
        state = _views.setdefault((region.as_pointer(), head.session_uid), ViewState())
        for step in (lambda: draw_head(state, head, region, region_3d, scene, playing), lambda: draw_image(state)):
            try:
                step()
                break
            except Exception as error:  # a draw handler must never raise: report once, keep the last image
                message = f"MoGaFace viewport: {head.name}: {error}"
                if state.error != message:
                    state.error = message
                    print(message)
    _ensure_poll()


def _busy() -> bool:
    now = time.monotonic()
    return any(state.future is not None or state.posing.busy or now - state.view_changed < SETTLE_S + 0.1
               for state in _views.values())


def _poll_renders():
    """Timer: redraw 3D views when a render finished or a view settled; stops when nothing is pending."""
    ready = any((state.future is not None and state.future.done())
                or (state.posing.future is not None and state.posing.future.done()) for state in _views.values())
    now = time.monotonic()
    settled = any(SETTLE_S <= now - state.view_changed < SETTLE_S + 0.1 for state in _views.values())
    if ready or settled:
        for window in bpy.context.window_manager.windows:
            for area in window.screen.areas:
                if area.type == "VIEW_3D":
                    area.tag_redraw()
    return 0.05 if _busy() else None


def _ensure_poll() -> None:
    if _busy() and not bpy.app.timers.is_registered(_poll_renders):
        bpy.app.timers.register(_poll_renders, first_interval=0.05)


# -- the per-object switch and registration -------------------------------------------------------


def display_for_avatar(obj) -> None:
    """While its avatar is shown, the head mesh is drawn as its bounds only (the mesh would cover
    the avatar) and in front: the overlay draws in-front objects against a depth buffer of their
    own, so the box's edges leave the scene's depth alone and the avatar, drawn after the
    overlays, covers them where it is opaque instead of being cut by them. The box stays a
    selectable, movable outline. Otherwise the textured mesh, as imported."""
    shown = bool(getattr(obj, SHOW_PROPERTY, False))
    obj.display_type = "BOUNDS" if shown else "TEXTURED"
    obj.show_in_front = shown


def _show_changed(obj, context) -> None:
    if is_head(obj):
        display_for_avatar(obj)


_handle = {"draw": None}


def register() -> None:
    setattr(bpy.types.Object, SHOW_PROPERTY, BoolProperty(
        name="Show Avatar", default=True, update=_show_changed,
        description="Draw this head's avatar in the 3D viewport (rendered by MoGaFace's splat engine)"))
    setattr(bpy.types.Object, DRAW_PROPERTY, EnumProperty(
        name="Viewport Draw", items=DRAW_MODES, default="BOTH",
        description="How the 3D viewport draws this head's avatar: by the GPU, by the CPU splat engine, or both"))
    if _handle["draw"] is None:
        _handle["draw"] = bpy.types.SpaceView3D.draw_handler_add(draw_avatars, (), "WINDOW", "POST_VIEW")


def unregister() -> None:
    if _handle["draw"] is not None:
        bpy.types.SpaceView3D.draw_handler_remove(_handle["draw"], "WINDOW")
        _handle["draw"] = None
    if bpy.app.timers.is_registered(_poll_renders):
        bpy.app.timers.unregister(_poll_renders)
    _views.clear()
    _shader.clear()
    gpu_draw.clear()
    for name in (SHOW_PROPERTY, DRAW_PROPERTY):
        if hasattr(bpy.types.Object, name):
            delattr(bpy.types.Object, name)
