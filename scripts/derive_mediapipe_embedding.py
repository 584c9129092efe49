"""Derive where each of MediaPipe's face-mesh points (and the two iris centres) sits on the procedural head.

    python scripts/derive_mediapipe_embedding.py            # derive, report, write core/track/mediapipe_embedding.npz
    python scripts/derive_mediapipe_embedding.py --check    # derive again; exit 1 if it differs from the stored file

Renders subjects 0–2 of the procedural head in seven poses (neutral, the jaw open, a smile, the brows
raised, a pucker, speaking, laughing) from 27 views each (azimuth −40° to 40°, elevation −15° to 15°:
the renderer and cameras of ``derive_ibug68_mapping.py``) and finds the face mesh in every render with
the face tracker. For each of the 21 poses and each mesh point:

1. the point's 3D position is triangulated from its rays (least squares), then twice again from the
   views where the surface point found is visible (facing the camera, not hidden: the rasteriser's
   depth) and whose ray passes near the others' solution;
2. it is snapped to the skin: the closest point on a triangle, a face and barycentric weights, which
   hold in the mesh's own topology, shared by every subject and pose.

Each pose's snapped point is a candidate; the one whose posed positions lie nearest, summed over the
21 poses, to where each pose's views put the point is the embedding (a medoid). A point is kept when it
is stable: its RMS distance over the poses is at most ``--tolerance`` mm. The iris centres are the
eyeballs' front poles (moved by ``eyes_pose``), checked against their triangulated positions.

Then the embedding is measured on renders it was not derived from (subjects 3 and 4, other views, other
poses, the eyes turned): each kept point posed with the render's true parameters and projected, against
the detector's point. Needs the face models (scripts/ensure_venv.sh); about two minutes on two cores.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import warnings

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).parent))
from derive_ibug68_mapping import render_poses  # noqa: E402

SUBJECTS = (0, 1, 2)
AZIMUTHS = (-40.0, -30.0, -20.0, -10.0, 0.0, 10.0, 20.0, 30.0, 40.0)
ELEVATIONS = (-15.0, 0.0, 15.0)
HELD_OUT_SUBJECTS = (3, 4)
HELD_OUT_AZIMUTHS = (-35.0, -25.0, -5.0, 5.0, 25.0, 35.0)
HELD_OUT_ELEVATIONS = (-20.0, 8.0)
SIZE = 512
MESH_COUNT = 468
IRIS_CENTRES = (468, 473)  # MediaPipe's: the eye on the image's left (the subject's right, −x), then the other
MIN_PRESENCE = 0.9  # views whose face presence is lower are not used
FACING = 0.2  # a view sees a surface point when the cosine between its normal and the view ray exceeds this
HIDDEN_MM = 1.5  # ... and nothing lies more than this in front of it
RAY_PX = 2.5  # a view's ray is dropped when it misses the others' solution by more than this (and 2.5 × the median)
MIN_VIEWS = 3
TOLERANCE_MM = 5.0  # a point is kept when its RMS disagreement over the poses is at most this
# MediaPipe's face oval (its FACEMESH_FACE_OVAL) and its lips' inner contour, to say which points were left out
FACE_OVAL = (10, 338, 297, 332, 284, 251, 389, 356, 454, 323, 361, 288, 397, 365, 379, 378, 400, 377, 152, 148, 176,
             149, 150, 136, 172, 58, 132, 93, 234, 127, 162, 21, 54, 103, 67, 109)
INNER_LIPS = (78, 95, 88, 178, 87, 14, 317, 402, 318, 324, 308, 191, 80, 81, 82, 13, 312, 311, 310, 415)
STORED = pathlib.Path(__file__).resolve().parents[1] / "core" / "track" / "mediapipe_embedding.npz"


def expression(**weights) -> np.ndarray:
    from mogaface.core.flame.procedural import EXPRESSION_NAMES

    expr = np.zeros(len(EXPRESSION_NAMES))
    for name, weight in weights.items():
        expr[EXPRESSION_NAMES.index(name)] = weight
    return expr


def poses() -> dict:
    return {"neutral": {}, "jaw open": {"jaw_pose": [0.25, 0.0, 0.0]},
            "smile": {"expr": expression(smile_left=1.2, smile_right=1.2)},
            "brows up": {"expr": expression(brow_raise_left=1.2, brow_raise_right=1.2, eye_wide=0.8)},
            "pucker": {"expr": expression(lip_pucker=1.2)},
            "speaking": {"jaw_pose": [0.18, 0.0, 0.0], "expr": expression(lip_funnel=1.0, lower_lip_depress=0.6)},
            "laughing": {"jaw_pose": [0.2, 0.0, 0.0], "expr": expression(smile_left=1.0, smile_right=1.0)}}


def held_out_poses() -> dict:
    return {"neutral": {}, "talking": {"jaw_pose": [0.15, 0.0, 0.0], "expr": expression(lip_funnel=0.8, upper_lip_raise=0.5)},
            "open smile": {"jaw_pose": [0.1, 0.0, 0.0], "expr": expression(smile_left=0.9, smile_right=0.6, squint=0.5)},
            "looking aside": {"eyes_pose": [0.1, 0.3, 0.0, 0.1, 0.3, 0.0], "expr": expression(brow_frown=0.8)}}


# -- geometry -----------------------------------------------------------------------------------

def closest_points(points: np.ndarray, triangles: np.ndarray, candidates: int = 48):
    """The closest point on a set of triangles ``(F,3,3)`` to each of ``points (N,3)``: ``(triangle (N,),
    barycentric (N,3), closest (N,3))``. Exact among the ``candidates`` triangles whose centroids are
    nearest (the mesh's triangles are a few mm across; the closest one is always among them)."""
    centroids = triangles.mean(1)
    near = np.argsort(np.linalg.norm(points[:, None] - centroids[None], axis=-1), axis=1, kind="stable")[:, :candidates]
    a, b, c = (triangles[near, k] for k in range(3))  # (N,C,3)
    bary = _closest_on_triangle(points[:, None], a, b, c)
    closest = bary[..., :1] * a + bary[..., 1:2] * b + bary[..., 2:] * c
    best = np.argmin(np.linalg.norm(closest - points[:, None], axis=-1), axis=1)
    rows = np.arange(len(points))
    return near[rows, best], bary[rows, best], closest[rows, best]


def _closest_on_triangle(p, a, b, c) -> np.ndarray:
    """Barycentric weights of the point of triangle ``abc`` closest to ``p`` (Ericson, Real-Time
    Collision Detection, 5.1.5), vectorised; the regions' tests in his order, the first that holds wins."""
    def dot(u, v):
        return np.einsum("...k,...k->...", u, v)

    ab, ac, ap, bp, cp = b - a, c - a, p - a, p - b, p - c
    d1, d2, d3, d4, d5, d6 = dot(ab, ap), dot(ac, ap), dot(ab, bp), dot(ac, bp), dot(ab, cp), dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        total = va + vb + vc
        v, w = np.where(total != 0, vb / total, 1 / 3), np.where(total != 0, vc / total, 1 / 3)
        t_ab = np.where(d1 - d3 != 0, d1 / (d1 - d3), 0.0)
        t_ac = np.where(d2 - d6 != 0, d2 / (d2 - d6), 0.0)
        t_bc = np.where((d4 - d3) + (d5 - d6) != 0, (d4 - d3) / ((d4 - d3) + (d5 - d6)), 0.0)
    one, zero = np.ones_like(d1), np.zeros_like(d1)
    regions = [  # (test, weights), Ericson's order
        ((d1 <= 0) & (d2 <= 0), (one, zero, zero)),
        ((d3 >= 0) & (d4 <= d3), (zero, one, zero)),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), (1 - t_ab, t_ab, zero)),
        ((d6 >= 0) & (d5 <= d6), (zero, zero, one)),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), (1 - t_ac, zero, t_ac)),
        ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), (zero, 1 - t_bc, t_bc)),
    ]
    weights = np.stack([1 - v - w, v, w], -1)
    for test, region in reversed(regions):
        weights = np.where(test[..., None], np.stack(region, -1), weights)
    return weights


