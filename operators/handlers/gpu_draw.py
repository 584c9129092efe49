"""The avatar drawn by the GPU: every Gaussian an instanced quad, through Blender's ``gpu`` module.

The Gaussians of the shown frame, posed, coloured for the view and sorted back to front by
:mod:`core.for_blender.splat_buffers`, are one float texture (4 texels each). A unit quad is drawn once
per Gaussian (``GPUBatch.draw_instanced``); its vertex shader projects the 3D covariance as the
CPU engine does (EWA Jacobian with the same 1.3x clamp, the same 0.3 px² low-pass), places the
quad at 3σ of the larger axis, and its fragment shader evaluates the Gaussian, cuts alpha at
1/255 (and at 0.99 from above) as the engine does, decodes the sRGB colour and writes it
premultiplied. Blending "over" back to front gives what the engine composites front to back.
The splats are depth-tested against the scene at their centres' depth but write no depth.

The camera is the core's camera of the view (:func:`core.for_blender.render.view_camera`), so the
GPU and the CPU image of a view are the same picture. Needs a GPU context; the posing runs on a
worker thread so a frame not yet posed never blocks a redraw.
"""

from __future__ import annotations

from ..common import background_thread
from ..dependencies import LazyModule

np = LazyModule("numpy")

_VERTEX = """
void main()
{
  int base = gl_InstanceID * 4;
  ivec2 at = ivec2(base % TEXTURE_WIDTH, base / TEXTURE_WIDTH);
  vec4 t0 = texelFetch(splats, at, 0);
  vec4 t1 = texelFetch(splats, at + ivec2(1, 0), 0);
  vec4 t2 = texelFetch(splats, at + ivec2(2, 0), 0);
  vec4 t3 = texelFetch(splats, at + ivec2(3, 0), 0);
  gl_Position = vec4(0.0, 0.0, 2.0, 1.0);  /* outside the clip volume: culled */
  offset = vec2(0.0);
  conic_opacity = vec4(0.0);
  color = vec3(0.0);
  vec3 p = (viewmat * vec4(t0.xyz, 1.0)).xyz;
  if (p.z <= NEAR) {
    return;
  }
  float u = clamp(p.x / p.z, -limits.y, limits.x);
  float v = clamp(p.y / p.z, -limits.w, limits.z);
  mat3 W = mat3(viewmat);
  vec3 a = vec3(intrinsics.x / p.z, 0.0, -intrinsics.x * u / p.z) * W;
  vec3 b = vec3(0.0, intrinsics.y / p.z, -intrinsics.y * v / p.z) * W;
  mat3 S = mat3(t1.x, t1.y, t1.z, t1.y, t1.w, t2.x, t1.z, t2.x, t2.y);
  float sxx = dot(a, S * a) + BLUR;
  float sxy = dot(b, S * a);
  float syy = dot(b, S * b) + BLUR;
  float det = sxx * syy - sxy * sxy;
  if (!(det > 0.0)) {
    return;
  }
  float mid = 0.5 * (sxx + syy);
  float radius = ceil(3.0 * sqrt(mid + sqrt(max(mid * mid - det, 0.0))));
  vec2 centre = vec2(intrinsics.x * p.x / p.z + intrinsics.z, intrinsics.y * p.y / p.z + intrinsics.w);
  offset = corner * radius;
  vec2 pixel = centre + offset;  /* image pixels, y down */
  float z = p.z * depth_map.z - depth_map.w;
  float ndc_z = (-depth_rows.x * z + depth_rows.y) / (-depth_rows.z * z + depth_rows.w);
  gl_Position = vec4(2.0 * pixel.x / depth_map.x - 1.0, 1.0 - 2.0 * pixel.y / depth_map.y, ndc_z, 1.0);
  conic_opacity = vec4(syy / det, -sxy / det, sxx / det, t0.w);
  color = t3.rgb;
}
"""

_FRAGMENT = """
void main()
{
  float q = (conic_opacity.x * offset.x + 2.0 * conic_opacity.y * offset.y) * offset.x
            + conic_opacity.z * offset.y * offset.y;
  if (q > 9.0) {
    discard;
  }
  float alpha = min(0.99, conic_opacity.w * exp(-0.5 * q));
  if (alpha < 1.0 / 255.0) {
    discard;
  }
  vec3 low = color / 12.92;
  vec3 high = pow((color + 0.055) / 1.055, vec3(2.4));
  vec3 linear = mix(high, low, vec3(lessThanEqual(color, vec3(0.04045))));
  fragColor = vec4(linear * alpha, alpha);
}
"""

_program: dict = {}


