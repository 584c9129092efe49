"""The procedural default head: FLAME layout, rig properties, expressions, texture."""

from __future__ import annotations

import numpy as np
import pytest

from mogaface.core.flame.procedural import build_head
from mogaface.core.flame.procedural_mesh import build_mesh
from mogaface.core.flame.procedural_sdf import EYE_CENTRE

N_SHAPE = 20


@pytest.fixture(scope="module")
def head():
    return build_head(0, 0)


@pytest.fixture(scope="module")
def mesh():
    return build_mesh()


def _component(head, name):
    names = list(head["expression_names"])
    return head["shapedirs"][:, :, int(head["n_shape"]) + names.index(name)]


def _triangle_areas(v, f):
    return 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)


def test_arrays_have_flame_shapes_and_types(head):
    v = head["v_template"]
    n_v = v.shape[0]
    assert 3000 <= n_v <= 8000
    assert v.dtype == np.float64 and v.shape == (n_v, 3)
    assert head["f"].dtype == np.int64 and head["f"].shape[1] == 3
    assert head["f"].min() == 0 and head["f"].max() == n_v - 1
    n_expr = int(head["n_expr"])
    assert int(head["n_shape"]) == N_SHAPE and n_expr >= 16
    assert head["shapedirs"].shape == (n_v, 3, N_SHAPE + n_expr)
    assert head["posedirs"].shape == (n_v, 3, 36)
    assert head["J_regressor"].shape == (5, n_v)
    assert head["weights"].shape == (n_v, 5)
    np.testing.assert_array_equal(head["kintree_table"], [[4294967295, 0, 1, 1, 1], [0, 1, 2, 3, 4]])
    assert head["texture"].dtype == np.uint8 and head["texture"].shape[2] == 3
    for key in ("v_template", "shapedirs", "posedirs", "J_regressor", "weights", "vt"):
        assert head[key].dtype == np.float64 and np.all(np.isfinite(head[key])), key


def test_head_has_human_size_and_flame_axes(head):
    v = head["v_template"]
    skin_top = v[:, 1].max()
    assert 0.10 < skin_top < 0.14
    nose_tip = v[np.argmax(v[:, 2])]
    assert abs(nose_tip[0]) < 0.005 and -0.05 < nose_tip[1] < 0.0  # the nose points +z
    head_part = v[v[:, 1] > 0.0]
    assert 0.14 < np.ptp(head_part[:, 0]) < 0.19  # ears included
    assert v[:, 1].min() < -0.18  # a neck below the chin
    # Symmetric about x = 0.
    mirrored = v * np.array([-1.0, 1.0, 1.0])
    d = np.min(np.linalg.norm(mirrored[:200, None] - v[None], axis=2), axis=1)
    assert d.max() < 1e-6


def test_triangles_are_not_degenerate(head):
    v, f = head["v_template"], head["f"]
    areas = _triangle_areas(v, f)
    assert areas.min() > 1e-9
    # No needles either (1 for an equilateral triangle): triangle frames stay well defined.
    squared_edges = sum(np.sum((v[f[:, (i + 1) % 3]] - v[f[:, i]]) ** 2, axis=1) for i in range(3))
    assert (4.0 * np.sqrt(3.0) * areas / squared_edges).min() > 0.03


def test_winding_is_consistent_and_outward(head, mesh):
    f = head["f"]
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert counts.max() == 1  # every directed edge once: neighbours agree on orientation
    v = head["v_template"]
    for part in (2, 3):  # each eyeball is closed with positive volume
        fs = f[np.all(mesh.part[f] == part, axis=1)]
        volume = np.einsum("ij,ij->i", v[fs[:, 0]], np.cross(v[fs[:, 1]], v[fs[:, 2]])).sum() / 6.0
        assert volume == pytest.approx(4 / 3 * np.pi * 0.012**3, rel=0.15)
    for part in (5, 6):  # each ear is a closed shell
        fs = f[np.all(mesh.part[f] == part, axis=1)]
        volume = np.einsum("ij,ij->i", v[fs[:, 0]], np.cross(v[fs[:, 1]], v[fs[:, 2]])).sum() / 6.0
        assert 1e-6 < volume < 2e-5
    cranium = f[np.all(v[f][:, :, 1] > 0.06, axis=1)]
    normals = np.cross(v[cranium[:, 1]] - v[cranium[:, 0]], v[cranium[:, 2]] - v[cranium[:, 0]])
    outward = v[cranium].mean(axis=1) - np.array([0.0, 0.02, -0.01])
    assert np.all(np.einsum("ij,ij->i", normals, outward) > 0)