def depth_map(vertices: np.ndarray, faces: np.ndarray, camera) -> np.ndarray:
    """(H,W) camera depth of the nearest surface at each pixel centre (inf where none): the reference
    renderer's own rasteriser, for visibility."""
    from mogaface.core.data import mesh_raster

    cam = np.ascontiguousarray(camera.world_to_camera(vertices)[faces])
    tri, _, _, _ = mesh_raster.clip_near(cam, np.zeros((len(faces), 3, 2)), np.zeros((len(faces), 3, 3)), 1e-3)
    xy, iz, bbox, _ = mesh_raster.setup_triangles(tri, camera.fx, camera.fy, camera.cx, camera.cy, camera.width,
                                                  camera.height, False)
    start, tris = mesh_raster.bin_to_bands(bbox, (camera.height + mesh_raster.BAND - 1) // mesh_raster.BAND)
    index, bary = mesh_raster.rasterize(xy, iz, bbox, start, tris, camera.width, camera.height)
    weights = np.concatenate([1 - bary.sum(-1, keepdims=True), bary], -1).astype(np.float64)
    depth = (weights * tri[np.maximum(index, 0), :, 2]).sum(-1)
    return np.where(index >= 0, depth, np.inf)


def visible(surface: np.ndarray, normals: np.ndarray, camera, depth: np.ndarray) -> np.ndarray:
    """(N,) whether ``camera`` sees each surface point: facing it, and not hidden (the nearest surface
    in the 3 × 3 pixels around it is at most :data:`HIDDEN_MM` in front)."""
    ray = camera.center - surface
    facing = np.einsum("nk,nk->n", normals, ray / np.linalg.norm(ray, axis=1, keepdims=True)) > FACING
    uv, z = camera.project(surface)
    column = np.clip(np.floor(uv[:, 0]).astype(int), 1, camera.width - 2)
    row = np.clip(np.floor(uv[:, 1]).astype(int), 1, camera.height - 2)
    around = np.max([depth[row + i, column + j] for i in (-1, 0, 1) for j in (-1, 0, 1)], axis=0)
    return facing & (z <= around + HIDDEN_MM / 1000)


def triangulate(origins: np.ndarray, directions: np.ndarray, use: np.ndarray) -> np.ndarray:
    """The points nearest their rays, least squares: ``origins (V,3)``, unit ``directions (V,N,3)``,
    ``use (V,N)`` which rays count → ``(N,3)`` (NaN with fewer than two)."""
    projector = np.eye(3) - directions[..., :, None] * directions[..., None, :]  # (V,N,3,3)
    projector = projector * use[..., None, None]
    lhs = projector.sum(0)
    rhs = np.einsum("vnij,vj->ni", projector, origins)
    solved = np.full((directions.shape[1], 3), np.nan)
    ok = use.sum(0) >= 2
    solved[ok] = np.linalg.solve(lhs[ok], rhs[ok][..., None])[..., 0]
    return solved


def rays(camera, pixels: np.ndarray) -> np.ndarray:
    """Unit world directions ``(N,3)`` of the rays through ``pixels (N,2)``."""
    local = np.stack([(pixels[:, 0] - camera.cx) / camera.fx, (pixels[:, 1] - camera.cy) / camera.fy,
                      np.ones(len(pixels))], 1)
    world = local @ camera.R  # camera → world: Rᵀ d, row-wise
    return world / np.linalg.norm(world, axis=1, keepdims=True)


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    corners = vertices[faces]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    return normal / np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)


