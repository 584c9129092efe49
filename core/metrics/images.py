"""Image metrics of the evaluation protocol: PSNR, SSIM and LPIPS (AlexNet).

Images are float sRGB in [0, 1], ``(H, W, 3)`` (or ``(H, W)`` grey), numpy arrays or
torch tensors. An optional mask ``(H, W)`` (bool or weights in [0, 1]) restricts a metric
to the foreground: PSNR and SSIM average only over masked pixels, LPIPS compares both
images composited onto black by the mask (its features see the whole image, so it cannot
skip pixels; outside the mask both inputs are then equal).
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError

SSIM_SIGMA = 1.5
SSIM_TRUNCATE = 3.5  # scikit-image's Gaussian window: radius int(3.5 * 1.5 + 0.5) = 5, 11 x 11
_RANGE_TOLERANCE = 1e-4
LPIPS_MIN_SIZE = 32  # smaller images vanish before AlexNet's last pooling


def _as_array(value, field: str) -> np.ndarray:
    if hasattr(value, "detach"):  # a torch tensor
        value = value.detach().cpu().numpy()
    array = np.asarray(value)
    if not np.issubdtype(array.dtype, np.floating) and array.dtype != bool:
        raise InputError(None, field, f"expected float values in [0, 1], found dtype {array.dtype}")
    return array.astype(np.float64)


def _checked(pred, target, mask):
    """Validate a pred/target (and mask) triple; return float64 arrays, the mask ``(H, W)`` or None."""
    pred, target = _as_array(pred, "pred"), _as_array(target, "target")
    if pred.ndim not in (2, 3) or pred.shape != target.shape:
        raise InputError(None, "pred", f"expected (H, W) or (H, W, C) images of one shape, found {pred.shape} and {target.shape}")
    for name, image in (("pred", pred), ("target", target)):
        if not np.all(np.isfinite(image)):
            raise InputError(None, name, "contains NaN or infinite values")
        if image.size and (image.min() < -_RANGE_TOLERANCE or image.max() > 1 + _RANGE_TOLERANCE):
            raise InputError(None, name, f"values must lie in [0, 1], found [{image.min():.4g}, {image.max():.4g}]")
    if mask is None:
        return pred, target, None
    mask = _as_array(mask, "mask")
    if mask.ndim == 3 and mask.shape[2] == 1:
        mask = mask[..., 0]
    if mask.shape != pred.shape[:2]:
        raise InputError(None, "mask", f"expected shape {pred.shape[:2]}, found {mask.shape}")
    if not np.all(np.isfinite(mask)) or mask.min() < 0 or mask.max() > 1:
        raise InputError(None, "mask", "values must lie in [0, 1]")
    if mask.sum() <= 0:
        raise InputError(None, "mask", "is empty: no pixel to score")
    return pred, target, mask


def psnr(pred, target, mask=None) -> float:
    """Peak signal-to-noise ratio in dB for data range 1; ``inf`` for identical images."""
    pred, target, mask = _checked(pred, target, mask)
    squared = (pred - target) ** 2
    if mask is None:
        mse = squared.mean()
    else:
        channels = 1 if squared.ndim == 2 else squared.shape[2]
        weights = mask if squared.ndim == 2 else mask[..., None]
        mse = (squared * weights).sum() / (mask.sum() * channels)
    return float("inf") if mse == 0 else float(10.0 * np.log10(1.0 / mse))


def ssim(pred, target, mask=None) -> float:
    """Mean SSIM (Gaussian window sigma 1.5, population covariances, data range 1).

    Without a mask this is scikit-image's ``structural_similarity`` value; with one, the
    same SSIM map averaged over the masked pixels of the same border-cropped area.
    """
    from skimage.metrics import structural_similarity

    pred, target, mask = _checked(pred, target, mask)
    radius = int(SSIM_TRUNCATE * SSIM_SIGMA + 0.5)
    if min(pred.shape[:2]) < 2 * radius + 1:
        raise InputError(None, "pred", f"SSIM needs images of at least {2 * radius + 1} x {2 * radius + 1} pixels")
    value, ssim_map = structural_similarity(
        pred,
        target,
        gaussian_weights=True,
        sigma=SSIM_SIGMA,
        use_sample_covariance=False,
        data_range=1.0,
        channel_axis=-1 if pred.ndim == 3 else None,
        full=True,
    )
    if mask is None:
        return float(value)
    inner = (slice(radius, -radius), slice(radius, -radius))
    weights = mask[inner]
    if weights.sum() <= 0:
        raise InputError(None, "mask", f"covers only the {radius}-pixel border that SSIM leaves out")
    cropped = ssim_map[inner]
    if cropped.ndim == 3:
        return float((cropped * weights[..., None]).sum() / (weights.sum() * cropped.shape[2]))
    return float((cropped * weights).sum() / weights.sum())


def lpips(pred, target, mask=None) -> float:
    """LPIPS v0.1 (AlexNet) distance; 0 for identical images. Needs the weights (see ``lpips_weights``)."""
    import torch

    from .lpips_alex import load_lpips_alex

    pred, target, mask = _checked(pred, target, mask)
    if pred.ndim == 2:
        pred, target = np.repeat(pred[..., None], 3, axis=2), np.repeat(target[..., None], 3, axis=2)
    if pred.shape[2] != 3:
        raise InputError(None, "pred", f"LPIPS needs RGB (or grey) images, found {pred.shape[2]} channels")
    if min(pred.shape[:2]) < LPIPS_MIN_SIZE:
        raise InputError(None, "pred", f"LPIPS needs images of at least {LPIPS_MIN_SIZE} x {LPIPS_MIN_SIZE} pixels")
    if mask is not None:
        pred, target = pred * mask[..., None], target * mask[..., None]
    model = load_lpips_alex()

    def batch(image):
        return torch.from_numpy(np.ascontiguousarray(image.transpose(2, 0, 1), dtype=np.float32))[None]

    with torch.no_grad():
        return float(model(batch(pred), batch(target))[0])


def compute_metrics(pred, target, mask=None) -> dict[str, float]:
    """All three metrics of one image pair: ``{"psnr": dB, "ssim": ..., "lpips": ...}``."""
    return {"psnr": psnr(pred, target, mask), "ssim": ssim(pred, target, mask), "lpips": lpips(pred, target, mask)}
