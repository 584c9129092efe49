"""Gradients against finite differences: the float64 reference, and the float32 engine itself."""

import torch

from mogaface.core.splat import rasterize
from mogaface.core.splat.reference import closest_to_threshold, look_at_camera, random_scene, rasterize_reference


def clean(n, width, height, margin, seed=0, **kw):
    viewmat, K = look_at_camera(width, height)
    for s in range(seed, seed + 200):
        scene = random_scene(n, s, depth=1.2, scale=0.1, **kw)
        if closest_to_threshold(*scene[:4], viewmat, K, width, height) > margin:
            return scene, viewmat, K
    raise AssertionError("no clean scene found")


def test_reference_gradients_match_finite_differences():
    width, height = 10, 8
    scene, viewmat, K = clean(6, width, height, 1e-3, sh_degree=1, spread=0.15)
    params = [p.double().requires_grad_(True) for p in scene]
    bg = torch.tensor([0.3, 0.1, 0.7], dtype=torch.float64, requires_grad=True)

    def fn(*args):
        out = rasterize_reference(*args[:5], viewmat, K, width, height, args[5])
        return out["rgb"], out["alpha"], out["depth"]

    assert fn(*params, bg)[1].max() > 0.5
    assert torch.autograd.gradcheck(fn, (*params, bg), eps=1e-6, atol=1e-6, rtol=1e-4,
                                    fast_mode=True)


def test_engine_gradients_match_finite_differences():
    width, height = 20, 14
    scene, viewmat, K = clean(15, width, height, 3e-3, seed=100, spread=0.2)
    g = torch.Generator().manual_seed(3)
    weights = [torch.randn(height, width, 3, generator=g), torch.randn(height, width, generator=g),
               torch.randn(height, width, generator=g)]

    def loss(*args):
        out = rasterize(*args, viewmat, K, width, height, torch.tensor([0.2, 0.4, 0.6]))
        return sum((o.double() * w.double()).sum() for o, w in zip((out.rgb, out.alpha, out.depth), weights))

    params = [p.clone().requires_grad_(True) for p in scene]
    loss(*params).backward()
    steps = {0: 1e-3, 1: 2e-3, 2: 1e-3, 3: 2e-3, 4: 2e-3}  # per parameter group
    checked = 0
    for i, step in steps.items():
        for trial in range(2):
            direction = torch.randn(scene[i].shape, generator=g)
            direction /= direction.norm()
            plus = [p.clone() for p in scene]
            minus = [p.clone() for p in scene]
            plus[i] = scene[i] + step * direction
            minus[i] = scene[i] - step * direction
            with torch.no_grad():
                numeric = (loss(*plus) - loss(*minus)) / (2 * step)
            analytic = (params[i].grad.double() * direction.double()).sum()
            assert abs(numeric - analytic) <= 2e-2 * abs(analytic) + 1e-3, (i, trial, numeric, analytic)
            checked += abs(analytic) > 1e-2
    assert checked >= 8  # the directions were not all trivially flat