# -- derivation ---------------------------------------------------------------------------------

def detect(views, tracker):
    """Each view with the tracker's 478 points and face presence (0 where no face was found)."""
    for view in views:
        face = tracker(view.image).face
        landmarks = face.landmarks[:, :2].astype(np.float64) if face is not None else np.full((478, 2), np.nan)
        yield view, landmarks, face.presence if face is not None else 0.0


def pose_groups(detected):
    """The detected views grouped by (subject, pose), in their order."""
    groups: dict = {}
    for view, landmarks, presence in detected:
        groups.setdefault((view.subject, view.pose), []).append((view, landmarks, presence))
    return groups


def locate(group, points: np.ndarray, skin: np.ndarray):
    """Where one pose's views put MediaPipe points ``points`` on its mesh: per point the snapped
    ``surface (N,3)``, ``face (N,)``, ``barycentric (N,3)``, the views used ``(N,)``, the RMS
    reprojection residual over them in px, and the triangulated point's distance to the surface in mm."""
    vertices, faces = group[0][0].vertices, group[0][0].faces
    views = [(view, landmarks) for view, landmarks, presence in group if presence >= MIN_PRESENCE]
    origins = np.stack([view.camera.center for view, _ in views])
    directions = np.stack([rays(view.camera, landmarks[points]) for view, landmarks in views])  # (V,N,3)
    depths = [depth_map(vertices, faces, view.camera) for view, _ in views]
    normals = face_normals(vertices, faces)
    use = np.ones(directions.shape[:2], bool)
    solved = np.zeros((len(points), 3))
    for _ in range(3):
        again = triangulate(origins, directions, use)
        solved = np.where(np.isnan(again), solved, again)  # a point seen in fewer than two views keeps the last
        face, bary, surface = closest_points(solved, vertices[faces[skin]])
        face = skin[face]
        seen = np.stack([visible(surface, normals[face], view.camera, depth) for (view, _), depth in zip(views, depths)])
        residual = np.stack([np.linalg.norm(view.camera.project(solved)[0] - landmarks[points], axis=1)
                             for view, landmarks in views])  # (V,N) px
        middle = _nanmedian(np.where(seen, residual, np.nan), axis=0)
        use = seen & (residual <= np.maximum(RAY_PX, 2.5 * np.nan_to_num(middle)))
    count = use.sum(0)
    rms = np.sqrt((np.where(use, residual, 0) ** 2).sum(0) / np.maximum(count, 1))
    return {"surface": surface, "face": face, "barycentric": bary, "views": count, "residual_px": rms,
            "off_surface_mm": 1000 * np.linalg.norm(solved - surface, axis=1)}


