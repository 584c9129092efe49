"""An independent FLAME evaluator for tests: plain numpy, float64, one vertex at a time in spirit.

Written from the published FLAME/SMPL equations, sharing no code with ``core.flame``:
rotations come from the matrix exponential of the skew matrix (scipy), the kinematic
chain is walked with explicit 4×4 homogeneous matrices.
"""

import numpy as np
import scipy.linalg


def rotation(rotvec):
    x, y, z = rotvec
    return scipy.linalg.expm(np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]], dtype=np.float64))


def homogeneous(rot, trans):
    m = np.eye(4)
    m[:3, :3] = rot
    m[:3, 3] = trans
    return m


def flame_vertices(model, shape, expr, rotation_, neck, jaw, eyes, translation, static_offset=None):
    """``model``: dict with v_template, shapedirs (split), posedirs (V,3,36), J_regressor, weights, parents."""
    v = model["v_template"] + model["shapedirs"] @ shape + model["exprdirs"] @ expr
    if static_offset is not None:
        v = v + static_offset
    joints = model["J_regressor"] @ v
    poses = [rotation_, neck, jaw, eyes[:3], eyes[3:]]
    rots = [rotation(np.asarray(p, dtype=np.float64)) for p in poses]
    feature = np.concatenate([(r - np.eye(3)).reshape(-1) for r in rots[1:]])
    v_posed = v + model["posedirs"] @ feature
    world = []
    for j, parent in enumerate(model["parents"]):
        local_t = joints[j] if parent < 0 else joints[j] - joints[parent]
        local = homogeneous(rots[j], local_t)
        world.append(local if parent < 0 else world[parent] @ local)
    skinning = [w @ homogeneous(np.eye(3), -joints[j]) for j, w in enumerate(world)]
    out = np.empty_like(v_posed)
    for i, point in enumerate(v_posed):
        blend = sum(model["weights"][i, j] * skinning[j] for j in range(len(skinning)))
        out[i] = (blend @ np.append(point, 1.0))[:3]
    return out + translation