def _build():
    import gpu
    from gpu_extras.batch import batch_for_shader

    from ...core.for_blender.splat_buffers import TEXTURE_WIDTH
    from ...core.splat.projection import BLUR, NEAR

    if not hasattr(gpu.types.GPUBatch, "draw_instanced"):
        raise RuntimeError("this Blender's gpu module has no instanced drawing")
    info = gpu.types.GPUShaderCreateInfo()
    interface = gpu.types.GPUStageInterfaceInfo("mogaface_splat_interface")
    interface.smooth("VEC2", "offset")
    interface.flat("VEC4", "conic_opacity")
    interface.flat("VEC3", "color")
    info.vertex_in(0, "VEC2", "corner")
    info.vertex_out(interface)
    info.sampler(0, "FLOAT_2D", "splats")
    info.push_constant("MAT4", "viewmat")
    info.push_constant("VEC4", "intrinsics")
    info.push_constant("VEC4", "limits")
    info.push_constant("VEC4", "depth_rows")
    info.push_constant("VEC4", "depth_map")
    info.fragment_out(0, "VEC4", "fragColor")
    constants = f"#define TEXTURE_WIDTH {TEXTURE_WIDTH}\n#define NEAR {NEAR!r}\n#define BLUR {BLUR!r}\n"
    info.vertex_source(constants + _VERTEX)
    info.fragment_source(_FRAGMENT)
    shader = gpu.shader.create_from_info(info)
    corners = ((-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, -1.0), (1.0, 1.0), (-1.0, 1.0))
    return shader, batch_for_shader(shader, "TRIS", {"corner": corners})


def program():
    """The splat shader and its quad, built once in a GPU context; None where this Blender cannot
    (then :func:`unavailable` says why)."""
    if "shader" not in _program:
        try:
            _program["shader"], _program["error"] = _build(), None
        except Exception as error:  # a failed compile or a missing feature: the CPU image stays
            _program["shader"], _program["error"] = None, f"{type(error).__name__}: {error}"
            print(f"MoGaFace viewport: the GPU draw cannot run here ({_program['error']})")
    return _program["shader"]


def software_renderer() -> bool:
    """Whether OpenGL is drawn by the CPU (Mesa's llvmpipe: a virtual screen, or a machine without a
    GPU driver). There the GPU draw rasterises every Gaussian on the interface thread, which holds
    the interface a frame change or an orbit step at a time (docs/blender.md, "In the 3D viewport"),
    while the CPU image is rendered on a worker thread; asked once, in a GPU context."""
    if "software" not in _program:
        try:
            import gpu

            renderer = gpu.platform.renderer_get().lower()
            _program["software"] = gpu.platform.device_type_get() == "SOFTWARE" or any(
                name in renderer for name in ("llvmpipe", "softpipe", "swrast"))
        except Exception:  # noqa: BLE001 - background mode, or a Blender without gpu.platform
            _program["software"] = False
    return _program["software"]


def unavailable() -> str | None:
    """Why the GPU draw cannot run, once it was tried; None when it runs or was not tried yet."""
    return _program.get("error")


class GpuSplats:
    """One (view, head) pair's GPU state: its sorted Gaussians and their texture."""

    def __init__(self):
        from ...core.for_blender.splat_buffers import SplatOrder

        self.order = SplatOrder()
        self.texture = None  # (order key, GPUTexture)

    def draw(self, splats, view, projection, width: int, height: int, frame: int) -> bool:
        """Draw ``splats`` (PosedSplats) as ``view`` sees them; False where the GPU cannot."""
        import gpu
        import mathutils

        from ...core.for_blender.splat_buffers import shader_values

        shader = program()
        if shader is None:
            return False
        shader, batch = shader
        self.order.update(splats, view.camera.w2c, frame)
        packed = self.order.packed
        if packed.count == 0:
            return True
        if self.texture is None or self.texture[0] != self.order.key:
            flat = packed.texels.reshape(-1)
            data = gpu.types.Buffer("FLOAT", flat.size, flat)
            self.texture = (self.order.key, gpu.types.GPUTexture(packed.size, format="RGBA32F", data=data))
        values = shader_values(view, projection, width, height)
        gpu.state.depth_test_set("LESS_EQUAL")
        gpu.state.depth_mask_set(False)
        gpu.state.blend_set("ALPHA_PREMULT")
        shader.bind()
        shader.uniform_sampler("splats", self.texture[1])
        shader.uniform_float("viewmat", mathutils.Matrix(values.pop("viewmat").tolist()))
        for name, value in values.items():
            shader.uniform_float(name, tuple(float(x) for x in value))
        batch.draw_instanced(shader, instance_start=0, instance_count=packed.count)
        gpu.state.blend_set("NONE")
        gpu.state.depth_test_set("NONE")
        return True


class Posing:
    """Poses frames on a worker thread: :meth:`latest` gives the newest posed Gaussians asked
    for, or the previous ones while the new frame is being posed (a redraw never waits)."""

    def __init__(self):
        self.splats = None
        self.frame = 0
        self.future = None
        self.wanted = None
        self.error: str | None = None

    def latest(self, avatar_path: str, values: dict, frame: int):
        from ...core.for_blender.splat_buffers import values_key

        key = values_key(avatar_path, values)
        if self.future is not None and self.future.done():
            future, self.future = self.future, None
            try:
                self.splats, self.frame, self.error = (*future.result(), None)
            except Exception as error:  # reported once by the caller; the CPU image stays
                self.error = str(error)
        if self.future is None and key != self.wanted:
            self.wanted = key
            self.future = background_thread("posing").submit(_pose, avatar_path, values, frame)
        return self.splats

    @property
    def busy(self) -> bool:
        return self.future is not None


def _pose(avatar_path, values, frame):
    from ...core.for_blender.splat_buffers import posed_splats

    return posed_splats(avatar_path, values), frame


def clear() -> None:
    _program.clear()