def _nanmedian(values: np.ndarray, axis: int) -> np.ndarray:
    """The median of the values that are not NaN (NaN, silently, where there are none)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmedian(values, axis=axis)


def at(vertices, faces, face, bary) -> np.ndarray:
    return (vertices[faces[face]] * bary[..., None]).sum(-2)


def derive(groups, tolerance_mm: float = TOLERANCE_MM) -> dict:
    """The embedding of the 468 mesh points from every pose group, and how stable each is.

    Each pose's own snapped point (a triangle and weights: one topology) is a candidate; posed in every
    pose, a candidate lies some distance from where that pose's views put the point. The candidate
    with the least distance summed over the poses is the embedding (a medoid: robust to a pose or two
    that disagree, and never between two far candidates, e.g. an inner-lip point on the upper or the
    lower lip of a closed mouth)."""
    from mogaface.core.flame.procedural_mesh import build_mesh

    mesh = build_mesh()
    faces = mesh.faces
    skin = np.flatnonzero(np.all(mesh.part[faces] == 0, axis=1))
    points = np.arange(MESH_COUNT)
    located = [locate(group, points, skin) for group in groups.values()]
    meshes = [group[0][0].vertices for group in groups.values()]
    enough = np.stack([found["views"] >= MIN_VIEWS for found in located])  # (G,N)
    distance = np.stack([np.stack([1000 * np.linalg.norm(at(vertices, faces, candidate["face"], candidate["barycentric"])
                                                         - found["surface"], axis=1)
                                   for vertices, found in zip(meshes, located)])
                         for candidate in located])  # (candidate, pose, N) mm
    distance = np.where(enough[None], distance, np.nan)
    total = np.where(enough, np.nansum(distance, axis=1), np.inf)
    best = np.argmin(total, axis=0)
    face = np.stack([found["face"] for found in located])[best, points]
    bary = np.stack([found["barycentric"] for found in located])[best, points]
    disagreement = distance[best, :, points]  # (N,G)
    spread = np.sqrt(np.nanmean(disagreement ** 2, axis=1))
    kept = (enough.sum(0) > len(located) // 2) & (spread <= tolerance_mm)
    return {"face": face, "barycentric": bary, "kept": kept, "spread_mm": spread,
            "max_mm": np.nanmax(disagreement, axis=1), "groups_seen": enough.sum(0),
            "residual_px": _nanmedian(np.where(enough, np.stack([f["residual_px"] for f in located]), np.nan), 0),
            "off_surface_mm": _nanmedian(np.where(enough, np.stack([f["off_surface_mm"] for f in located]), np.nan), 0),
            "views": np.median(np.stack([found["views"] for found in located]), axis=0)}


def iris_centres(groups) -> dict:
    """The eyeballs' front poles as embedding points (MediaPipe's 468: the −x eyeball, 473: the +x one),
    and how far each pose's triangulated iris centres lie from them (mm)."""
    from mogaface.core.flame.procedural_mesh import build_mesh

    mesh = build_mesh()
    faces, bary, pole_vertices = [], [], []
    for part in (3, 2):  # the subject's right eye (−x) first, as MediaPipe's 468
        eyeball = np.flatnonzero(mesh.part == part)
        pole = int(eyeball[np.argmax(mesh.vertices[eyeball, 2])])  # the front pole: the first vertex
        face, corner = np.argwhere(mesh.faces == pole)[0]
        weights = np.zeros(3)
        weights[corner] = 1.0
        faces.append(int(face))
        bary.append(weights)
        pole_vertices.append(pole)
    eyeballs = np.flatnonzero(np.all(np.isin(mesh.part[mesh.faces], (2, 3)), axis=1))
    distances = []
    for group in groups.values():
        found = locate(group, np.array(IRIS_CENTRES), eyeballs)
        vertices = group[0][0].vertices
        distances.append(1000 * np.linalg.norm(found["surface"] - vertices[pole_vertices], axis=1))
    return {"face": np.array(faces), "barycentric": np.array(bary), "distance_mm": np.array(distances)}


