"""Which point of MediaPipe's face mesh stands for each of the 68 iBUG-300W points.

The rest of the project (the ``landmark2d/`` files of a capture, camera solving, fitting) speaks
iBUG-68 (:mod:`..flame.landmarks`). :data:`IBUG68_FROM_MESH` names, for each iBUG point in order,
one of the 468 mesh points.

How it was made (``scripts/derive_ibug68_mapping.py`` does it again and compares): the project's
procedural head (subjects 0, 1 and 2), whose own iBUG-68 embedding is
:func:`..flame.landmarks.procedural_embedding`, is rendered by the reference mesh renderer
(:mod:`..data.mesh_render`) from 30 views each (azimuth −30° to 30°, elevation −10° to 10°, the
mouth closed and open, 512 px); the face tracker finds the mesh in every view; for each iBUG point
the mesh point chosen is the one nearest the projected embedding point on average over the views,
distances in units of the distance between the outer eye corners, with two rules (:func:`derive`):
no two iBUG points share a mesh point, and mirror-image iBUG points take mirror-image mesh points
(the mesh's mirror found by flipping frontal renders). See ``docs/tracking.md`` for how consistent
the choice was across views.
"""

from __future__ import annotations

import numpy as np

IBUG68_FROM_MESH = (
    227, 137, 147, 213, 214, 210, 170, 32, 199, 262, 395, 430, 434, 433, 376, 366, 447,  # 0-16 jaw
    70, 63, 105, 66, 107, 336, 296, 334, 293, 300,  # 17-26 brows
    168, 197, 195, 4, 240, 99, 94, 328, 460,  # 27-35 nose
    246, 159, 158, 173, 145, 144, 398, 385, 386, 466, 373, 374,  # 36-47 eyes
    61, 40, 72, 11, 302, 270, 291, 406, 313, 18, 83, 182,  # 48-59 outer lips
    76, 81, 13, 311, 306, 403, 14, 179,  # 60-67 inner lips
)


def mirror_indices(pairs, tie_break: float = 0.0) -> np.ndarray:
    """For each point of a point set, the index of its mirror image, from pairs ``(points (N,d),
    mirrored (N,d))``: ``mirrored[j]`` is where point ``j`` lies in the mirrored scene, brought back
    into the original's frame (e.g. the mesh found on a frontal face's left-right flipped image, its
    x flipped back). A one-to-one choice (an assignment) minimising the distance summed over the
    pairs; ``tie_break`` × |index difference| is added, to part points that coincide."""
    from scipy.optimize import linear_sum_assignment

    cost = sum(np.linalg.norm(np.asarray(mirrored, np.float64)[:, None] - np.asarray(points, np.float64)[None], axis=-1)
               for points, mirrored in pairs)
    index = np.arange(len(cost))
    cost = np.asarray(cost) + tie_break * np.abs(index[:, None] - index[None])
    return linear_sum_assignment(cost)[1]


def derive(views, mesh_mirror=None, ibug_mirror=None) -> dict:
    """The mesh point nearest each iBUG point over ``views``: pairs ``(ibug (68,2), mesh (≥468,2))`` of
    one image's projected iBUG points and detected mesh points, distances in units of the distance
    between the outer eye corners (iBUG 36, 45).

    No two iBUG points take the same mesh point: the choice is an assignment (scipy's
    ``linear_sum_assignment``) minimising the summed distance. With ``mesh_mirror`` (468,) and
    ``ibug_mirror`` (68,) (:func:`mirror_indices`) it is also symmetric: an iBUG point ``k`` and its
    mirror ``k'`` take a mesh point ``j`` and its mirror, the ``j`` that minimises the two distances
    together (a point on the midline takes one whose mirror is near it).

    Returns ``mapping`` (68,) mesh indices; ``agreement`` (68,), the fraction of views whose own nearest
    mesh point is the one chosen; ``excess`` (68,), how much farther from the iBUG point the chosen
    mesh point is than each view's own nearest, on average; ``error`` (68,), the mean distance from
    the chosen mesh point to the iBUG point (both in eye-corner distances); ``error_px`` the same in
    pixels."""
    costs, pixels, nearest = [], [], []
    for ibug, mesh in views:
        ibug, mesh = np.asarray(ibug, np.float64)[:, :2], np.asarray(mesh, np.float64)[:468, :2]
        distance = np.linalg.norm(ibug[:, None] - mesh[None], axis=-1)  # (68, 468)
        costs.append(distance / np.linalg.norm(ibug[36] - ibug[45]))
        pixels.append(distance)
        nearest.append(distance.argmin(1))
    cost = np.mean(costs, 0)
    rows, paired = np.arange(len(cost)), cost
    if mesh_mirror is not None and ibug_mirror is not None:
        mesh_mirror, ibug_mirror = np.asarray(mesh_mirror), np.asarray(ibug_mirror)
        if np.any(ibug_mirror[ibug_mirror] != rows):
            raise ValueError("ibug_mirror must be its own inverse")
        rows = np.where(ibug_mirror >= rows)[0]  # a pair's lower-numbered point; a point on the midline
        paired = cost[rows] + cost[ibug_mirror[rows]][:, mesh_mirror]
    from scipy.optimize import linear_sum_assignment

    assigned, picked = linear_sum_assignment(paired)
    mapping = np.zeros(len(cost), np.int64)
    mapping[rows[assigned]] = picked
    if len(rows) < len(cost):
        others = rows[ibug_mirror[rows] != rows]
        mapping[ibug_mirror[others]] = mesh_mirror[mapping[others]]
    every = np.arange(len(mapping))
    excess = np.mean([view[every, mapping] - view.min(1) for view in costs], 0)
    return {"mapping": mapping, "agreement": np.mean(np.array(nearest) == mapping, 0), "excess": excess,
            "error": cost[every, mapping], "error_px": np.mean(pixels, 0)[every, mapping]}