def test_skin_is_closed_except_openings(head, mesh):
    f = head["f"]
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    boundary = unique[counts == 1]
    v = head["v_template"]
    # Open edges: the neck bottom, and the inner edge of each eye opening's lining, hidden
    # inside the eyeball. The mouth is closed by its bag.
    ends = boundary.ravel()
    at_neck = v[ends, 1] < -0.19
    eye_distance = np.minimum(np.linalg.norm(v[ends] - EYE_CENTRE, axis=1),
                              np.linalg.norm(v[ends] - EYE_CENTRE * [-1, 1, 1], axis=1))
    in_eyeball = (mesh.part[ends] == 4) & (eye_distance < 0.012)
    assert np.all(at_neck | in_eyeball)
    assert at_neck.sum() >= 2 * mesh.grid_columns


def test_skinning_weights_are_convex_and_eyes_rigid(head, mesh):
    w = head["weights"]
    assert w.min() >= 0.0
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-12)
    for part, joint in ((2, 3), (3, 4)):
        np.testing.assert_array_equal(w[mesh.part == part, joint], 1.0)
    v = head["v_template"]
    chin = np.argmin(np.linalg.norm(v - np.array([0.0, -0.1, 0.09]), axis=1))
    crown = np.argmax(v[:, 1])
    assert w[chin, 2] > 0.95 and w[crown, 1] == 1.0
    # The lip seam separates them: the upper lip stays with the head, the lower lip follows the jaw.
    middle = len(mesh.upper_lip_rim) // 2
    assert w[mesh.upper_lip_rim[1:-1], 2].max() < 0.1 and w[mesh.upper_lip_rim[middle], 2] < 1e-3
    assert w[mesh.lower_lip_rim[middle - 3:middle + 4], 2].min() > 0.99
    assert np.all(w[v[:, 1] < -0.19, 0] == 1.0)


def test_joint_regressor_rows_are_sparse_convex_and_well_placed(head):
    j_reg = head["J_regressor"]
    assert j_reg.min() >= 0.0
    np.testing.assert_allclose(j_reg.sum(axis=1), 1.0, atol=1e-9)
    assert np.all((j_reg > 0).sum(axis=1) < 400)
    joints = j_reg @ head["v_template"]
    np.testing.assert_allclose(joints[3], EYE_CENTRE, atol=2e-4)
    np.testing.assert_allclose(joints[4], EYE_CENTRE * [-1, 1, 1], atol=2e-4)
    assert np.all(np.abs(joints[:3, 0]) < 1e-4)  # root, neck, jaw on the midline
    assert joints[2, 1] > joints[1, 1] and joints[2, 2] > joints[1, 2]  # jaw hinge above and in front of neck


def test_shape_moves_joints(head):
    head_width = head["shapedirs"][:, :, 0]
    eye_shift = head["J_regressor"] @ head_width
    assert eye_shift[3, 0] > 1e-4 and eye_shift[4, 0] < -1e-4


def test_components_are_named(head):
    names = list(head["expression_names"])
    assert head["expression_names"].dtype.kind == "U" and len(names) == int(head["n_expr"])
    assert len(head["shape_names"]) == N_SHAPE and head["shape_names"].dtype.kind == "U"
    for name in ("smile_left", "smile_right", "lip_pucker", "blink_left", "blink_right", "brow_raise_left",
                 "brow_frown", "cheek_puff", "jaw_forward", "nose_wrinkle"):
        assert name in names
        assert np.abs(_component(head, name)).max() > 1e-3, name


