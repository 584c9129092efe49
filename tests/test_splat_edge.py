"""Edge cases give finite images and gradients; bad input raises InputError."""

import pytest
import torch

from mogaface.core.errors import InputError
from mogaface.core.splat import rasterize
from mogaface.core.splat.reference import look_at_camera, random_scene, rasterize_reference


def render(scene, width=32, height=24, principal=None, background=None):
    viewmat, K = look_at_camera(width, height, principal=principal)
    params = [p.detach().clone().requires_grad_(True) for p in scene]
    out = rasterize(*params, viewmat, K, width, height, background)
    (out.rgb.sum() + out.alpha.sum() + out.depth.sum()).backward()
    for t in (out.rgb, out.alpha, out.depth, out.means2d):
        assert torch.isfinite(t).all()
    for p in params:
        assert p.grad is not None and torch.isfinite(p.grad).all()
    return out, params


def test_behind_camera_and_on_near_plane():
    means, quats, scales, opac, colors = random_scene(6, 0)
    means[:, 0] = 0.0
    means[:, 1] = 0.0
    means[:, 2] = torch.tensor([-1.0, 0.0, 0.005, 0.01, 0.0100001, 0.5])
    scales[:] = 0.05
    out, params = render((means, quats, scales, opac, colors))
    assert out.radii[:4].tolist() == [0, 0, 0, 0]  # z <= 0.01 is culled
    assert out.radii[5] > 0
    assert torch.all(params[0].grad[:4] == 0)


def test_near_plane_off_axis_is_tame():
    """Just past the near plane, far off-axis: the clamped Jacobian keeps values finite."""
    means, quats, scales, opac, colors = random_scene(4, 1)
    means[:] = torch.tensor([[5.0, 0.0, 0.011], [-5.0, 3.0, 0.02], [0.0, 0.0, 0.0101], [100.0, -100.0, 0.5]])
    render((means, quats, scales, opac, colors))


@pytest.mark.parametrize("scale", [0.0, 1e-30, 1e3, 1e20])
def test_degenerate_scales(scale):
    means, quats, scales, opac, colors = random_scene(20, 2)
    scales[:5] = scale
    scales[5:8, 0] = 0.0  # flat
    out, _ = render((means, quats, scales, opac, colors))
    assert (out.radii[:5] > 0).all()
    if scale >= 1e3:  # covers the whole image: every pixel sees it
        assert (out.alpha > 0.04).all()


def test_huge_scale_matches_reference():
    means, quats, scales, opac, colors = random_scene(10, 3)
    scales[0] = 1e20
    viewmat, K = look_at_camera(16, 12)
    a = rasterize(means, quats, scales, opac, colors, viewmat, K, 16, 12)
    b = rasterize_reference(*(p.double() for p in (means, quats, scales, opac, colors)), viewmat, K, 16, 12)
    assert (a.rgb.double() - b["rgb"]).abs().max() < 1e-4


def test_zero_opacity_and_zero_quaternion():
    means, quats, scales, opac, colors = random_scene(10, 4)
    opac[:3] = 0.0
    quats[3] = 0.0
    out, params = render((means, quats, scales, opac, colors))
    assert out.radii[:3].tolist() == [0, 0, 0]
    assert torch.all(params[3].grad[:3] == 0)


def test_all_off_screen():
    means, quats, scales, opac, colors = random_scene(10, 5)
    means[:, 0] += 50.0
    bg = torch.tensor([0.1, 0.2, 0.3])
    out, _ = render((means, quats, scales, opac, colors), background=bg)
    assert (out.radii == 0).all()
    assert torch.allclose(out.rgb, bg.expand(24, 32, 3))
    assert (out.alpha == 0).all() and (out.depth == 0).all()


def test_empty_scene():
    scene = tuple(t[:0] for t in random_scene(1, 6))
    out, _ = render(scene, background=torch.ones(3))
    assert out.radii.shape == (0,) and out.means2d.shape == (0, 2)
    assert (out.rgb == 1).all()


@pytest.mark.parametrize("size", [(1, 1), (1, 17), (33, 1), (17, 16)])
def test_tiny_and_odd_images(size):
    width, height = size
    means, quats, scales, opac, colors = random_scene(30, 7, spread=0.1, scale=0.2)
    out, _ = render((means, quats, scales, opac, colors), width, height)
    assert out.rgb.shape == (height, width, 3)
    viewmat, K = look_at_camera(width, height)
    ref = rasterize_reference(*(p.double() for p in (means, quats, scales, opac, colors)), viewmat, K,
                              width, height)
    assert (out.alpha.double() - ref["alpha"]).abs().max() < 1e-4
    assert out.alpha.max() > 0


def test_principal_point_outside_image():
    means, quats, scales, opac, colors = random_scene(30, 8)
    render((means, quats, scales, opac, colors), principal=(-20.0, 40.0))


def bad_inputs():
    means, quats, scales, opac, colors = random_scene(5, 9)
    good = dict(means=means, quats=quats, scales=scales, opacities=opac, colors=colors)
    yield "means", dict(good, means=means.double())
    yield "quats", dict(good, quats=quats[:, :3])
    yield "scales", dict(good, scales=scales[:4])
    yield "opacities", dict(good, opacities=opac[:, None])
    yield "colors", dict(good, colors=torch.zeros(5, 5, 3))
    yield "colors", dict(good, colors=colors.numpy())


@pytest.mark.parametrize("field,kwargs", list(bad_inputs()))
def test_bad_input_raises(field, kwargs):
    viewmat, K = look_at_camera(8, 8)
    with pytest.raises(InputError, match=field):
        rasterize(viewmat=viewmat, K=K, width=8, height=8, **kwargs)


@pytest.mark.parametrize("field,value", [("viewmat", torch.eye(3)), ("K", torch.zeros(3, 3)),
                                         ("width", 0), ("background", torch.zeros(4))])
def test_bad_camera_raises(field, value):
    scene = random_scene(5, 10)
    viewmat, K = look_at_camera(8, 8)
    args = dict(viewmat=viewmat, K=K, width=8, height=8, background=None)
    args[field] = value
    with pytest.raises(InputError, match=field):
        rasterize(*scene, **args)
