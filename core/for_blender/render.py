"""One render request for every place the avatar appears in Blender, and its answer.

The Image Editor (Render Frame / Render Animation), the 3D viewport's draw handler and the
compositor's avatar layer all ask the same question: *this avatar, posed by these FLAME
parameters, seen by this camera* → colour, alpha and depth. :class:`RenderRequest` is that
question (plain numpy, built on Blender's main thread, safe to hand to another thread) and
:func:`render` its one answer, through the avatar's own render call. Only the callers differ.

Also here, without Blender: the OpenCV camera of a 3D viewport (its view and projection
matrices) and the conversion of the avatar's depth to the viewport's depth-buffer values.
"""

from __future__ import annotations

import dataclasses
import hashlib

import numpy as np

from ..camera import Camera
from ..errors import InputError
from .avatar import load_avatar
from .axes import CV_TO_BLENDER_CAMERA, flame_to_blender_matrix
from .head_rig import POSE_PROPERTIES, head_flame_params

#: Alpha below which a pixel holds no avatar: its depth is "nothing there" (infinitely far).
EMPTY_ALPHA = 1.0 / 255.0


@dataclasses.dataclass(frozen=True)
class RenderRequest:
    """Avatar file, FLAME parameters of one frame, the camera, and what the caller needs.

    ``background``: an RGB colour the avatar is composited over (the Image Editor), or None
    for a transparent layer whose colour is premultiplied by alpha (viewport, compositor).
    ``depth_scale``: scene units per avatar unit (the head object's scale), applied to depth.
    """

    avatar_path: str
    params: dict
    camera: Camera
    background: tuple | None = None
    depth_scale: float = 1.0
    frame: int = 0

    def key(self) -> str:
        """A digest of everything that changes the picture: equal keys, equal images."""
        digest = hashlib.blake2b(digest_size=16)
        digest.update(str(self.avatar_path).encode())
        for name in sorted(self.params):
            digest.update(name.encode())
            digest.update(np.ascontiguousarray(self.params[name], np.float64).tobytes())
        cam = self.camera
        for array in (cam.K, cam.w2c):
            digest.update(np.ascontiguousarray(array, np.float64).tobytes())
        digest.update(repr((cam.width, cam.height, self.background, float(self.depth_scale))).encode())
        return digest.hexdigest()


@dataclasses.dataclass
class RenderResult:
    """``rgb (H,W,3)``, ``alpha (H,W)``, ``depth (H,W)`` float32, top row first.

    ``depth`` is the camera-space distance along the view axis (planar, like Blender's Z pass),
    in scene units; ``inf`` where the avatar is absent (alpha < :data:`EMPTY_ALPHA`).
    """

    request: RenderRequest
    rgb: np.ndarray
    alpha: np.ndarray
    depth: np.ndarray

    @property
    def rgba(self) -> np.ndarray:
        return np.concatenate([self.rgb, self.alpha[..., None]], axis=2)


def fitted_params(values: dict, avatar) -> dict:
    """A head's values (``shape``, optional ``static_offset``, ``expr``, pose) fitted to ``avatar``."""
    pose = {name: values[name] for name in POSE_PROPERTIES if name in values}
    return head_flame_params(values.get("shape", ()), values.get("static_offset"), values.get("expr", ()), pose,
                             avatar.flame.n_shape, avatar.flame.n_expr)


def render(request: RenderRequest) -> RenderResult:
    """Answer a request with the avatar's own render (the one training and evaluation use).

    ``request.params`` holds what the head shows (identity, expression values, pose); they are
    fitted to the avatar's counts here, so building a request never loads the avatar.
    """
    from ..avatar.avatar import render_arrays

    avatar = load_avatar(request.avatar_path)
    params = fitted_params(request.params, avatar)
    background = (0.0, 0.0, 0.0) if request.background is None else tuple(request.background)
    rgb, alpha, depth = render_arrays(avatar, params, request.camera, background)
    rgb = np.clip(rgb, 0.0, 1.0) if request.background is not None else np.clip(rgb, 0.0, alpha[..., None])
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = depth / alpha * np.float32(request.depth_scale)
    depth = np.where(alpha >= EMPTY_ALPHA, depth, np.float32(np.inf)).astype(np.float32)
    return RenderResult(request, rgb, alpha, depth)


