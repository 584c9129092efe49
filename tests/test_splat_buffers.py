"""The Blender-free parts of the viewport's GPU draw (core/for_blender/splat_buffers.py): covariances,
back-to-front order keyed on view, frame and pose, the packed texture, the posing cache, and the
draw's maths (the shaders' steps, replayed here in numpy on the packed texture) against the
splat engine's render of the same view."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mogaface.core.camera import Camera
from mogaface.core.for_blender import splat_buffers
from mogaface.core.for_blender.render import RenderRequest, blender_rgba, render, view_camera


def _rotation(axis, angle):
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def _splats(n=200, seed=0, key="pose-a"):
    rng = np.random.default_rng(seed)
    quats = rng.normal(size=(n, 4))
    scales = rng.uniform(0.005, 0.03, (n, 3))
    return splat_buffers.PosedSplats(
        means=rng.uniform(-0.2, 0.2, (n, 3)).astype(np.float32),
        covariances=splat_buffers.covariances(quats, scales),
        opacities=rng.uniform(0.0, 1.0, n).astype(np.float32),
        colors=rng.normal(0.0, 0.3, (n, 4, 3)).astype(np.float32), key=key), quats, scales


def _w2c(rotation, eye):
    w2c = np.eye(4)
    w2c[:3, :3] = rotation
    w2c[:3, 3] = -rotation @ np.asarray(eye, np.float64)
    return w2c


def test_covariances_are_r_s_s_r():
    splats, quats, scales = _splats(5)
    for q, s, cov in zip(quats, scales, splats.covariances):
        w, x, y, z = q / np.linalg.norm(q)
        rot = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
        full = rot @ np.diag(s ** 2) @ rot.T
        np.testing.assert_allclose(cov, full[[0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]], rtol=1e-5, atol=1e-9)


def test_back_to_front_is_by_view_depth_and_drops_what_cannot_show():
    splats, _, _ = _splats()
    w2c = _w2c(np.diag([1.0, -1.0, -1.0]), (0.0, 0.0, 1.0))  # looking down -z from z = 1
    order = splat_buffers.back_to_front(splats, w2c)
    depth = splats.means.astype(np.float64) @ w2c[2, :3] + w2c[2, 3]
    assert np.all(np.diff(depth[order]) <= 0)
    assert set(order) == set(np.flatnonzero(splats.opacities >= 1 / 255))
    behind = _w2c(np.eye(3), (0.0, 0.0, 1.0))  # looking up +z: everything behind the camera
    assert len(splat_buffers.back_to_front(splats, behind)) == 0


def test_the_order_is_rebuilt_when_the_view_turns_in_place_or_the_frame_changes():
    splats, _, _ = _splats()
    eye = (0.0, 0.0, 1.0)
    front = _w2c(np.diag([1.0, -1.0, -1.0]), eye)
    order = splat_buffers.SplatOrder()
    assert order.update(splats, front, frame=1)
    first = order.packed.texels.copy()
    assert not order.update(splats, front, frame=1)  # nothing changed: no new sort
    turned = _w2c(_rotation((0.0, 1.0, 0.0), 0.5) @ np.diag([1.0, -1.0, -1.0]), eye)  # same eye, turned
    assert order.update(splats, turned, frame=1)
    depth = splats.means.astype(np.float64) @ turned[2, :3] + turned[2, 3]
    means = order.packed.texels.reshape(-1, 4, 4)[:order.packed.count, 0, :3]
    packed_depth = means.astype(np.float64) @ turned[2, :3] + turned[2, 3]
    assert np.all(np.diff(packed_depth) <= 1e-6) and not np.array_equal(order.packed.texels, first)
    assert len(means) == int(((depth > 0.01) & (splats.opacities >= 1 / 255)).sum())
    assert order.update(splats, turned, frame=2)  # the frame changed, the view did not
    moved = splat_buffers.PosedSplats(-splats.means, splats.covariances, splats.opacities, splats.colors, "pose-b")
    assert order.update(moved, turned, frame=2)  # a new pose (the head's values changed)
    means = order.packed.texels.reshape(-1, 4, 4)[:order.packed.count, 0, :3]
    assert np.all(np.diff(means.astype(np.float64) @ turned[2, :3]) <= 1e-6)
    assert order.sorts == 4


def test_pack_holds_each_gaussian_in_four_texels():
    splats, _, _ = _splats(1500)
    order = np.arange(1500)[::-1]
    colors = np.random.default_rng(1).uniform(0, 1, (1500, 3)).astype(np.float32)
    packed = splat_buffers.pack(splats, order, colors)
    width, rows = packed.size
    assert width == splat_buffers.TEXTURE_WIDTH and rows == 2 and packed.count == 1500
    texels = packed.texels.reshape(-1, 4)
    for slot, g in ((0, 1499), (1023, 476), (1024, 475), (1499, 0)):  # across the row break
        at = slot * 4
        np.testing.assert_array_equal(texels[at], [*splats.means[g], splats.opacities[g]])
        np.testing.assert_array_equal(texels[at + 1], splats.covariances[g, :4])
        np.testing.assert_array_equal(texels[at + 2, :2], splats.covariances[g, 4:])
        np.testing.assert_array_equal(texels[at + 3, :3], colors[g])


def test_view_colors_are_the_engines_sh_for_the_camera():
    from mogaface.core.splat.sh import sh_to_rgb

    splats, _, _ = _splats(50)
    w2c = _w2c(np.diag([1.0, -1.0, -1.0]), (0.1, 0.2, 1.0))
    expected = sh_to_rgb(torch.from_numpy(splats.colors), torch.from_numpy(splats.means),
                         torch.tensor([0.1, 0.2, 1.0])).numpy()
    np.testing.assert_allclose(splat_buffers.view_colors(splats, w2c), np.clip(expected, 0, 1), atol=1e-5)
    turned = _w2c(_rotation((1.0, 0.0, 0.0), 0.4) @ np.diag([1.0, -1.0, -1.0]), (0.1, 0.2, 1.0))
    np.testing.assert_allclose(splat_buffers.view_colors(splats, turned), np.clip(expected, 0, 1), atol=1e-5)


def shader_draw(packed, values, width, height):
    """The vertex and fragment shaders of operators/handlers/gpu_draw.py step by step in numpy,
    blended "over" in the packed (back-to-front) order: ``(H, W, 4)`` linear premultiplied, top row
    first."""
    from mogaface.core.io.image import srgb_to_linear

    out = np.zeros((height, width, 4), np.float64)
    V = values["viewmat"]
    fx, fy, cx, cy = values["intrinsics"]
    lxp, lxn, lyp, lyn = values["limits"]
    ys, xs = np.mgrid[0:height, 0:width] + 0.5
    for t0, t1, t2, t3 in packed.texels.reshape(-1, 4, 4)[:packed.count]:
        p = V[:3, :3] @ t0[:3] + V[:3, 3]
        if p[2] <= 0.01:
            continue
        u, v = np.clip(p[0] / p[2], -lxn, lxp), np.clip(p[1] / p[2], -lyn, lyp)
        a = np.array([fx / p[2], 0, -fx * u / p[2]]) @ V[:3, :3]
        b = np.array([0, fy / p[2], -fy * v / p[2]]) @ V[:3, :3]
        S = np.array([[t1[0], t1[1], t1[2]], [t1[1], t1[3], t2[0]], [t1[2], t2[0], t2[1]]])
        sxx, sxy, syy = a @ S @ a + 0.3, b @ S @ a, b @ S @ b + 0.3
        det = sxx * syy - sxy * sxy
        mid = 0.5 * (sxx + syy)
        radius = np.ceil(3 * np.sqrt(mid + np.sqrt(max(mid * mid - det, 0))))
        mx, my = fx * p[0] / p[2] + cx, fy * p[1] / p[2] + cy
        # the pixels whose centres lie in the quad (|dx|, |dy| <= radius); none outside it change
        x0, x1 = max(0, int(np.ceil(mx - radius - 0.5))), min(width, int(np.floor(mx + radius - 0.5)) + 1)
        y0, y1 = max(0, int(np.ceil(my - radius - 0.5))), min(height, int(np.floor(my + radius - 0.5)) + 1)
        if x0 >= x1 or y0 >= y1:
            continue
        dx, dy = xs[y0:y1, x0:x1] - mx, ys[y0:y1, x0:x1] - my
        inside = (np.abs(dx) <= radius) & (np.abs(dy) <= radius)
        q = (syy * dx * dx - 2 * sxy * dx * dy + sxx * dy * dy) / det
        alpha = np.minimum(0.99, t0[3] * np.exp(-0.5 * q))
        alpha = np.where(inside & (q <= 9) & (alpha >= 1 / 255), alpha, 0.0)[..., None]
        color = np.append(srgb_to_linear(t3[:3]), 1.0)
        out[y0:y1, x0:x1] = color * alpha + out[y0:y1, x0:x1] * (1 - alpha)
    return out


@pytest.fixture(scope="module")
def small_avatar(tmp_path_factory):
    """The procedural head with one Gaussian per triangle, made opaque and varied in colour."""
    from mogaface.core.avatar.avatar import Avatar
    from mogaface.core.flame.model_file import write_model_file
    from mogaface.core.flame.procedural import build_head

    folder = tmp_path_factory.mktemp("gpu-avatar")
    write_model_file(folder / "head.pkl", build_head(subject=0, seed=0))
    avatar = Avatar.initial(folder / "head.pkl", max_sh_degree=1)
    gen = torch.Generator().manual_seed(0)
    with torch.no_grad():
        avatar.gaussians.opacity_logit.copy_(torch.rand(avatar.gaussians.opacity_logit.shape, generator=gen) * 6 - 1)
        avatar.gaussians.sh_dc.copy_(torch.rand(avatar.gaussians.sh_dc.shape, generator=gen) - 0.5)
    avatar.save(folder / "avatar.pt")
    return folder / "avatar.pt"


def _view(width, height):
    """A Blender view (world→view, OpenGL projection) facing the procedural head from 0.5 m."""
    projection = np.zeros((4, 4))
    near, far = 0.01, 100.0
    projection[0, 0] = projection[1, 1] = 2.8
    projection[2, 2], projection[2, 3], projection[3, 2] = -(far + near) / (far - near), -2 * far * near / (far - near), -1
    c2w = np.array([[1.0, 0, 0, 0.0], [0, 0, -1, -0.5], [0, 1, 0, 0.02], [0, 0, 0, 1]])
    return np.linalg.inv(c2w), projection


def test_posing_is_the_avatars_own_and_cached_per_pose(small_avatar):
    from mogaface.core.for_blender.avatar import load_avatar

    values = {"expr": np.zeros(3), "jaw_pose": np.array([0.2, 0.0, 0.0])}
    first = splat_buffers.posed_splats(str(small_avatar), values)
    assert splat_buffers.posed_splats(str(small_avatar), dict(values)) is first  # the same pose: cached
    other = splat_buffers.posed_splats(str(small_avatar), {**values, "jaw_pose": np.array([0.0, 0.0, 0.0])})
    assert other.key != first.key and np.abs(other.means - first.means).max() > 1e-4  # the jaw closed
    avatar = load_avatar(str(small_avatar))
    from mogaface.core.avatar.avatar import flame_params_to_torch
    from mogaface.core.for_blender.render import fitted_params

    with torch.no_grad():
        world = avatar.world_gaussians(flame_params_to_torch(fitted_params(values, avatar)))
    np.testing.assert_allclose(first.means, world["means"].numpy(), atol=1e-6)
    np.testing.assert_allclose(first.opacities, world["opacities"].numpy(), atol=1e-7)


def test_the_draws_maths_agree_with_the_engines_render(small_avatar):
    """The same view drawn by the shaders' maths and rendered by the engine: ≥ 30 dB over the
    avatar's pixels, as premultiplied sRGB (what "Standard" shows over black)."""
    from mogaface.core.for_blender.render import srgb_from_blender

    width, height = 96, 80
    view_matrix, projection = _view(width, height)
    view = view_camera(view_matrix, projection, np.diag([2.0, 2.0, 2.0, 1.0]), width, height)
    values = {"jaw_pose": np.array([0.1, 0.0, 0.0])}
    core = render(RenderRequest(str(small_avatar), values, view.camera, None, view.scale))
    splats = splat_buffers.posed_splats(str(small_avatar), values)
    order = splat_buffers.SplatOrder()
    order.update(splats, view.camera.w2c, frame=0)
    drawn = shader_draw(order.packed, splat_buffers.shader_values(view, projection, width, height), width, height)
    mask = core.alpha > 1 / 255
    assert mask.mean() > 0.2
    got, expected = srgb_from_blender(drawn.astype(np.float32)), srgb_from_blender(blender_rgba(core))
    db = 10 * np.log10(1 / np.mean((got[mask] - expected[mask]) ** 2))
    assert db >= 30.0, db
    print(f"shader maths against the engine: {db:.1f} dB")
    assert np.abs(drawn[..., 3] - core.alpha).max() < 0.05
    # at twice the target size the camera's pixels scale with it (the same picture, finer)
    finer = shader_draw(order.packed, splat_buffers.shader_values(view, projection, 2 * width, 2 * height),
                        2 * width, 2 * height)
    assert abs(finer[..., 3].mean() - drawn[..., 3].mean()) < 0.02


def test_a_camera_of_another_size_is_scaled_to_the_target():
    camera = Camera(np.array([[100.0, 0, 32], [0, 100, 24], [0, 0, 1]]), np.eye(4), 64, 48)
    view = type("View", (), {"camera": camera, "scale": 1.0, "depth_offset": 0.0})()
    values = splat_buffers.shader_values(view, np.eye(4), 128, 96)
    assert values["intrinsics"] == (200.0, 200.0, 64.0, 48.0)
    assert values["depth_map"] == (128.0, 96.0, 1.0, 0.0)
