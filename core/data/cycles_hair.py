"""Hair strands for Cycles: scalp hair, eyebrows and lashes as short curves bound to the head's
triangles, computed without Blender.

Each strand is rooted at a point of one triangle (barycentric) and keeps its shape in that
triangle's frame, so it turns and moves with the skin under it, as a Gaussian bound to a triangle
does. Where strands grow is read from the head itself: scalp hair where the texture has the colour
of the top of the head (a bald head's top is skin-coloured and grows none), eyebrows on the darkest
texels around the brow landmarks, lashes along the upper lids' landmarks.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..io.image import srgb_to_linear
from .mesh_render import vertex_normals

POINTS = 5  # control points per strand
KINDS = ("scalp", "brow", "lash")


@dataclasses.dataclass
class Strands:
    """``face`` (S,), ``bary`` (S,3): where each strand is rooted; ``local`` (S,P,3): its points in
    the root triangle's frame (edge, in-plane normal to it, surface normal); ``radius`` (S,P) metres;
    ``kind`` (S,) index into :data:`KINDS`; ``colour`` the hair's linear RGB colour."""

    face: np.ndarray
    bary: np.ndarray
    local: np.ndarray
    radius: np.ndarray
    kind: np.ndarray
    colour: np.ndarray

    def positions(self, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """(S,P,3) strand points on the mesh posed as ``vertices``."""
        frame = triangle_frames(vertices, faces[self.face])
        root = np.einsum("sk,skc->sc", self.bary, vertices[faces[self.face]])
        return root[:, None, :] + np.einsum("spk,skc->spc", self.local, frame)

    def arrays(self) -> dict[str, np.ndarray]:
        return {f"strand_{f.name}": getattr(self, f.name) for f in dataclasses.fields(self)}

    @classmethod
    def from_arrays(cls, data) -> "Strands":
        return cls(**{f.name: np.asarray(data[f"strand_{f.name}"]) for f in dataclasses.fields(cls)})


def triangle_frames(vertices: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """(T,3,3) orthonormal frames (rows: first edge, in-plane normal to it, face normal)."""
    tri = vertices[corners]
    edge = tri[:, 1] - tri[:, 0]
    normal = np.cross(edge, tri[:, 2] - tri[:, 0])
    edge /= np.maximum(np.linalg.norm(edge, axis=1, keepdims=True), 1e-12)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    return np.stack([edge, np.cross(normal, edge), normal], 1)


def _tangent(direction, normal):
    t = direction - np.sum(direction * normal, -1, keepdims=True) * normal
    return t / np.maximum(np.linalg.norm(t, axis=-1, keepdims=True), 1e-12)


def _curve(root, normal, along, length, lift, bend):
    """(S,P,3) points of strands leaving ``root`` at ``lift`` radians off the surface toward
    ``along``, bending back toward the surface by ``bend``."""
    s = np.linspace(0.0, 1.0, POINTS)[None, :, None]
    rise = np.sin(lift)[:, None, None] * s - bend[:, None, None] * s**2
    run = np.cos(lift)[:, None, None] * s
    return root[:, None] + length[:, None, None] * (run * along[:, None] + rise * normal[:, None])


def grow_strands(arrays, rest: np.ndarray, texel_face: np.ndarray, texel_bary: np.ndarray,
                 marks: np.ndarray, skin_faces: np.ndarray, rng: np.random.Generator,
                 scalp: int = 12000, brow: int = 500, lash: int = 70) -> Strands:
    """Strands for one head at rest (``rest`` vertices, ``marks`` its 68 landmarks); ``texel_face``
    and ``texel_bary`` say which triangle lies under each texel (:func:`.cycles_skin.texel_surface`)."""
    texture = arrays.texture.astype(np.float32) / 255.0
    faces = arrays.faces
    on_skin = (texel_face >= 0)
    on_skin[on_skin] = skin_faces[texel_face[on_skin]]
    rows, cols = np.nonzero(on_skin)
    where = np.einsum("nk,nkc->nc", texel_bary[rows, cols], rest[faces[texel_face[rows, cols]]])
    size = texel_face.shape[0]
    colour = texture[rows * texture.shape[0] // size, cols * texture.shape[1] // size]
    top = where[:, 1] > np.quantile(where[:, 1], 0.97)
    hair_colour = np.median(colour[top], 0)
    forehead = colour[np.linalg.norm(where - marks[27] - [0, 0.04, 0], axis=1) < 0.01]
    picks, kinds = [], []
    if len(forehead) and np.abs(hair_colour - np.median(forehead, 0)).max() > 0.12:
        hairy = (np.abs(colour - hair_colour).max(1) < 0.1) & (where[:, 1] > marks[36:48, 1].max())
        picks.append(rng.choice(np.flatnonzero(hairy), min(scalp, int(hairy.sum())), replace=False))
        kinds.append(np.zeros(len(picks[-1]), int))
    brows = marks[17:27]
    near = (np.abs(where - brows.mean(0)) < [0.08, 0.02, 0.04]).all(1)
    near[near] = np.min(np.linalg.norm(where[near][:, None, :2] - brows[None, :, :2], axis=2), 1) < 0.005
    near &= where[:, 2] > brows[:, 2].min() - 0.01
    if near.any():
        dark = near & (colour.mean(1) <= np.quantile(colour[near].mean(1), 0.35))
        picks.append(rng.choice(np.flatnonzero(dark), min(brow * 2, int(dark.sum())), replace=False))
        kinds.append(np.ones(len(picks[-1]), int))
    lids = np.concatenate([_along(marks[[36, 37, 38, 39]], lash), _along(marks[[42, 43, 44, 45]], lash)])
    around = np.flatnonzero((np.abs(where - marks[36:48].mean(0)) < [0.06, 0.02, 0.03]).all(1))
    picks.append(around[np.argmin(np.linalg.norm(where[around][None] - lids[:, None], axis=2), 1)])
    kinds.append(np.full(len(lids), 2))
    texel = np.concatenate(picks)
    kind = np.concatenate(kinds)
    face = texel_face[rows[texel], cols[texel]]
    bary = texel_bary[rows[texel], cols[texel]].astype(np.float64)
    root = where[texel]
    normal = np.einsum("sk,skc->sc", bary, vertex_normals(rest, faces)[faces[face]])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    count = len(face)
    length = np.choose(kind, [rng.uniform(0.012, 0.03, count), rng.uniform(0.005, 0.008, count),
                              rng.uniform(0.006, 0.009, count)])
    down_back = np.array([0.0, -1.0, -0.6])
    lateral = np.stack([np.sign(root[:, 0]), np.full(count, 0.35), np.zeros(count)], 1)
    forward_up = np.array([0.0, 0.5, 1.0])
    aim = np.where((kind == 0)[:, None], down_back, np.where((kind == 1)[:, None], lateral, forward_up))
    along = _tangent(aim + rng.normal(scale=0.15, size=(count, 3)), normal)
    lift = np.choose(kind, [np.full(count, 0.45), np.full(count, 0.25), np.full(count, 1.1)])
    bend = np.choose(kind, [np.full(count, 0.35), np.full(count, 0.1), np.full(count, 0.5)])
    points = _curve(root, normal, along, length, lift + rng.normal(scale=0.1, size=count), bend)
    frame = triangle_frames(rest, faces[face])
    local = np.einsum("spc,skc->spk", points - root[:, None], frame)
    taper = np.linspace(1.0, 0.35, POINTS)[None]
    radius = np.choose(kind, [np.full(count, 5e-5), np.full(count, 4e-5), np.full(count, 5e-5)])[:, None] * taper
    return Strands(face, bary, local, radius, kind, srgb_to_linear(hair_colour))


def _along(polyline: np.ndarray, count: int) -> np.ndarray:
    """``count`` points spread evenly along a polyline."""
    steps = np.linalg.norm(np.diff(polyline, axis=0), axis=1)
    at = np.linspace(0.0, steps.sum(), count)
    cumulative = np.concatenate([[0.0], np.cumsum(steps)])
    return np.stack([np.interp(at, cumulative, polyline[:, c]) for c in range(3)], 1)
