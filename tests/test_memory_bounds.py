"""What training keeps in memory does not grow with the capture's length (lazy, bounded caches)."""

import types

import numpy as np
import torch

from mogaface.core.mogaface.views import ViewImages


class CountingCapture:
    """Stands in for a capture: numbered frames whose images are drawn from their number."""

    def __init__(self):
        self.loads = 0

    def load_image(self, frame):
        self.loads += 1
        rng = np.random.default_rng(int(frame.file_path))
        return rng.random((16, 16, 3), dtype=np.float32), np.ones((16, 16), np.float32)


def test_encoder_views_are_cached_up_to_a_byte_bound():
    capture = CountingCapture()
    views = ViewImages(capture, size=8, max_bytes=5 * 3 * 8 * 8)
    frames = [types.SimpleNamespace(file_path=str(i)) for i in range(40)]
    first = [views.batch([f]) for f in frames]
    assert len(views._cache) == 5 and capture.loads == 40  # a long capture fills only the bound
    again = [views.batch([f]) for f in frames]
    assert capture.loads == 40 + 35  # the 5 cached views are not decoded twice, the rest are
    assert all(torch.equal(a, b) for a, b in zip(first, again))  # and look the same either way
