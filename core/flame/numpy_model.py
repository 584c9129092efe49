"""FLAME evaluation in numpy, for one head in Blender: importing and posing heads needs no torch.

The same formulation as :class:`~mogaface.core.flame.model.FlameModel` (blend shapes, pose
correctives, linear blend skinning over FLAME's 5 joints), float64, one parameter set at a time.
Training uses the torch model (it needs gradients); tests check the two agree.
"""

from __future__ import annotations

import os

import numpy as np

from ..errors import InputError
from .model_file import ModelArrays, read_model_file
from .teeth import match_tracking

POSE_NAMES = ("rotation", "neck_pose", "jaw_pose", "eyes_pose")


def axis_angle_to_matrix(rotvec: np.ndarray) -> np.ndarray:
    """Rodrigues' formula, ``(J,3)`` axis-angle → ``(J,3,3)``, exact at the rest pose."""
    theta2 = (rotvec * rotvec).sum(-1)[:, None, None]
    small = theta2 < 1e-6
    safe = np.where(small, 1.0, theta2)
    theta = np.sqrt(safe)
    a = np.where(small, 1 - theta2 / 6 + theta2**2 / 120, np.sin(theta) / theta)
    b = np.where(small, 0.5 - theta2 / 24 + theta2**2 / 720, 2 * np.sin(theta / 2) ** 2 / safe)
    x, y, z = rotvec.T
    zero = np.zeros_like(x)
    skew = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=-1).reshape(-1, 3, 3)
    return np.eye(3) + a * skew + b * (skew @ skew)


def _components(values, count: int) -> np.ndarray:
    """``count`` coefficients: missing trailing ones are zero, as in FLAME's own code."""
    values = np.zeros(0) if values is None else np.asarray(values, np.float64).reshape(-1)
    if values.size > count:
        raise InputError(None, "coefficients", f"expected at most {count} values, found {values.size}")
    return np.pad(values, (0, count - values.size))


class NumpyFlame:
    """``model(shape=…, expr=…, rotation=…, …)`` → vertices ``(V,3)`` for one parameter set."""

    def __init__(self, arrays: ModelArrays):
        if arrays.weights.shape[1] != 5:
            raise InputError(None, "kintree_table", f"expected FLAME's 5 joints, found {arrays.weights.shape[1]}")
        self.arrays = arrays
        self.parents = [int(p) for p in arrays.parents]
        self.expression_names = list(arrays.expression_names)

    @classmethod
    def load(cls, path: str | os.PathLike, n_vertices: int | None = None) -> "NumpyFlame":
        """``n_vertices``: the tracking's vertex count; 5143 on a 5023-vertex FLAME adds its teeth."""
        return cls(match_tracking(read_model_file(path), n_vertices, path))

    @property
    def n_shape(self) -> int:
        return self.arrays.shapedirs.shape[2]

    @property
    def n_expr(self) -> int:
        return self.arrays.exprdirs.shape[2]

    @property
    def n_vertices(self) -> int:
        return self.arrays.v_template.shape[0]

    def __call__(self, shape=None, expr=None, static_offset=None, translation=None, **pose) -> np.ndarray:
        a = self.arrays
        shape, expr = _components(shape, self.n_shape), _components(expr, self.n_expr)
        shaped = a.v_template + a.shapedirs @ shape + a.exprdirs @ expr
        if static_offset is not None:
            shaped = shaped + np.asarray(static_offset, np.float64).reshape(shaped.shape)
        joints = a.J_regressor @ shaped
        full_pose = np.concatenate([np.zeros(6 if name == "eyes_pose" else 3) if pose.get(name) is None
                                    else np.asarray(pose[name], np.float64).reshape(-1) for name in POSE_NAMES])
        rotations = axis_angle_to_matrix(full_pose.reshape(5, 3))
        n_vertices = shaped.shape[0]
        feature = (rotations[1:] - np.eye(3)).reshape(-1)
        posed = shaped + (a.posedirs.reshape(n_vertices * 3, -1) @ feature).reshape(n_vertices, 3)
        world = []  # chained (R, t) of each joint, then the rest position removed
        for j in range(5):
            local_t = joints[j] - (joints[self.parents[j]] if j else 0)
            if j == 0:
                world.append((rotations[0], local_t))
            else:
                parent_r, parent_t = world[self.parents[j]]
                world.append((parent_r @ rotations[j], parent_r @ local_t + parent_t))
        transforms = np.zeros((5, 3, 4))
        for j, (r, t) in enumerate(world):
            transforms[j, :, :3], transforms[j, :, 3] = r, t - r @ joints[j]
        blended = np.einsum("vj,jab->vab", a.weights, transforms)
        vertices = np.einsum("vab,vb->va", blended[:, :, :3], posed) + blended[:, :, 3]
        if translation is not None:
            vertices = vertices + np.asarray(translation, np.float64).reshape(3)
        return vertices