# -- accuracy -----------------------------------------------------------------------------------

def accuracy(detected, embedding) -> dict:
    """Each embedded point posed with a render's true parameters and projected, against the detector's
    point: errors in px (at the render's size) and in mm at the point's depth; the iBUG-51 route beside."""
    from mogaface.core.flame.landmarks import STATIC_IBUG, procedural_embedding
    from mogaface.core.track.mediapipe_ibug68 import IBUG68_FROM_MESH

    ibug = procedural_embedding().subset(STATIC_IBUG)
    ibug_columns = np.asarray(IBUG68_FROM_MESH)[ibug.ibug]
    rows = {"mesh": [], "mesh_mm": [], "iris": [], "iris_mm": [], "ibug": [], "azimuth": []}
    mesh = embedding.ibug < MESH_COUNT
    for view, landmarks, presence in detected:
        if presence < MIN_PRESENCE:
            continue
        uv, z = view.camera.project(embedding.positions(view.vertices, view.faces))
        error = np.linalg.norm(uv - landmarks[embedding.ibug], axis=1)
        millimetres = 1000 * error * z / view.camera.fx
        rows["mesh"].append(error[mesh])
        rows["mesh_mm"].append(millimetres[mesh])
        rows["iris"].append(error[~mesh])
        rows["iris_mm"].append(millimetres[~mesh])
        rows["azimuth"].append(view.azimuth)
        uv, _ = view.camera.project(ibug.positions(view.vertices, view.faces))
        rows["ibug"].append(np.linalg.norm(uv - landmarks[ibug_columns], axis=1))
    return {name: np.array(value) for name, value in rows.items()}


