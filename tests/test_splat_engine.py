"""The splat engine against its pure-torch reference: images, radii and every gradient."""

import pytest
import torch

from mogaface.core.splat import rasterize
from mogaface.core.splat.reference import closest_to_threshold, look_at_camera, random_scene, rasterize_reference

W, H = 32, 24
NAMES = ("means", "quats", "scales", "opacities", "colors")


def clean_scene(n, seed, width=W, height=H, principal=None, margin=1e-4, **kw):
    """A random scene with no (pixel, splat) pair near a compositing threshold, so float32 and
    float64 make the same discrete decisions."""
    viewmat, K = look_at_camera(width, height, principal=principal)
    for s in range(seed, seed + 50):
        scene = random_scene(n, s, **kw)
        if closest_to_threshold(*scene[:4], viewmat, K, width, height) > margin:
            return scene, viewmat, K
    raise AssertionError("no clean scene found")


def render_and_grad(fn, scene, viewmat, K, width, height, background, dtype, seed=7):
    params = [p.detach().to(dtype).requires_grad_(True) for p in scene]
    bg = background.detach().to(dtype).requires_grad_(True)
    out = fn(*params, viewmat, K, width, height, bg)
    get = (lambda k: out[k]) if isinstance(out, dict) else (lambda k: getattr(out, k))
    g = torch.Generator().manual_seed(seed)
    w_rgb = torch.randn(height, width, 3, generator=g, dtype=torch.float64).to(dtype)
    w_a = torch.randn(height, width, generator=g, dtype=torch.float64).to(dtype)
    w_d = torch.randn(height, width, generator=g, dtype=torch.float64).to(dtype)
    loss = (get("rgb") * w_rgb).sum() + (get("alpha") * w_a).sum() + (get("depth") * w_d).sum()
    loss.backward()
    result = {k: get(k).detach().double() for k in ("rgb", "alpha", "depth", "radii")}
    result["means2d_grad"] = get("means2d").grad.double()
    result.update({name: p.grad.double() for name, p in zip(NAMES, params)})
    result["background"] = bg.grad.double()
    return result


def assert_matches(engine, ref, image_tol=2e-5, grad_rtol=2e-4):
    for key in ("rgb", "alpha", "depth"):
        err = (engine[key] - ref[key]).abs().max().item()
        assert err < image_tol * max(1.0, ref[key].abs().max().item()), (key, err)
    assert torch.equal(engine["radii"], ref["radii"])
    for key in ("means2d_grad", "background") + NAMES:
        scale = ref[key].abs().max().item()
        err = (engine[key] - ref[key]).abs().max().item()
        assert err <= grad_rtol * max(scale, 1e-3), (key, err, scale)


@pytest.mark.parametrize("seed", [0, 1])
def test_rgb_scene_matches_reference(seed):
    scene, viewmat, K = clean_scene(150, seed * 100)
    bg = torch.tensor([0.2, 0.5, 0.9])
    engine = render_and_grad(rasterize, scene, viewmat, K, W, H, bg, torch.float32)
    ref = render_and_grad(rasterize_reference, scene, viewmat, K, W, H, bg, torch.float64)
    assert engine["alpha"].max() > 0.9  # the scene covers pixels to saturation
    assert (engine["radii"] > 0).sum() > 50
    assert_matches(engine, ref)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_sh_colours_match_reference(degree):
    scene, viewmat, K = clean_scene(80, 10 + degree, sh_degree=degree)
    bg = torch.tensor([0.3, 0.3, 0.3])
    engine = render_and_grad(rasterize, scene, viewmat, K, W, H, bg, torch.float32)
    ref = render_and_grad(rasterize_reference, scene, viewmat, K, W, H, bg, torch.float64)
    assert ref["colors"].abs().sum() > 0
    assert_matches(engine, ref)


@pytest.mark.parametrize("size,principal", [((40, 17), None), ((19, 33), (3.0, 25.0)), ((48, 32), (40.5, 2.0))])
def test_non_square_and_off_centre(size, principal):
    width, height = size
    scene, viewmat, K = clean_scene(120, 50, width=width, height=height, principal=principal, spread=0.5)
    bg = torch.tensor([0.0, 1.0, 0.5])
    engine = render_and_grad(rasterize, scene, viewmat, K, width, height, bg, torch.float32)
    ref = render_and_grad(rasterize_reference, scene, viewmat, K, width, height, bg, torch.float64)
    assert engine["rgb"].shape == (height, width, 3)
    assert_matches(engine, ref)


def test_saturated_pixels_stop_early():
    """Dense opaque scene: transmittance cut-off and the 0.99 clamp are exercised."""
    scene, viewmat, K = clean_scene(60, 300, depth=1.0, spread=0.25, scale=0.2, opacity=(0.6, 1.0), margin=2e-5)
    assert (scene[3] > 0.99).any()  # some alphas clamp at 0.99
    bg = torch.tensor([1.0, 0.0, 0.0])
    engine = render_and_grad(rasterize, scene, viewmat, K, W, H, bg, torch.float32)
    ref = render_and_grad(rasterize_reference, scene, viewmat, K, W, H, bg, torch.float64)
    assert (ref["alpha"] > 0.999).float().mean() > 0.2
    assert_matches(engine, ref, grad_rtol=1e-3)


def test_means2d_gradient_is_kept():
    scene, viewmat, K = clean_scene(60, 400)
    params = [p.clone().requires_grad_(True) for p in scene]
    out = rasterize(*params, viewmat, K, W, H)
    assert out.means2d.shape == (60, 2)
    out.rgb.sum().backward()
    grad = out.means2d.grad
    assert grad is not None and grad[out.radii > 0].abs().sum() > 0
    assert torch.all(grad[out.radii == 0] == 0)


def test_deterministic():
    scene, viewmat, K = clean_scene(150, 500)
    a = render_and_grad(rasterize, scene, viewmat, K, W, H, torch.zeros(3), torch.float32)
    b = render_and_grad(rasterize, scene, viewmat, K, W, H, torch.zeros(3), torch.float32)
    for key in a:
        assert torch.equal(a[key], b[key]), key


def test_numpy_camera_accepted():
    scene, viewmat, K = clean_scene(30, 600)
    a = rasterize(*scene, viewmat, K, W, H)
    b = rasterize(*scene, viewmat.numpy(), K.numpy(), W, H)
    assert torch.equal(a.rgb, b.rgb)
