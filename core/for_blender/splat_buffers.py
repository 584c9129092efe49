"""The avatar's Gaussians for the viewport's GPU draw: posed, coloured for a view, sorted, packed.

The GPU draw (``operators/handlers/gpu_draw.py``) splats each Gaussian as an instanced quad;
everything it needs up to the float texture it uploads is plain numpy here, testable without
Blender:

- :func:`posed_splats`: the avatar posed for one frame (FLAME, binding, the MoGaFace modules'
  offsets) as world means, 3D covariances, opacities and colour coefficients, cached per pose so
  that playback poses each frame once;
- :class:`SplatOrder`: the per-view part (colours of the view from the SH coefficients, the
  back-to-front order by view depth, the packed texture), redone whenever the view, the frame or
  the pose changes, and only then. Keying on the frame as well as the view matters: a deforming
  head needs a new order every frame even when the view stands still, and a view turned in place
  (same eye, new direction) needs one too.

Units are the avatar's own, and the camera is the core's :class:`~..camera.Camera` of the view
(:func:`..render.view_camera`), the one the CPU render of the same view uses.
"""

from __future__ import annotations

import dataclasses
import hashlib

import numpy as np

from ..data.byte_cache import ByteLRU
from ..splat.projection import NEAR
from ..splat.tiles import ALPHA_MIN

#: Texels per texture row; each Gaussian takes :data:`TEXELS_PER_SPLAT` consecutive texels.
TEXTURE_WIDTH = 4096
#: [mean xyz, opacity], [Σxx Σxy Σxz Σyy], [Σyz Σzz 0 0], [sRGB r g b, 0]
TEXELS_PER_SPLAT = 4
#: Posed frames kept (bytes of their arrays), least recently used dropped first.
POSE_CACHE_BYTES = 512 << 20


@dataclasses.dataclass(frozen=True)
class PosedSplats:
    """One frame's Gaussians: ``means (N,3)``, ``covariances (N,6)`` (xx, xy, xz, yy, yz, zz),
    ``opacities (N,)``, ``colors`` ``(N,3)`` RGB or ``(N,(d+1)²,3)`` SH, all float32 in avatar
    units; ``key`` names the pose (avatar and parameters)."""

    means: np.ndarray
    covariances: np.ndarray
    opacities: np.ndarray
    colors: np.ndarray
    key: str

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in (self.means, self.covariances, self.opacities, self.colors))


def covariances(quats, scales) -> np.ndarray:
    """``R S Sᵀ Rᵀ`` of wxyz ``quats (N,4)`` (normalised here) and linear ``scales (N,3)`` as
    ``(N,6)`` float32 (xx, xy, xz, yy, yz, zz), computed in float64 as the CPU projection does."""
    q = np.asarray(quats, np.float64)
    q = q / np.maximum(np.linalg.norm(q, axis=1, keepdims=True), 1e-12)
    w, x, y, z = q.T
    rot = np.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], axis=1).reshape(-1, 3, 3)
    m = rot * np.asarray(scales, np.float64)[:, None, :]
    cov = m @ m.transpose(0, 2, 1)
    return cov[:, [0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]].astype(np.float32)


def values_key(avatar_path, values: dict) -> str:
    """A digest of a head's pose request (avatar file and values), cheap to make on every
    redraw: equal keys, equal posed Gaussians (while the avatar file stays the same)."""
    digest = hashlib.blake2b(digest_size=16)
    digest.update(str(avatar_path).encode())
    for name in sorted(values):
        digest.update(name.encode())
        digest.update(np.ascontiguousarray(values[name], np.float64).tobytes())
    return digest.hexdigest()


def pose_key(avatar, params: dict) -> str:
    """The key of a pose: the loaded avatar (a new load, a new key) and its fitted parameters."""
    return values_key(f"loaded avatar {id(avatar)}", params)


_pose_cache = ByteLRU(POSE_CACHE_BYTES)


def posed_splats(avatar_path, values: dict) -> PosedSplats:
    """The avatar of ``avatar_path`` posed by a head's ``values`` (as a render request holds
    them), through the avatar's own posing (the one its render uses); cached per pose."""
    import torch

    from ..avatar.avatar import flame_params_to_torch
    from .render import fitted_params, load_avatar

    avatar = load_avatar(avatar_path)
    params = fitted_params(values, avatar)
    key = pose_key(avatar, params)
    cached = _pose_cache.get(key)
    if cached is not None:
        return cached
    with torch.no_grad():
        world = avatar.world_gaussians(flame_params_to_torch(params))
    splats = PosedSplats(
        means=world["means"].numpy().astype(np.float32),
        covariances=covariances(world["quats"].numpy(), world["scales"].numpy()),
        opacities=world["opacities"].numpy().astype(np.float32).reshape(-1),
        colors=world["colors"].numpy().astype(np.float32),
        key=key,
    )
    _pose_cache.put(key, splats, splats.nbytes)
    return splats


