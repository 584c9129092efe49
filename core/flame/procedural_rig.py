"""Skinning weights, joint regressor and pose correctives of the procedural head.

Joint order is FLAME's: 0 root (top of the neck), 1 neck (the head turns about it),
2 jaw (hinge in front of the ears), 3 left eye (+x), 4 right eye (−x).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import nnls

from .procedural_mesh import HeadMesh
from .procedural_sdf import EYE_RADIUS

KINTREE_TABLE = np.array([[4294967295, 0, 1, 1, 1], [0, 1, 2, 3, 4]], dtype=np.int64)
ROOT_TARGET = np.array([0.0, -0.075, -0.018])
NECK_TARGET = np.array([0.0, -0.055, -0.020])
JAW_TARGET = np.array([0.0, -0.014, 0.004])


def smoothstep(x, lo, hi):
    t = np.clip((x - lo) / (hi - lo), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def lower_lip_side(mesh: HeadMesh) -> np.ndarray:
    """1 for skin below the lip seam (and the bag's lower half), 0 above; 0.5 at the corners."""
    side = (mesh.skin_row > mesh.mouth_row).astype(float)
    c0, c1 = mesh.mouth_columns
    on_seam = (mesh.skin_row == mesh.mouth_row) & (mesh.skin_col >= c0) & (mesh.skin_col <= c1)
    side[on_seam] = mesh.is_lower_copy[on_seam]
    side[mesh.upper_lip_rim[[0, -1]]] = 0.5
    bag = mesh.part == 1
    side[bag] = mesh.mouth_bag_lower[bag]
    return side


def jaw_weight(mesh: HeadMesh, vertices: np.ndarray) -> np.ndarray:
    """How much each vertex follows the jaw: chin, lower lip and lower cheeks, fading at the cheeks."""
    x, y, z = vertices.T
    ax = np.abs(x)
    # The boundary runs from the mouth corners back and up towards the ear lobes.
    boundary = -0.060 + 0.040 * smoothstep(ax, 0.022, 0.068)
    below = smoothstep(boundary - y, -0.004, 0.014)
    in_front_of_ear = smoothstep(z, -0.028, 0.0)
    # The throat stays with the neck: fade out under the chin, behind its front.
    throat = smoothstep(-0.112 - y, 0.0, 0.025) * (1.0 - smoothstep(z, 0.02, 0.055))
    weight = below * in_front_of_ear * (1.0 - throat)
    # Near the mouth the seam decides: the lower lip goes with the jaw, the upper lip stays.
    mouth = np.clip(1.1 * np.exp(-((x / 0.032) ** 4) - ((y + 0.062) / 0.02) ** 4), 0.0, 1.0) * smoothstep(z, 0.04, 0.07)
    side = lower_lip_side(mesh)
    weight = weight + (1.0 - weight) * mouth * side
    weight = weight * (1.0 - mouth * (1.0 - side))
    bag = mesh.part == 1
    weight[bag] = mesh.mouth_bag_lower[bag]
    weight[mesh.part >= 2] = 0.0
    return np.clip(weight, 0.0, 1.0)


def skinning_weights(mesh: HeadMesh, vertices: np.ndarray) -> np.ndarray:
    """(V,5) weights: root fades into the neck joint up the neck; jaw region; eyeballs rigid."""
    weights = np.zeros((len(vertices), 5))
    root = 1.0 - smoothstep(vertices[:, 1], -0.175, -0.115)
    jaw = jaw_weight(mesh, vertices) * (1.0 - root)
    weights[:, 0] = root
    weights[:, 2] = jaw
    weights[:, 1] = 1.0 - root - jaw
    for k, part in enumerate((2, 3)):
        eye = mesh.part == part
        weights[eye] = 0.0
        weights[eye, 3 + k] = 1.0
    return weights


def _fit_weights(points: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Non-negative weights summing to one whose weighted mean of ``points`` is ``target``.

    Pulled towards uniform so every chosen vertex contributes and the joint follows
    the whole region when the shape changes.
    """
    n = len(points)
    uniform = np.full(n, 1.0 / n)
    a = np.vstack([points.T * 100.0, np.full((1, n), 100.0), 1.0 * np.eye(n)])
    b = np.concatenate([target * 100.0, [100.0], 1.0 * uniform])
    w, _ = nnls(a, b, maxiter=5000)
    return w / w.sum()


def _nearest(vertices, candidates, point, count):
    d = np.linalg.norm(vertices[candidates] - point, axis=1)
    return candidates[np.argsort(d)[:count]]


def joint_regressor(mesh: HeadMesh, vertices: np.ndarray) -> np.ndarray:
    """(5,V) sparse regressor; each joint is a convex combination of vertices around it."""
    skin = np.flatnonzero(mesh.part == 0)
    regressor = np.zeros((5, len(vertices)))

    def symmetric_patches(points, count):
        chosen = []
        for p in points:
            for sign in (1.0, -1.0):
                chosen.append(_nearest(vertices, skin, p * np.array([sign, 1.0, 1.0]), count))
        return np.unique(np.concatenate(chosen))

    # Root and neck: rings around the upper neck and the nape.
    neck_ring = skin[np.abs(vertices[skin, 1] + 0.125) < 0.006]
    root_set = np.unique(np.concatenate([neck_ring, symmetric_patches([np.array([0.04, -0.05, -0.07])], 6)]))
    neck_set = np.unique(np.concatenate([neck_ring, symmetric_patches(
        [np.array([0.05, -0.03, -0.06]), np.array([0.06, -0.04, 0.0])], 6)]))
    jaw_set = symmetric_patches([np.array([0.07, -0.014, 0.004]), np.array([0.06, -0.045, 0.01])], 8)
    for row, (ids, target) in enumerate(((root_set, ROOT_TARGET), (neck_set, NECK_TARGET), (jaw_set, JAW_TARGET))):
        regressor[row, ids] = _fit_weights(vertices[ids], target)
    for k, part in enumerate((2, 3)):
        # The eyeball's rings are denser in front, so fit rather than average; its
        # last vertex is the back pole, one radius behind the centre.
        ids = np.flatnonzero(mesh.part == part)
        centre = vertices[ids[-1]] + np.array([0.0, 0.0, EYE_RADIUS])
        regressor[3 + k, ids] = _fit_weights(vertices[ids], centre)
    return regressor


def pose_correctives(mesh: HeadMesh, vertices: np.ndarray) -> np.ndarray:
    """(V,3,36) small correctives: neck bulge when the head turns or bends, jaw-open stretch."""
    x, y, z = vertices.T
    posedirs = np.zeros((len(vertices), 3, 36))
    # Neck (block 0): entries 0, 4, 8 are cos θ − 1 (negative for any bend): a mild bulge.
    neck = smoothstep(-y, 0.09, 0.12) * (1.0 - smoothstep(-y, 0.17, 0.2))
    radial = np.stack([x, np.zeros_like(x), z + 0.015], axis=1)
    radial /= np.linalg.norm(radial, axis=1, keepdims=True) + 1e-9
    for entry in (0, 4, 8):
        posedirs[:, :, entry] = -0.012 * (neck[:, None] * radial)
    # Jaw (block 1): entry 9+7 is sin θ of the opening rotation about x.
    jaw = jaw_weight(mesh, vertices)
    cheek = np.exp(-((np.abs(x) - 0.045) / 0.015) ** 2 - ((y + 0.045) / 0.02) ** 2) * smoothstep(z, 0.02, 0.05)
    under_chin = smoothstep(-y, 0.095, 0.115) * smoothstep(z, 0.0, 0.04) * jaw
    open_dir = np.zeros((len(vertices), 3))
    open_dir[:, 0] = -np.sign(x) * 0.006 * cheek
    open_dir[:, 2] = 0.004 * under_chin - 0.002 * cheek
    open_dir[:, 1] = 0.003 * under_chin
    posedirs[:, :, 9 + 7] = open_dir
    posedirs[mesh.part >= 2] = 0.0
    return posedirs