def mirror_error(embedding, tracker) -> np.ndarray:
    """(N,) how far each kept point's mirror image (x → −x on subject 0's symmetric rest head) lies from
    the point kept for its mirror in MediaPipe's mesh (mm; NaN where that one was not kept). The mesh's
    mirror as ``derive_ibug68_mapping.py`` finds it: the frontal face flipped left-right."""
    from mogaface.core.track.mediapipe_ibug68 import mirror_indices

    view = next(render_poses((0,), {"neutral": {}}, (0.0,), (0.0,)))
    found = tracker(view.image).face.landmarks[:MESH_COUNT]
    flipped = tracker(np.ascontiguousarray(view.image[:, ::-1])).face.landmarks[:MESH_COUNT]
    mirror = mirror_indices([(found, flipped * (-1, 1, 1) + (view.image.shape[1], 0, 0))])
    positions = embedding.positions(view.vertices, view.faces)
    index = {int(i): k for k, i in enumerate(embedding.ibug)}
    error = np.full(len(embedding.ibug), np.nan)
    for k, i in enumerate(embedding.ibug):
        if i < MESH_COUNT and int(mirror[i]) in index:
            error[k] = 1000 * np.linalg.norm(positions[k] * (-1, 1, 1) - positions[index[int(mirror[i])]])
    return error


# -- the command --------------------------------------------------------------------------------

