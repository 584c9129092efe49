"""A tracked frame's image (on white, through the person's mask) and mask, written at the capture's
size in a background thread, so the next frame is decoded and detected meanwhile.

At 720×1280 the compositing, the box-filter shrink and the two PNGs cost about as much as the face
models (20–45 ms a frame here); they release the GIL, so in the thread they overlap the next frame.
The values are those :func:`on_white` and :func:`shrunk` define; the PNGs are written with a fast
zlib level (lossless: the same pixels, slightly larger files).
"""

from __future__ import annotations

import collections
import concurrent.futures
import pathlib

import numpy as np

from ..data import layout
from ..io.image import write_png

PNG_LEVEL = 1  # zlib's fastest: about 40 % less time than the default 4, for 5-15 % more bytes
QUEUED = 2  # frames given and not yet written, at most (each holds its full-size frame and mask)
_ROWS = 128  # rows composited at a time: the float buffers stay in the cache


def on_white(rgb: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The frame composited on the capture's background (white) through the person's mask: a
    capture's images are stored so (VHAP's exports, the synthetic captures), and training takes
    them as they are; the wall behind the subject would otherwise be learnt as part of the head.

    ``uint8(rgb·α + 255·(1 − α) + 0.5)`` in float32, one channel and a band of rows at a time
    (broadcasting α over a length-3 axis was most of the cost; the values are the same)."""
    alpha = np.clip(mask, 0.0, 1.0)
    out = np.empty(rgb.shape[:2] + (3,), np.uint8)
    value = np.empty((_ROWS, rgb.shape[1]), np.float32)
    white = np.empty((_ROWS, rgb.shape[1]), np.float32)
    for top in range(0, rgb.shape[0], _ROWS):
        band = alpha[top:top + _ROWS]
        rows = len(band)
        np.subtract(np.float32(1.0), band, out=white[:rows])
        white[:rows] *= np.float32(255.0)
        for channel in range(3):
            np.multiply(rgb[top:top + rows, :, channel], band, out=value[:rows])
            value[:rows] += white[:rows]
            value[:rows] += np.float32(0.5)
            out[top:top + rows, :, channel] = value[:rows]  # truncation, as astype(uint8)
    return out


def shrunk(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``image`` (uint8) at ``size`` (width, height), by area averaging (PIL's box filter)."""
    if image.shape[1::-1] == tuple(size):
        return image
    from PIL import Image

    return np.asarray(Image.fromarray(image).resize(size, Image.Resampling.BOX))


def write_frame(out: pathlib.Path, rgb: np.ndarray, mask: np.ndarray, size, position: int, camera: int) -> None:
    """Timestep ``position`` of ``camera``: its image and mask, at ``size`` (width, height)."""
    write_png(out / layout.image_path(position, camera), shrunk(on_white(rgb, mask), size), compress_level=PNG_LEVEL)
    write_png(out / layout.mask_path(position, camera), shrunk((mask * 255 + 0.5).astype(np.uint8), size),
              compress_level=PNG_LEVEL)


class FrameWriter:
    """:func:`write_frame` in one background thread. :meth:`flush` waits for every frame given so far
    (and raises a write's error); leaving the ``with`` block flushes, or on an error lets the frame
    being written finish and drops those still waiting (their detections are not saved either)."""

    def __init__(self, out: pathlib.Path):
        self.out = pathlib.Path(out)
        self._pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="track-write")
        self._pending: collections.deque = collections.deque()

    def add(self, rgb: np.ndarray, mask: np.ndarray, size, position: int, camera: int) -> None:
        self._pending.append(self._pool.submit(write_frame, self.out, rgb, mask, size, position, camera))
        while len(self._pending) > QUEUED:
            self._pending.popleft().result()

    def flush(self) -> None:
        while self._pending:
            self._pending.popleft().result()

    def __enter__(self) -> "FrameWriter":
        return self

    def __exit__(self, kind, error, trace) -> None:
        try:
            if kind is None:
                self.flush()
        finally:
            self._pool.shutdown(wait=True, cancel_futures=True)
