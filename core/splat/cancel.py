"""Cancellation that reaches into a running raster kernel.

A Python signal handler runs only between bytecodes, so while the main thread is inside one
numba kernel (seconds at the image and Gaussian limits) SIGINT/SIGTERM would wait for it. Once
:func:`arm` has run, the interpreter's C-level handler also writes the signal number to a pipe
(``signal.set_wakeup_fd``); a watcher thread reads it and sets :data:`FLAG`, which the raster
kernels (``nogil``, so the watcher can run) poll once per tile: the tiles not yet started are
skipped, and the caller raises :class:`RenderCancelled` instead of using the partial image. A
second signal ends the process at once, also inside a pass that does not poll the flag.
Nothing in the process uses the flag unless :func:`arm` was called (the training command does).
"""

from __future__ import annotations

import os
import signal
import threading

import numpy as np

FLAG = np.zeros(1, np.int32)  # set (non-zero) to make the raster kernels skip their remaining tiles
_armed: set[int] = set()


class RenderCancelled(Exception):
    """A render stopped part-way because the process was asked to stop; its image is incomplete."""


def raise_if_requested() -> None:
    if FLAG[0]:
        raise RenderCancelled("render cancelled by a signal")


def arm(signals=(signal.SIGINT, signal.SIGTERM)) -> None:
    """Let ``signals`` (which must have Python handlers) cancel a running kernel. Main thread only."""
    if _armed:
        return
    read_end, write_end = os.pipe()
    os.set_blocking(write_end, False)
    signal.set_wakeup_fd(write_end, warn_on_full_buffer=False)
    _armed.update(int(s) for s in signals)
    threading.Thread(target=_watch, args=(read_end,), name="mogaface-cancel", daemon=True).start()


def _watch(read_end: int) -> None:
    """The first signal stops the running render; the second ends the process at once, wherever
    it is (files are written under temporary names and renamed, so nothing is half-written)."""
    seen = 0
    while True:
        data = os.read(read_end, 64)
        if not data:
            return
        for number in data:
            if number in _armed:
                seen += 1
                FLAG[0] = 1
                if seen >= 2:
                    os._exit(128 + number)
