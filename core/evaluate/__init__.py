"""Evaluation: image metrics (PSNR, SSIM, LPIPS) and the evaluation protocols."""

from .metrics import compute_metrics, lpips, psnr, ssim

__all__ = ["compute_metrics", "lpips", "psnr", "ssim"]
