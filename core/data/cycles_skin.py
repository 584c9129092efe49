"""What Cycles needs to know about a head's surface, computed without Blender: which material each
triangle gets, the expression-driven wrinkle maps and the skin's roughness map.

Wrinkles work as a production face rig's wrinkle maps do: four height maps in texture space
(forehead lines, crow's feet, nasolabial folds, frown lines between the brows), each blended in by
how far the expressions that make it are active, per side of the face. The maps are drawn on the
rest head around its landmarks (the iBUG 68 points of ``model_landmarks``),
so they fit any head in the FLAME layout; which expressions drive them is read from the model's
component names, so a model without names (the real FLAME's PCA components) gets no wrinkles.
"""

from __future__ import annotations

import numpy as np

from ..flame.expression_roles import LEFT_EYE, RIGHT_EYE, has_component_names
from ..flame.procedural_rig import smoothstep
from ..flame.procedural_uv import LID_LINING_UV_BOX, MOUTH_UV_BOX
from ..flame.teeth import TEETH_VERTEX_COUNT
from . import mesh_raster

SKIN, EYE, MOUTH, LINING = 0, 1, 2, 3
MATERIALS = ("skin", "eye", "mouth", "lining")
WRINKLES = ("forehead", "crows_feet", "nasolabial", "frown")
# Which expressions make each wrinkle (substrings of the model's component names).
WRINKLE_EXPRESSIONS = {
    "forehead": ("brow_raise",),
    "crows_feet": ("smile", "squint"),
    "nasolabial": ("smile", "upper_lip_raise", "nose_wrinkle"),
    "frown": ("brow_frown", "nose_wrinkle"),
}
FULL_ACTIVATION = 1.2  # an expression coefficient at which its wrinkles are fully in


def face_materials(arrays) -> np.ndarray:
    """(F,) material index of every triangle: the eyeballs (all corners bound to an eye joint),
    the inside of the mouth and the lids' lining (the procedural head's texture boxes, or the teeth
    a FLAME head with teeth carries), the skin elsewhere."""
    faces = arrays.faces
    material = np.full(len(faces), SKIN, np.int64)
    if arrays.vt is not None and has_component_names(arrays.expression_names):
        centre = arrays.vt[arrays.ft].mean(1)
        for index, (u0, v0, w, h) in ((MOUTH, MOUTH_UV_BOX), (LINING, LID_LINING_UV_BOX)):
            inside = (centre[:, 0] >= u0) & (centre[:, 0] < u0 + w) & (centre[:, 1] >= v0) & (centre[:, 1] < v0 + h)
            material[inside] = index
    elif len(arrays.v_template) >= TEETH_VERTEX_COUNT and _has_teeth(arrays):
        material[(faces >= len(arrays.v_template) - TEETH_VERTEX_COUNT).all(1)] = MOUTH
    eyeball = arrays.weights[:, LEFT_EYE] + arrays.weights[:, RIGHT_EYE] > 0.5
    material[eyeball[faces].all(1)] = EYE
    return material


def _has_teeth(arrays) -> bool:
    from ..flame.landmarks import FLAME_VERTEX_COUNT

    return len(arrays.v_template) == FLAME_VERTEX_COUNT + TEETH_VERTEX_COUNT