def view_colors(splats: PosedSplats, w2c) -> np.ndarray:
    """Colours ``(N,3)`` in [0, 1] (the core's sRGB) seen from the camera ``w2c``: the SH
    coefficients evaluated per view by the engine's own function."""
    import torch

    from ..splat.sh import sh_to_rgb

    colors = splats.colors
    if colors.ndim == 3:
        w2c = np.asarray(w2c, np.float64)
        campos = torch.from_numpy(-w2c[:3, :3].T @ w2c[:3, 3]).float()
        colors = sh_to_rgb(torch.from_numpy(colors), torch.from_numpy(splats.means), campos).numpy()
    return np.clip(colors, 0.0, 1.0).astype(np.float32)


def back_to_front(splats: PosedSplats, w2c) -> np.ndarray:
    """Indices of the Gaussians in front of the camera that can show (opacity ≥ 1/255), farthest
    first by view depth: the order premultiplied "over" blending needs."""
    w2c = np.asarray(w2c, np.float64)
    depth = splats.means.astype(np.float64) @ w2c[2, :3] + w2c[2, 3]
    shown = np.flatnonzero((depth > NEAR) & (splats.opacities >= ALPHA_MIN))
    return shown[np.argsort(-depth[shown], kind="stable")]


@dataclasses.dataclass(frozen=True)
class PackedSplats:
    """The texture the draw uploads: ``texels (rows, TEXTURE_WIDTH, 4)`` float32, row 0 first,
    holding ``count`` Gaussians back to front."""

    texels: np.ndarray
    count: int

    @property
    def size(self) -> tuple[int, int]:
        return self.texels.shape[1], self.texels.shape[0]


def pack(splats: PosedSplats, order: np.ndarray, colors: np.ndarray) -> PackedSplats:
    """The Gaussians ``order`` selects, in that order, as texels (see :data:`TEXELS_PER_SPLAT`)."""
    per_row = TEXTURE_WIDTH // TEXELS_PER_SPLAT
    rows = max(1, -(-len(order) // per_row))
    texels = np.zeros((rows * per_row, TEXELS_PER_SPLAT, 4), np.float32)
    n = len(order)
    texels[:n, 0, :3] = splats.means[order]
    texels[:n, 0, 3] = splats.opacities[order]
    texels[:n, 1] = splats.covariances[order, :4]
    texels[:n, 2, :2] = splats.covariances[order, 4:]
    texels[:n, 3, :3] = colors[order]
    return PackedSplats(texels.reshape(rows, TEXTURE_WIDTH, 4), n)


def shader_values(view, projection, width: int, height: int) -> dict:
    """The GPU draw's shader values for the core's camera of a view (``view``: a ViewCamera) drawn into a
    ``width`` x ``height`` target whose depth buffer follows ``projection``."""
    cam = view.camera
    fx, fy, cx, cy = cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]
    sx, sy = cam.width / width, cam.height / height  # the camera's pixels per target pixel
    fx, fy, cx, cy = fx / sx, fy / sy, cx / sx, cy / sy
    proj = np.asarray(projection, np.float64)
    return {
        "viewmat": np.asarray(cam.w2c, np.float64),
        "intrinsics": (fx, fy, cx, cy),
        # the engine's clamp of x/z, y/z: 1.3x the view (projection.py ``_limits``)
        "limits": ((width - cx) / fx + 0.3 * width / fx, cx / fx + 0.3 * width / fx,
                   (height - cy) / fy + 0.3 * height / fy, cy / fy + 0.3 * height / fy),
        "depth_rows": (proj[2, 2], proj[2, 3], proj[3, 2], proj[3, 3]),
        "depth_map": (float(width), float(height), view.scale, view.depth_offset),
    }


class SplatOrder:
    """The packed Gaussians of one view, rebuilt when the view, the frame or the pose changes."""

    def __init__(self):
        self.key = None
        self.packed: PackedSplats | None = None
        self.sorts = 0

    def update(self, splats: PosedSplats, w2c, frame: int) -> bool:
        """Bring :attr:`packed` up to date; True when it was rebuilt (re-sorted)."""
        w2c = np.asarray(w2c, np.float64)
        key = (w2c.tobytes(), int(frame), splats.key)
        if key == self.key:
            return False
        self.packed = pack(splats, back_to_front(splats, w2c), view_colors(splats, w2c))
        self.key = key
        self.sorts += 1
        return True
