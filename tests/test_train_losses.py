"""Training losses: SSIM against scikit-image, the hinges, the image loss mix."""

import numpy as np
import pytest
import torch
from skimage.metrics import structural_similarity

from mogaface.core.train import losses


@pytest.mark.parametrize("shape", [(32, 40, 3), (24, 24)])
def test_ssim_matches_skimage(shape):
    rng = np.random.default_rng(0)
    a = rng.random(shape)
    b = np.clip(a + rng.normal(scale=0.2, size=shape), 0, 1)
    expected = structural_similarity(a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
                                     data_range=1.0, channel_axis=-1 if len(shape) == 3 else None)
    got = losses.ssim(torch.tensor(a, dtype=torch.float32), torch.tensor(b, dtype=torch.float32))
    assert abs(float(got) - expected) < 1e-4


def test_ssim_of_identical_images_is_one_and_differentiable():
    a = torch.rand(20, 20, 3)
    assert float(losses.ssim(a, a)) == pytest.approx(1.0, abs=1e-5)
    pred = torch.rand(20, 20, 3, requires_grad=True)
    (1 - losses.ssim(pred, a)).backward()
    assert torch.isfinite(pred.grad).all() and pred.grad.abs().sum() > 0


@pytest.mark.parametrize("shape", [(32, 40, 3), (24, 24), (11, 30, 3)])
def test_ssim_kernels_match_the_torch_ssim_and_its_gradient(shape):
    generator = torch.Generator().manual_seed(0)
    pred = torch.rand(shape, generator=generator, requires_grad=True)
    target = (pred.detach() + 0.2 * torch.randn(shape, generator=generator)).clamp(0, 1)
    fast, reference = losses.ssim(pred, target), losses.ssim_torch(pred, target)
    assert float(fast.detach()) == pytest.approx(float(reference.detach()), abs=2e-6)
    (g_fast,) = torch.autograd.grad(3 * fast, pred)
    (g_reference,) = torch.autograd.grad(3 * reference, pred)
    assert g_fast.shape == pred.shape
    assert (g_fast - g_reference).abs().max() <= 1e-5 * g_reference.abs().max()


def test_ssim_outside_the_kernels_is_the_torch_ssim():
    a, b = torch.rand(16, 16, 3, dtype=torch.float64), torch.rand(16, 16, 3, dtype=torch.float64)
    assert float(losses.ssim(a, b)) == float(losses.ssim_torch(a, b))
    b32 = b.float().requires_grad_()  # a differentiable target
    losses.ssim(a.float(), b32).backward()
    assert b32.grad is not None and b32.grad.abs().sum() > 0


def test_position_hinge_values():
    local = torch.tensor([[0.5, 0.0, 0.0], [3.0, 4.0, 0.0], [0.0, 0.0, -2.0]])
    # norms 0.5, 5, 2 -> relu(norm - 1) = 0, 4, 1
    assert float(losses.position_hinge(local, 1.0)) == pytest.approx(5 / 3)
    assert float(losses.position_hinge(local[:0], 1.0)) == 0.0


def test_scaling_hinge_values():
    log_scale = torch.log(torch.tensor([[0.5, 0.5, 0.5], [1.6, 0.6, 0.1], [0.6, 3.6, 4.6]]))
    # rows: (0,0,0) -> 0; (1,0,0) -> 1; (0,3,4) -> 5
    assert float(losses.scaling_hinge(log_scale, 0.6)) == pytest.approx(2.0, abs=1e-5)


def test_hinges_over_a_mask_equal_the_hinges_of_the_masked_rows():
    g = torch.Generator().manual_seed(3)
    local = torch.randn(50, 3, generator=g).mul(1.5).requires_grad_()
    log_scale = torch.randn(50, 3, generator=g).requires_grad_()
    mask = torch.rand(50, generator=g) > 0.4
    for hinge, x, t in ((losses.position_hinge, local, 1.0), (losses.scaling_hinge, log_scale, 0.6)):
        masked = hinge(x, t, mask)
        gathered = hinge(x[mask], t)
        assert masked.item() > 0 and masked.item() == pytest.approx(gathered.item(), rel=1e-6)
        a, = torch.autograd.grad(masked, x)
        b, = torch.autograd.grad(gathered, x)
        assert torch.allclose(a, b, atol=1e-7) and not a[~mask].any()
        assert hinge(x, t, torch.zeros(50, dtype=torch.bool)).item() == 0.0


def test_image_loss_mix():
    pred, target = torch.rand(16, 16, 3), torch.rand(16, 16, 3)
    parts = losses.image_loss(pred, target, 0.2)
    expected = 0.8 * (pred - target).abs().mean() + 0.2 * (1 - losses.ssim(pred, target))
    assert float(parts["rgb"]) == pytest.approx(float(expected), rel=1e-6)