def render_image_name(camera_name: str, frame: int) -> str:
    """The image datablock a render of ``camera_name`` at ``frame`` goes to."""
    return f"MoGaFace {camera_name} {frame:04d}"

def blender_rgba(result: RenderResult) -> np.ndarray:
    """``(H,W,4)`` float32, top row first: the one conversion of a render's colours for Blender.

    The core renders display-referred sRGB (the capture's own values); Blender holds
    scene-linear RGB premultiplied by alpha, and its view transform comes after ("Standard"
    turns it back into these sRGB values). Every place the avatar reaches Blender uses this:
    the viewport's draw, the Image Editor's images, the compositor's layer and the EXR files.

    A transparent render (no ``background``) holds colour premultiplied by alpha: it is divided
    by alpha, decoded with the sRGB curve per channel and premultiplied again, so semi-transparent
    pixels keep their colour (neither darkened nor whitened). A render over a background is
    opaque: alpha 1.
    """
    from ..io.image import srgb_to_linear

    if result.request.background is None:
        alpha = result.alpha[..., None]
        with np.errstate(divide="ignore", invalid="ignore"):
            straight = np.where(alpha > 0, result.rgb / alpha, 0.0)
    else:
        alpha = np.ones_like(result.alpha)[..., None]
        straight = result.rgb
    linear = srgb_to_linear(np.clip(straight, 0.0, 1.0)) * alpha
    return np.concatenate([linear, alpha], axis=2).astype(np.float32)


def srgb_from_blender(rgba) -> np.ndarray:
    """``(H,W,4)`` scene-linear premultiplied RGBA (as :func:`blender_rgba` gives, or as read back
    from Blender) → the sRGB colour premultiplied by alpha that the core renders, ``(H,W,3)``;
    what the "Standard" view transform shows over black."""
    from ..io.image import linear_to_srgb

    rgba = np.asarray(rgba, np.float32)
    alpha = rgba[..., 3:4]
    with np.errstate(divide="ignore", invalid="ignore"):
        straight = np.where(alpha > 0, rgba[..., :3] / alpha, 0.0)
    return (linear_to_srgb(straight) * alpha).astype(np.float32)


# -- the 3D viewport ------------------------------------------------------------------------------


def is_perspective(projection) -> bool:
    """Whether an OpenGL projection matrix is a perspective one (else orthographic)."""
    return abs(float(np.asarray(projection)[3, 3])) < 0.5


@dataclasses.dataclass
class ViewCamera:
    """A viewport's camera for the splat engine: ``camera`` (avatar units), the head's ``scale``
    (scene units per avatar unit) and ``depth_offset``, what to subtract from a rendered depth
    (scene units) to get the view's own depth (non-zero for an orthographic view's stand-in)."""

    camera: Camera
    scale: float
    depth_offset: float = 0.0


