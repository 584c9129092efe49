"""Reference renderer for textured triangle meshes: the ground truth of synthetic captures.

A z-buffer rasterizer with perspective-correct UVs, bilinear texturing, diffuse + ambient
shading and supersampled anti-aliasing. It is independent of the Gaussian splat engine on
purpose: ground truth must never come from the thing being evaluated.

Conventions:

- colours are sRGB values in [0, 1]; shading multiplies texel values directly (no
  linearisation), like the splat engine that learns to reproduce these images;
- both sides of every triangle are drawn; a triangle seen from its back (clockwise on screen
  for counter-clockwise-outward winding, e.g. the inside of the mouth) is shaded with its
  normal turned towards the camera. ``cull_backfaces=True`` drops such triangles instead;
- triangles are clipped against the plane ``z = near`` in front of the camera, so geometry
  behind the camera never shows (and never produces NaN);
- lighting: see :class:`Lighting`. The default lights are fixed in *world* space (FLAME axes:
  y up, z toward the face), so a surface point has the same colour from every view, as in a
  real capture rig.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..camera import Camera
from ..errors import InputError
from . import mesh_raster


def _unit(v) -> tuple[float, float, float]:
    v = np.asarray(v, dtype=np.float64)
    return tuple(v / np.linalg.norm(v))


@dataclasses.dataclass(frozen=True)
class Lighting:
    """A key and a fill directional light plus ambient.

    Directions point *toward* the light. ``space="world"``: directions in world axes (default:
    key from the upper front left of a face looking along +z, fill from the right).
    ``space="camera"``: directions in OpenCV camera axes (x right, y down, z forward), so the
    lights move with the camera.
    """

    key_dir: tuple[float, float, float] = _unit((0.45, 0.55, 1.0))
    key: float = 0.65
    fill_dir: tuple[float, float, float] = _unit((-0.7, 0.1, 0.6))
    fill: float = 0.25
    ambient: float = 0.35
    space: str = "world"

    def world_directions(self, camera: Camera) -> np.ndarray:
        """Unit light directions (2,3) in world axes."""
        dirs = np.array([_unit(self.key_dir), _unit(self.fill_dir)], dtype=np.float64)
        if self.space == "camera":
            return dirs @ camera.R  # camera -> world: R^T d, row-wise
        if self.space != "world":
            raise InputError(None, "space", f"lighting space must be 'world' or 'camera', got {self.space!r}")
        return dirs


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (V,3), following the faces' winding."""
    tri = vertices[faces]
    face_n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals = np.zeros_like(vertices)
    for k in range(3):
        for c in range(3):
            normals[:, c] += np.bincount(faces[:, k], weights=face_n[:, c], minlength=len(vertices))
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return normals / np.where(length > 0, length, 1.0)


def _as_texture(texture) -> np.ndarray:
    tex = np.asarray(texture)
    if tex.ndim != 3 or tex.shape[2] not in (3, 4) or tex.shape[0] == 0 or tex.shape[1] == 0:
        raise InputError(None, "texture", f"expected (H,W,3) image, got shape {tex.shape}")
    if tex.dtype == np.uint8:
        tex = tex[..., :3].astype(np.float32) / 255.0
    else:
        tex = tex[..., :3]
    return np.ascontiguousarray(tex, dtype=np.float32)


def _check_indices(index: np.ndarray, count: int, field: str) -> np.ndarray:
    index = np.asarray(index)
    if index.ndim != 2 or index.shape[1] != 3 or not np.issubdtype(index.dtype, np.integer):
        raise InputError(None, field, f"expected (F,3) integer array, got {index.dtype} {index.shape}")
    if index.size and (index.min() < 0 or index.max() >= count):
        raise InputError(None, field, f"indices must lie in [0, {count})")
    return index.astype(np.int64)


