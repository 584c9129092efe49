"""Downsampled view images for the encoder, cached apart from the capture's full-size images.

The capture's byte-bounded cache holds full frames for the loss; the encoder needs only small
copies, kept here as uint8 ``(3, S, S)`` tensors (48 KiB each at 128²), up to ``max_bytes`` (128 MiB:
every training image of a default capture, 2400 views), so memory stays flat however long the
capture is; beyond the bound views are decoded each time.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F


class ViewImages:
    """``frames → (B, 3, S, S)`` float tensors in [0, 1] for the encoder."""

    def __init__(self, capture, size: int = 128, max_bytes: int = 128 * 1024 * 1024):
        self.capture = capture
        self.size = size
        self.max_items = max_bytes // (3 * size * size)
        self._cache: dict[tuple, torch.Tensor] = {}

    def _load(self, frame) -> torch.Tensor:
        key = (frame.file_path, self.size)
        hit = self._cache.get(key)
        if hit is not None:
            return hit
        rgb, _ = self.capture.load_image(frame)
        image = torch.from_numpy(np.array(rgb, dtype=np.float32)).permute(2, 0, 1)[None]
        if image.shape[-1] != self.size or image.shape[-2] != self.size:
            image = F.interpolate(image, size=(self.size, self.size), mode="area")
        small = (image[0].clamp(0, 1) * 255.0 + 0.5).to(torch.uint8)
        if len(self._cache) < self.max_items:
            self._cache[key] = small
        return small

    def batch(self, frames) -> torch.Tensor:
        return torch.stack([self._load(f) for f in frames]).float() / 255.0