def view_camera(view_matrix, projection, head_matrix, width: int, height: int,
                camera_id: str = "viewport") -> ViewCamera:
    """The OpenCV camera of a 3D viewport relative to a head object.

    ``view_matrix``/``projection``: the region's world→view and OpenGL projection matrices
    (Blender's ``RegionView3D.view_matrix`` and ``window_matrix``); ``head_matrix``: the head
    object's ``matrix_world``. A perspective projection gives the pinhole ``K`` directly;
    an orthographic one is imaged by a pinhole placed far back along the view axis with the
    same pixels per unit at the view's focus, which the splat engine (pinhole only) can draw.
    """
    if width < 1 or height < 1:
        raise InputError(None, "viewport size", f"expected a positive size, got {width}x{height}")
    view = np.asarray(view_matrix, np.float64)
    proj = np.asarray(projection, np.float64)
    head = np.asarray(head_matrix, np.float64)
    scale = float(np.cbrt(abs(np.linalg.det(head[:3, :3])))) or 1.0
    c2w = np.linalg.inv(view)  # Blender camera axes: x right, y up, looking along -z
    distance = 0.0
    if is_perspective(proj):
        fx, fy = proj[0, 0] * width / 2, proj[1, 1] * height / 2
        cx, cy = width / 2 * (1 - proj[0, 2]), height / 2 * (1 + proj[1, 2])
    else:
        distance = ortho_distance(proj)
        c2w = c2w @ _translation(0.0, 0.0, distance)
        fx, fy = proj[0, 0] * width / 2 * distance, proj[1, 1] * height / 2 * distance
        cx, cy = width / 2 * (1 - proj[0, 3]), height / 2 * (1 + proj[1, 3])
    head_rigid = head.copy()
    head_rigid[:3, :3] /= np.linalg.norm(head_rigid[:3, :3], axis=0)
    relative = np.linalg.inv(head_rigid) @ c2w
    relative[:3, 3] /= scale  # avatar units
    c2w_cv = flame_to_blender_matrix(np.eye(4)).T @ relative @ CV_TO_BLENDER_CAMERA
    if not is_perspective(proj):
        fx, fy = fx / scale, fy / scale
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    camera = Camera(K=K, w2c=np.linalg.inv(c2w_cv), width=width, height=height, camera_id=camera_id)
    return ViewCamera(camera, scale, distance)


def ortho_distance(projection) -> float:
    """How far back the stand-in pinhole of an orthographic view sits: 40 view widths."""
    proj = np.asarray(projection, np.float64)
    return 40.0 * 2.0 / abs(proj[0, 0])


def _translation(x: float, y: float, z: float) -> np.ndarray:
    out = np.eye(4)
    out[:3, 3] = (x, y, z)
    return out


def depth_buffer_values(depth, projection) -> np.ndarray:
    """Planar depths (scene units, ``inf`` = empty) → window depths in [0, 1] of ``projection``.

    What OpenGL writes for a point at that distance (``glDepthRange(0, 1)``), so the avatar's
    pixels are hidden behind nearer scene geometry and hide farther geometry; empty pixels get 1.
    For the orthographic stand-in, pass the depths as seen from the view itself.
    """
    proj = np.asarray(projection, np.float64)
    z_view = -np.asarray(depth, np.float64)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        clip_z = proj[2, 2] * z_view + proj[2, 3]
        clip_w = proj[3, 2] * z_view + proj[3, 3]
        ndc = clip_z / clip_w
    window = np.clip(0.5 * ndc + 0.5, 0.0, 1.0)
    return np.where(np.isfinite(depth), window, 1.0).astype(np.float32)


def view_framing(points, lens: float, width: int, height: int, margin: float = 1.15) -> tuple[np.ndarray, float]:
    """Where a perspective 3D view looks and how far back it stands to show all ``points``.

    ``lens``: the view's focal length in mm (``SpaceView3D.lens``; Blender images a view onto a
    72 mm sensor along the region's longer side). Returns ``(centre, distance)`` for
    ``RegionView3D.view_location``/``view_distance``: the points' bounding sphere, seen whole
    through the narrower side of the region, with ``margin``.
    """
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if len(points) == 0:
        raise InputError(None, "points", "nothing to frame")
    if lens <= 0 or width < 1 or height < 1:
        raise InputError(None, "view", f"expected a positive lens and size, got {lens} mm, {width}x{height}")
    centre = (points.min(axis=0) + points.max(axis=0)) / 2
    radius = max(float(np.linalg.norm(points - centre, axis=1).max()), 1e-3) * margin
    half_fov = np.arctan(36.0 / lens * min(width, height) / max(width, height))
    return centre, radius / np.sin(half_fov)