def test_expressions_stay_on_the_face(head, mesh):
    v = head["v_template"]
    expr = head["shapedirs"][:, :, N_SHAPE:]
    back = v[:, 2] < -0.02
    neck = v[:, 1] < -0.15
    eyes = (mesh.part == 2) | (mesh.part == 3)
    ears = (mesh.part == 5) | (mesh.part == 6)
    assert np.abs(expr[back | neck | eyes | ears]).max() == 0.0
    assert np.abs(head["posedirs"][eyes]).max() == 0.0
    # Strong but plausible: at most a couple of centimetres per unit.
    assert np.abs(expr).max() < 0.02


def test_blink_closes_the_eye(head, mesh):
    v = head["v_template"]
    for eye, name in ((0, "blink_left"), (1, "blink_right")):
        upper, lower = mesh.upper_lid_rims[eye], mesh.lower_lid_rims[eye]
        open_gap = np.linalg.norm(v[upper] - v[lower], axis=1).max()
        assert open_gap > 0.006
        closed = v + _component(head, name)
        assert np.linalg.norm(closed[upper] - closed[lower], axis=1).max() < 5e-4
        # The other eye stays open.
        other = 1 - eye
        assert np.abs(_component(head, name)[mesh.upper_lid_rims[other]]).max() == 0.0


def test_jaw_pose_opens_the_mouth(head, mesh):
    v = head["v_template"]
    joints = head["J_regressor"] @ v
    angle = 0.3
    rot = np.array([[1, 0, 0], [0, np.cos(angle), -np.sin(angle)], [0, np.sin(angle), np.cos(angle)]])
    moved = (v - joints[2]) @ rot.T + joints[2]
    w = head["weights"][:, 2:3]
    posed = (1 - w) * v + w * moved  # neck and root are at rest, so they stay put
    gap = posed[mesh.upper_lip_rim[1:-1], 1] - posed[mesh.lower_lip_rim[1:-1], 1]
    assert gap.max() > 0.015
    area_rest = _triangle_areas(v, head["f"])
    area_open = _triangle_areas(posed, head["f"])
    assert (area_open / area_rest).max() < 20.0  # stretches at the corners, never tears


def test_uvs_in_unit_square(head):
    vt, ft = head["vt"], head["ft"]
    assert vt.min() >= 0.0 and vt.max() <= 1.0
    assert ft.shape == head["f"].shape and ft.max() < len(vt) and ft.min() >= 0
    assert len(vt) >= len(head["v_template"])


def test_texture_has_fine_detail(head):
    tex = head["texture"].astype(float).mean(axis=2)
    laplacian = 4 * tex[1:-1, 1:-1] - tex[:-2, 1:-1] - tex[2:, 1:-1] - tex[1:-1, :-2] - tex[1:-1, 2:]
    assert np.sqrt(np.mean(laplacian**2)) > 4.0
    assert tex.std() > 20.0


def test_same_arguments_give_identical_arrays(head):
    from mogaface.core.flame.procedural import _built_head

    _built_head.cache_clear()  # built again, not the process's kept copy
    again = build_head(0, 0)
    for key, value in head.items():
        np.testing.assert_array_equal(again[key], value, err_msg=key)
    again["v_template"][:] = 0  # each caller's own arrays: the kept head is untouched
    assert np.array_equal(build_head(0, 0)["v_template"], head["v_template"])


def test_subjects_and_seeds_differ(head):
    other = build_head(3, 0)
    assert np.abs(other["v_template"] - head["v_template"]).max() > 1e-3
    assert np.abs(other["texture"].astype(int) - head["texture"]).mean() > 5.0
    reseeded = build_head(0, 1)
    np.testing.assert_array_equal(reseeded["v_template"], head["v_template"])
    assert np.any(reseeded["texture"] != head["texture"])