def render_mesh(
    vertices,
    faces,
    vt,
    ft,
    texture,
    camera: Camera,
    background=(1.0, 1.0, 1.0),
    *,
    supersample: int = 3,
    lighting: Lighting | None = None,
    near: float = 1e-3,
    cull_backfaces: bool = False,
    flat_shading: bool = False,
    normals: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Render a textured mesh seen by ``camera``.

    Args:
        vertices: (V,3) world positions. faces: (F,3) vertex indices.
        vt: (VT,2) texture coordinates, OBJ convention (v up). ft: (F,3) indices into ``vt``.
        texture: (Ht,Wt,3) uint8 or float in [0,1]; pass float32 to skip a per-call conversion.
        camera: the one :class:`~mogaface.core.camera.Camera`.
        background: sRGB colour the foreground is composited over.
        supersample: samples per pixel along each axis; ``s*s`` samples are box-filtered.
        lighting: :class:`Lighting`; ``None`` uses the default world-space lights.
        near: clipping distance in front of the camera (world units).
        cull_backfaces: drop triangles seen from behind instead of shading their facing side.
        flat_shading: shade with face normals instead of interpolated vertex normals.
        normals: (V,3) world vertex normals, e.g. :func:`vertex_normals` computed once for
            many views of the same pose; computed here when None.

    Returns:
        ``rgb`` (H,W,3) float32 in [0,1], composited over ``background``, and ``alpha`` (H,W)
        float32, the fraction of each pixel's samples covered by the mesh.
    """
    s = int(supersample)
    if s < 1:
        raise InputError(None, "supersample", f"must be >= 1, got {supersample}")
    vertices = np.asarray(vertices, dtype=np.float64)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise InputError(None, "vertices", f"expected (V,3), got {vertices.shape}")
    if not np.isfinite(vertices).all():
        raise InputError(None, "vertices", "contains NaN or inf")
    vt = np.asarray(vt, dtype=np.float64)
    if vt.ndim != 2 or vt.shape[1] != 2:
        raise InputError(None, "vt", f"expected (VT,2), got {vt.shape}")
    faces = _check_indices(faces, len(vertices), "faces")
    ft = _check_indices(ft, len(vt), "ft")
    if ft.shape != faces.shape:
        raise InputError(None, "ft", f"expected the shape of faces {faces.shape}, got {ft.shape}")
    tex = _as_texture(texture)
    bg = np.asarray(background, dtype=np.float64).reshape(3)
    lights = lighting or Lighting()

    sup = camera.scaled(s)
    height, width = sup.height, sup.width
    if len(faces) == 0:
        rgb = np.broadcast_to(bg.astype(np.float32), (camera.height, camera.width, 3)).copy()
        return rgb, np.zeros((camera.height, camera.width), np.float32)

    if flat_shading:
        tri_w = vertices[faces]
        fn = np.cross(tri_w[:, 1] - tri_w[:, 0], tri_w[:, 2] - tri_w[:, 0])
        fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
        nrm = np.repeat(fn[:, None, :], 3, axis=1)
    elif normals is not None:
        normals = np.asarray(normals, dtype=np.float64)
        if normals.shape != vertices.shape:
            raise InputError(None, "normals", f"expected shape {vertices.shape}, got {normals.shape}")
        nrm = normals[faces]
    else:
        nrm = vertex_normals(vertices, faces)[faces]
    cam_pts = camera.world_to_camera(vertices)[faces]
    tri_p, tri_uv, tri_n, _ = mesh_raster.clip_near(
        np.ascontiguousarray(cam_pts), np.ascontiguousarray(vt[ft]), np.ascontiguousarray(nrm), float(near)
    )
    xy, iz, bbox, flip = mesh_raster.setup_triangles(
        tri_p, sup.fx, sup.fy, sup.cx, sup.cy, width, height, bool(cull_backfaces)
    )
    n_bands = (height + mesh_raster.BAND - 1) // mesh_raster.BAND
    start, tris = mesh_raster.bin_to_bands(bbox, n_bands)
    tri_id, bary = mesh_raster.rasterize(xy, iz, bbox, start, tris, width, height)
    light_dirs = np.ascontiguousarray(lights.world_directions(camera))
    gains = np.array([lights.key, lights.fill], dtype=np.float64)
    rgb, cover = mesh_raster.shade(
        tri_id, bary, tri_uv, tri_n, flip, tex, light_dirs, gains, float(lights.ambient), bg
    )
    return mesh_raster.box_downsample(rgb, cover, s)