def texel_surface(arrays, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Which triangle lies under each texel of a ``size``² texture, and where: ``(face (H,W), -1
    for none; barycentric (H,W,3))``. Rows run top to bottom (v = 1 first), as the texture's.

    The mesh renderer's rasteriser draws the UV layout: corners at depth 1 seen by a camera with
    unit focal length project to their own texel coordinates."""
    corners = np.ones(arrays.ft.shape + (3,))
    corners[..., :2] = arrays.vt[arrays.ft] * size
    corners[..., 1] = size - corners[..., 1]
    xy, iz, bbox, _ = mesh_raster.setup_triangles(corners, 1.0, 1.0, 0.0, 0.0, size, size, False)
    start, tris = mesh_raster.bin_to_bands(bbox, (size + mesh_raster.BAND - 1) // mesh_raster.BAND)
    face_of, b12 = mesh_raster.rasterize(xy, iz, bbox, start, tris, size, size)
    bary = np.concatenate([1.0 - b12.sum(-1, keepdims=True), b12], -1)
    return face_of.astype(np.int64), np.where(face_of[..., None] >= 0, bary, 0.0).astype(np.float32)


def _groove(distance, width):
    return np.exp(-((distance / width) ** 2))


def _segment_distance(p, a, b):
    ab = b - a
    t = np.clip(((p - a) @ ab) / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[..., None] * ab), axis=-1), t


def wrinkle_heights(p: np.ndarray, marks: np.ndarray) -> np.ndarray:
    """(…,4) groove depths in [0,1] at rest positions ``p`` (…,3), one per :data:`WRINKLES`, drawn
    around the rest head's 68 landmarks ``marks`` (FLAME axes: x across, y up, z forward)."""
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    front = z > marks[27:36, 2].min() - 0.03
    brows = marks[17:27]
    order = np.argsort(brows[:, 0])
    brow_y = np.interp(x, brows[order, 0], brows[order, 1])
    half_width = 0.5 * (brows[:, 0].max() - brows[:, 0].min())
    forehead = sum(_groove(y - brow_y - lift - 0.0015 * np.sin(x / 0.02 * np.pi + k), 0.0007)
                   for k, lift in enumerate((0.010, 0.017, 0.024, 0.031)))
    forehead = forehead * np.exp(-((x / half_width) ** 4)) * front

    crows = np.zeros_like(x)
    for corner in (marks[36], marks[45]):
        d = p - corner
        lateral = d[..., 0] * np.sign(corner[0])
        r = np.linalg.norm(d[..., :2], axis=-1)
        angle = np.arctan2(d[..., 1], np.maximum(lateral, 1e-9))
        lines = sum(_groove(r * np.abs(np.sin(angle - a)), 0.0005) for a in (-0.45, -0.1, 0.25, 0.55))
        reach = smoothstep(r, 0.004, 0.008) * (1 - smoothstep(r, 0.016, 0.022))
        crows += lines * reach * (lateral > 0.002) * (z > corner[2] - 0.025)

    fold = np.zeros_like(x)
    for wing, mouth in ((marks[31], marks[48]), (marks[35], marks[54])):
        out = np.sign(wing[0])
        start = wing + np.array([0.004 * out, 0.002, -0.002])
        end = mouth + np.array([0.007 * out, -0.010, -0.004])
        distance, t = _segment_distance(p[..., :2], start[:2], end[:2])  # across the face, not into it
        fold += 1.5 * _groove(distance, 0.0012) * smoothstep(t, 0.0, 0.15) * front

    inner = 0.5 * (marks[21] + marks[22])
    frown = sum(_groove(x - inner[0] - dx, 0.0005) for dx in (-0.007, -0.003, 0.003, 0.007))
    frown = frown * smoothstep(y, inner[1] - 0.008, inner[1] - 0.004) * (1 - smoothstep(y, inner[1] + 0.010, inner[1] + 0.016))
    frown = frown * front * (np.abs(x - inner[0]) < 0.012)
    return np.clip(np.stack([forehead, crows, fold, frown], -1), 0.0, 1.0)


def roughness(p: np.ndarray, marks: np.ndarray) -> np.ndarray:
    """(…) skin roughness at rest positions: an oily T-zone (forehead centre, nose) and wet lips
    are shinier than the cheeks; a slow variation over the whole face."""
    x, y = p[..., 0], p[..., 1]
    t_zone = np.exp(-((x / 0.018) ** 2)) * smoothstep(y, marks[33, 1] - 0.005, marks[33, 1] + 0.005)
    lips = np.zeros_like(x)
    near = (np.abs(p - marks[48:60].mean(0)) < [0.05, 0.03, 0.03]).all(-1)
    lips[near] = np.exp(-((np.linalg.norm(p[near][:, None, :] - marks[48:60], axis=-1).min(-1) / 0.004) ** 2))
    slow = 0.04 * np.sin(x / 0.013) * np.cos(y / 0.017)
    return np.clip(0.55 - 0.17 * t_zone - 0.25 * lips + slow, 0.2, 0.8)


def surface_maps(arrays, rest: np.ndarray, marks: np.ndarray, size: int = 1024) -> dict[str, np.ndarray]:
    """The maps of one head (``rest`` vertices, ``marks`` its 68 landmarks): ``wrinkles``
    (size,size,4) and ``roughness`` (size,size), rows top to bottom, zero wrinkles and roughness 0.5
    where no skin lies; and which triangle lies under each texel (:func:`texel_surface`)."""
    face_of, bary = texel_surface(arrays, size)
    skin = face_of >= 0
    skin[skin] = face_materials(arrays)[face_of[skin]] == SKIN
    p = np.einsum("nk,nkc->nc", bary[skin], rest[arrays.faces[face_of[skin]]])
    wrinkles = np.zeros((size, size, 4), np.float32)
    rough = np.full((size, size), 0.5, np.float32)
    wrinkles[skin] = wrinkle_heights(p, marks)
    rough[skin] = roughness(p, marks)
    return {"wrinkles": wrinkles, "roughness": rough, "texel_face": face_of, "texel_bary": bary}


class WrinkleDriver:
    """Per-vertex weights of the four wrinkle maps for a set of expression coefficients."""

    def __init__(self, arrays, rest: np.ndarray):
        names = [n.lower() for n in arrays.expression_names]
        self.enabled = has_component_names(arrays.expression_names)
        self.x = rest[:, 0]
        # A sided component's side is where it moves the face (its displacement-weighted mean x).
        moved = np.linalg.norm(arrays.exprdirs, axis=1)  # (V, n_expr)
        side = np.sign((moved * self.x[:, None]).sum(0))
        self.terms = {w: [(k, side[k] if ("left" in n or "right" in n) else 0.0)
                          for k, n in enumerate(names) if any(e in n for e in WRINKLE_EXPRESSIONS[w])]
                      for w in WRINKLES}

    def weights(self, expr: np.ndarray) -> np.ndarray:
        """(V,4) weights in [0,1] for expression coefficients ``expr`` (n_expr,)."""
        out = np.zeros((len(self.x), len(WRINKLES)), np.float32)
        if not self.enabled:
            return out
        active = np.clip(np.asarray(expr, np.float64).reshape(-1) / FULL_ACTIVATION, 0.0, 1.0)
        for column, wrinkle in enumerate(WRINKLES):
            for k, side in self.terms[wrinkle]:
                reach = 1.0 if side == 0 else smoothstep(side * self.x, -0.004, 0.004)
                out[:, column] += active[k] * reach
        return np.clip(out, 0.0, 1.0)
