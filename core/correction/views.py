"""Downsampled view images for the encoder, cached apart from the capture's full-size images.

The capture's byte-bounded cache holds full frames for the loss; the encoder needs only small
copies, kept here as uint8 ``(3, S, S)`` arrays (48 KiB each at 128²): in memory up to
``max_bytes`` (128 MiB: 2730 views, every training image of a default capture), then in an
unnamed temporary file up to ``spill_bytes`` (1 GiB, and never more than half the temporary
folder's free space). Memory stays flat however long the capture is, and a view is decoded once
per run, not once per use (about 10 ms for a full frame at 802×550: 80 ms for a step's eight
views). Beyond both bounds views are decoded each time.
"""

from __future__ import annotations

import os
import shutil
import tempfile

import numpy as np
import torch
import torch.nn.functional as F


class ViewImages:
    """``frames → (B, 3, S, S)`` float tensors in [0, 1] for the encoder."""

    def __init__(self, capture, size: int = 128, max_bytes: int = 128 * 1024 * 1024,
                 spill_bytes: int = 1024 * 1024 * 1024):
        self.capture = capture
        self.size = size
        self.view_bytes = 3 * size * size
        self.max_items = max_bytes // self.view_bytes
        self.max_spilled = spill_bytes // self.view_bytes
        self._cache: dict[tuple, np.ndarray] = {}
        self._spilled: dict[tuple, int] = {}  # key -> slot in the spill file
        self._spill = None

    def _decode(self, frame) -> np.ndarray:
        rgb = self.capture.load_rgb(frame)
        image = torch.from_numpy(np.array(rgb, dtype=np.float32)).permute(2, 0, 1)[None]
        if image.shape[-1] != self.size or image.shape[-2] != self.size:
            image = F.interpolate(image, size=(self.size, self.size), mode="area")
        return (image[0].clamp(0, 1) * 255.0 + 0.5).to(torch.uint8).numpy()

    def _load(self, frame) -> np.ndarray:
        key = (frame.file_path, self.size)
        hit = self._cache.get(key)
        if hit is not None:
            return hit
        slot = self._spilled.get(key)
        if slot is not None:
            data = os.pread(self._spill.fileno(), self.view_bytes, slot * self.view_bytes)
            return np.frombuffer(data, np.uint8).reshape(3, self.size, self.size)
        small = self._decode(frame)
        if len(self._cache) < self.max_items:
            self._cache[key] = small
        elif len(self._spilled) < self.max_spilled:
            self._store(key, small)
        return small

    def _store(self, key, small: np.ndarray) -> None:
        """Append a view to the spill file; a full disk leaves it uncached (decoded again when next
        used), never half-stored."""
        slot = len(self._spilled)
        try:
            if self._spill is None:
                free = shutil.disk_usage(tempfile.gettempdir()).free
                self.max_spilled = min(self.max_spilled, free // 2 // self.view_bytes)
                if slot >= self.max_spilled:
                    return
                self._spill = tempfile.TemporaryFile(prefix="mogaface-views-")
            written = os.pwrite(self._spill.fileno(), small.tobytes(), slot * self.view_bytes)
        except OSError:
            return
        if written == self.view_bytes:
            self._spilled[key] = slot

    def batch(self, frames) -> torch.Tensor:
        return torch.from_numpy(np.stack([self._load(f) for f in frames])).float() / 255.0

    def close(self) -> None:
        """Drop the spill file (also dropped when the object is collected or the process exits)."""
        if self._spill is not None:
            self._spill.close()
            self._spill = None
            self._spilled.clear()