def main(argv=None) -> int:
    from mogaface.core.flame.landmarks import LandmarkEmbedding
    from mogaface.core.flame.procedural_mesh import build_mesh
    from mogaface.core.io.npz import save_npz
    from mogaface.core.track.detect import FaceTracker
    from mogaface.core.track.mediapipe_embedding import read_mediapipe_embedding

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if the derived embedding differs from the stored one")
    parser.add_argument("--out", type=pathlib.Path, default=STORED, help=f"where to write it (default {STORED})")
    parser.add_argument("--tolerance", type=float, default=TOLERANCE_MM, help="keep points whose RMS disagreement "
                        f"over the poses is at most this many mm (default {TOLERANCE_MM})")
    args = parser.parse_args(argv)
    tracker = FaceTracker(track=False, mask=False)

    groups = pose_groups(detect(render_poses(SUBJECTS, poses(), AZIMUTHS, ELEVATIONS, SIZE), tracker))
    presence = np.array([p for group in groups.values() for _, _, p in group])
    print(f"{len(presence)} renders ({len(groups)} poses × {len(AZIMUTHS) * len(ELEVATIONS)} views); face presence "
          f"min {presence.min():.3f}, {np.sum(presence < MIN_PRESENCE)} below {MIN_PRESENCE}")
    found = derive(groups, args.tolerance)
    irises = iris_centres(groups)
    kept = np.flatnonzero(found["kept"])
    spread = found["spread_mm"]
    print(f"mesh points kept: {len(kept)} of {MESH_COUNT} (RMS disagreement over the poses ≤ {args.tolerance} mm)")
    print(f"  disagreement (RMS over poses) of all points: median {np.nanmedian(spread):.2f} mm, "
          f"90th percentile {np.nanpercentile(spread, 90):.2f} mm, max {np.nanmax(spread):.2f} mm")
    print(f"  kept: median {np.median(spread[kept]):.2f} mm, max {spread[kept].max():.2f} mm; the worst pose's "
          f"median {np.median(found['max_mm'][kept]):.2f} mm")
    print(f"  views per point and pose (median) {np.median(found['views']):.0f}; triangulation residual "
          f"median {np.nanmedian(found['residual_px']):.2f} px; triangulated point to the skin median "
          f"{np.nanmedian(found['off_surface_mm']):.2f} mm")
    left = np.flatnonzero(~found["kept"])
    print(f"  left out: {len(left)}, of them {np.isin(left, FACE_OVAL).sum()} of the {len(FACE_OVAL)} on the face "
          f"oval and {np.isin(left, INNER_LIPS).sum()} of the {len(INNER_LIPS)} on the lips' inner contour: "
          + ", ".join(f"{i} ({spread[i]:.1f} mm)" for i in left))
    distance = irises["distance_mm"]
    print(f"iris centres: triangulated vs the eyeball's front pole, mm per pose: right eye (468) median "
          f"{np.median(distance[:, 0]):.2f} max {distance[:, 0].max():.2f}; left eye (473) median "
          f"{np.median(distance[:, 1]):.2f} max {distance[:, 1].max():.2f}")

    mesh = build_mesh()
    arrays = {"mediapipe": np.concatenate([kept, IRIS_CENTRES]).astype(np.int32),
              "faces": np.concatenate([found["face"][kept], irises["face"]]).astype(np.int32),
              "barycentric": np.concatenate([found["barycentric"][kept], irises["barycentric"]]).astype(np.float32),
              "n_vertices": np.array(len(mesh.vertices), np.int32), "n_faces": np.array(len(mesh.faces), np.int32)}
    arrays["barycentric"] /= arrays["barycentric"].sum(1, keepdims=True)
    embedding = LandmarkEmbedding(arrays["faces"].astype(np.int64), arrays["barycentric"].astype(np.float64),
                                  arrays["mediapipe"].astype(np.int64))

    mirror = mirror_error(embedding, tracker)
    print(f"symmetry: a kept point's mirror image vs the point kept for its mirror, on subject 0 (symmetric): "
          f"median {np.nanmedian(mirror):.2f} mm, 90th percentile {np.nanpercentile(mirror, 90):.2f} mm")

    held_out = list(detect(render_poses(HELD_OUT_SUBJECTS, held_out_poses(), HELD_OUT_AZIMUTHS, HELD_OUT_ELEVATIONS,
                                        SIZE), tracker))
    score = accuracy(held_out, embedding)
    print(f"held out: subjects {HELD_OUT_SUBJECTS}, {len(held_out_poses())} other poses (eyes turned in one), "
          f"azimuths {HELD_OUT_AZIMUTHS}, elevations {HELD_OUT_ELEVATIONS}: {len(score['azimuth'])} renders at {SIZE} px")
    print("  points                  mean px  median px  90th px  mean mm  median mm")
    for name, px, mm in (("mesh (kept)", score["mesh"], score["mesh_mm"]), ("iris centres", score["iris"], score["iris_mm"])):
        print(f"  {name:22s} {px.mean():8.2f} {np.median(px):9.2f} {np.percentile(px, 90):8.2f} {mm.mean():8.2f} "
              f"{np.median(mm):9.2f}")
    ibug = score["ibug"]
    print(f"  iBUG 17-67 (the procedural iBUG embedding vs the mesh points IBUG68_FROM_MESH names): mean "
          f"{ibug.mean():.2f} px, median {np.median(ibug):.2f} px")
    for azimuth in sorted(set(np.abs(score["azimuth"]).tolist())):
        rows = np.abs(score["azimuth"]) == azimuth
        print(f"  |azimuth| {azimuth:4.0f}°: mesh mean {score['mesh'][rows].mean():.2f} px, iris mean "
              f"{score['iris'][rows].mean():.2f} px")

    if args.check:
        stored = read_mediapipe_embedding(args.out)
        same = (np.array_equal(stored.ibug, embedding.ibug) and np.array_equal(stored.faces, embedding.faces)
                and np.abs(stored.barycentric - embedding.barycentric).max() <= 1e-6)
        print("same as the stored embedding" if same else f"differs from the stored embedding {args.out}")
        return 0 if same else 1
    save_npz(args.out, arrays)
    print(f"wrote {args.out} ({args.out.stat().st_size} bytes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
