"""Gaussians bound to triangles: frames, local → world, quaternions, the avatar file."""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from mogaface.core.avatar.avatar import Avatar, flame_params_to_torch
from mogaface.core.avatar.binding import bound_to_world, matrix_to_quaternion, quaternion_multiply, triangle_frames
from mogaface.core.avatar.gaussians import BoundGaussians
from mogaface.core.errors import InputError


def test_frame_and_scale_of_a_known_triangle():
    vertices = torch.tensor([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.5, 1.0, 0.0]], dtype=torch.float64)
    frames = triangle_frames(vertices, torch.tensor([[0, 1, 2]]))
    # Columns: first edge (+x), normal (+z), edge × normal (−y).
    np.testing.assert_allclose(frames.rotation[0].numpy(), [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-12)
    assert frames.scale.item() == pytest.approx((2.0 + 1.0) / 2)  # first edge 2, height 1
    np.testing.assert_allclose(frames.centroid[0].numpy(), [2.5 / 3, 1 / 3, 0], atol=1e-12)


def test_frames_are_rotations():
    rng = np.random.default_rng(0)
    vertices = torch.tensor(rng.normal(size=(30, 3)))
    faces = torch.tensor(rng.choice(30, size=(20, 3), replace=True))
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    rot = triangle_frames(vertices, faces).rotation
    eye = torch.eye(3, dtype=torch.float64).expand_as(rot)
    np.testing.assert_allclose((rot.transpose(1, 2) @ rot).numpy(), eye.numpy(), atol=1e-10)
    np.testing.assert_allclose(torch.linalg.det(rot).numpy(), 1.0, atol=1e-10)


def test_quaternions_match_scipy():
    rotations = Rotation.random(200, random_state=1)
    near_half_turn = Rotation.from_rotvec(np.pi * 0.99999 * np.eye(3))
    matrices = np.concatenate([rotations.as_matrix(), near_half_turn.as_matrix(), np.eye(3)[None]])
    ours = matrix_to_quaternion(torch.tensor(matrices)).numpy()
    xyzw = Rotation.from_matrix(matrices).as_quat()
    theirs = np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1)
    theirs *= np.where(theirs[:, :1] < 0, -1, 1)
    # q and -q are the same rotation; compare up to sign where w is ~0.
    error = np.minimum(np.abs(ours - theirs).max(1), np.abs(ours + theirs).max(1))
    assert error.max() < 1e-7
    a, b = Rotation.random(2, random_state=2)
    qa, qb = (np.roll(r.as_quat(), 1) for r in (a, b))
    product = quaternion_multiply(torch.tensor(qa), torch.tensor(qb)).numpy()
    expected = np.roll((a * b).as_quat(), 1)
    assert min(np.abs(product - expected).max(), np.abs(product + expected).max()) < 1e-12


def _random_bound(n_faces=6, n=15, seed=3):
    rng = np.random.default_rng(seed)
    vertices = torch.tensor(rng.normal(size=(3 * n_faces, 3)))
    faces = torch.arange(3 * n_faces).reshape(n_faces, 3)
    binding = torch.tensor(rng.integers(0, n_faces, size=n))
    local = [torch.tensor(rng.normal(size=s)) for s in ((n, 3), (n, 3), (n, 4))]
    return vertices, faces, binding, local


def test_gaussians_follow_a_similarity_transform_of_the_mesh():
    vertices, faces, binding, (position, log_scale, rotation) = _random_bound()
    means, scales, quats = bound_to_world(triangle_frames(vertices, faces), binding, position, log_scale, rotation)
    turn = Rotation.random(random_state=4)
    R, s, t = torch.tensor(turn.as_matrix()), 1.7, torch.tensor([0.3, -0.2, 1.0], dtype=torch.float64)
    moved = s * vertices @ R.T + t
    means2, scales2, quats2 = bound_to_world(triangle_frames(moved, faces), binding, position, log_scale, rotation)
    np.testing.assert_allclose(means2.numpy(), (s * means @ R.T + t).numpy(), atol=1e-10)
    np.testing.assert_allclose(scales2.numpy(), s * scales.numpy(), rtol=1e-10)
    q_turn = torch.tensor(np.roll(turn.as_quat(), 1)).expand_as(quats)
    expected = quaternion_multiply(q_turn, quats)
    sign = torch.sign((expected * quats2).sum(-1, keepdim=True))
    np.testing.assert_allclose(quats2.numpy(), (sign * expected).numpy(), atol=1e-10)


def test_local_zero_gaussian_sits_at_the_centroid_with_the_triangle_size():
    vertices, faces, _, _ = _random_bound(n_faces=4)
    frames = triangle_frames(vertices, faces)
    n = 4
    means, scales, _ = bound_to_world(frames, torch.arange(n), torch.zeros(n, 3, dtype=torch.float64),
                                      torch.zeros(n, 3, dtype=torch.float64), torch.tensor([[1.0, 0, 0, 0]] * n, dtype=torch.float64))
    np.testing.assert_allclose(means.numpy(), frames.centroid.numpy(), atol=1e-12)
    np.testing.assert_allclose(scales.numpy(), frames.scale[:, None].expand(n, 3).numpy(), atol=1e-12)


def test_binding_gradients_match_finite_differences():
    vertices, faces, binding, local = _random_bound(n_faces=3, n=5)
    inputs = [vertices.requires_grad_(), *(x.requires_grad_() for x in local)]

    def f(v, p, s, r):
        return bound_to_world(triangle_frames(v, faces), binding, p, s, r)

    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-5)


def test_avatar_save_load_round_trip(procedural_head_pkl, tmp_path):
    import shutil

    head = tmp_path / "head.pkl"
    shutil.copyfile(procedural_head_pkl, head)
    avatar = Avatar.initial(head)
    with torch.no_grad():
        avatar.gaussians.local_position.normal_(std=0.2)
        avatar.gaussians.sh_rest.normal_(std=0.1)
    avatar.gaussians.active_sh_degree = 2
    avatar.save(tmp_path / "avatar.pt")
    loaded = Avatar.load(tmp_path / "avatar.pt")
    assert loaded.gaussians.active_sh_degree == 2
    for name, value in avatar.gaussians.tensors().items():
        assert torch.equal(value, loaded.gaussians.tensors()[name]), name
    from mogaface.core.camera import Camera

    camera = Camera.look_at([0.0, 0.0, 1.0], [0.0, 0.0, 0.0], width=40, height=32, fx=120.0)
    params = flame_params_to_torch({"jaw_pose": np.array([0.2, 0, 0]), "expr": np.ones(avatar.flame.n_expr)})
    with torch.no_grad():
        a, b = avatar.render(params, camera), loaded.render(params, camera)
    assert torch.equal(a.rgb, b.rgb) and a.alpha.sum() > 1.0


def test_bad_avatar_files(tmp_path):
    (tmp_path / "junk.pt").write_bytes(b"not a torch file")
    with pytest.raises(InputError, match="junk.pt: not a torch archive"):
        Avatar.load(tmp_path / "junk.pt")
    torch.save({"format": "something else"}, tmp_path / "other.pt")
    with pytest.raises(InputError, match="field 'format'"):
        Avatar.load(tmp_path / "other.pt")
    with pytest.raises(InputError, match="local_position"):
        BoundGaussians(torch.zeros(2, dtype=torch.long), 0, local_position=torch.zeros(3, 3))
