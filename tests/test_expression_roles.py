"""Expressions by role on a model without component names (as the released FLAME files are)."""

import numpy as np
import vhap_fixture as V

from mogaface.core.flame.expression_roles import has_component_names, mouth_components, role_expression
from mogaface.core.flame.model_file import _validate
from mogaface.core.flame.teeth import LIP_RING_LOWER, LIP_RING_UPPER


def unnamed_model():
    """The synthetic FLAME-sized model, its eye joints put on the face, with planted components."""
    raw = V.synthetic_flame_topology(seed=3)
    v = raw["v_template"]
    raw["shapedirs"][:, :, 300:] *= 0.01  # background components barely move anything
    grid = raw["J_regressor"][0] > 0  # the ellipsoid's vertices (their mean is the centre)
    for joint, x in ((3, 0.03), (4, -0.03)):
        nearest = np.argmin(np.linalg.norm(v - [x, 0.03, 0.09], axis=1))
        raw["J_regressor"][joint] = 0.2 * grid / grid.sum()
        raw["J_regressor"][joint, nearest] += 0.8  # an eyeball centre ~2 cm behind the skin
    arrays = _validate("synthetic", raw, None, None)
    lips = list(LIP_RING_UPPER) + list(LIP_RING_LOWER)
    corners = [LIP_RING_UPPER[0], LIP_RING_UPPER[-1], LIP_RING_LOWER[0], LIP_RING_LOWER[-1]]
    arrays.exprdirs[corners, 1, 17] = -0.01  # component 17, negative: corners up (a smile)
    arrays.exprdirs[lips, 2, 42] = 0.01  # component 42: the mouth forward (a pucker)
    joints = arrays.J_regressor @ v
    for eye in joints[3:5]:
        near = (np.linalg.norm(v - eye, axis=1) < 0.025) & (v[:, 2] > eye[2])
        arrays.exprdirs[near, 1, 63] = -0.01  # component 63: around the eyes down (a blink)
        above = (v[:, 1] - eye[1] > 0.02) & (v[:, 1] - eye[1] < 0.035) & (np.abs(v[:, 0] - eye[0]) < 0.02)
        arrays.exprdirs[above & (v[:, 2] > eye[2]), 1, 80] = 0.01  # component 80: brows up
    return arrays


def test_roles_are_chosen_by_geometry_without_names():
    arrays = unnamed_model()
    assert not has_component_names(arrays.expression_names)
    smile = role_expression(arrays, "smile")
    assert np.flatnonzero(smile).tolist() == [17] and smile[17] < 0
    assert np.flatnonzero(role_expression(arrays, "pucker")).tolist() == [42]
    assert np.flatnonzero(role_expression(arrays, "blink")).tolist() == [63]
    assert np.flatnonzero(role_expression(arrays, "brow_raise")).tolist() == [80]
    mouth = mouth_components(arrays, count=8)
    assert len(mouth) == 8 and {17, 42} <= set(mouth)


def test_named_models_keep_choosing_by_name(procedural_head):
    arrays = _validate("procedural", procedural_head, None, None)
    assert has_component_names(arrays.expression_names)
    smile = role_expression(arrays, "smile")
    assert all(("smile" in n or "cheek" in n) == bool(smile[i]) for i, n in enumerate(arrays.expression_names))
    named = [i for i, n in enumerate(arrays.expression_names) if "lip" in n or "mouth" in n]
    assert set(named) <= set(mouth_components(arrays)) and len(mouth_components(arrays)) < arrays.n_expr
