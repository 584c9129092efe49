"""Image metrics (PSNR, SSIM, LPIPS): below both training (its end-of-run check) and evaluation.

The metrics are imported on first use (they need torch), so the command line can name the
protocols without loading torch (``python -m mogaface eval --help``).
"""

__all__ = ["compute_metrics", "lpips", "psnr", "ssim"]


def __getattr__(name):
    if name in __all__:
        from . import images

        return getattr(images, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
