"""Rendering a range of frames without freezing Blender: requests on the main thread, renders in a thread.

Reading a frame's values needs ``scene.frame_set`` (main thread only); the render itself is
pure core work, so it runs in a worker thread while Blender keeps drawing. :class:`RenderJob`
is stepped by its caller: from a modal operator's timer in the UI, in a blocking loop in
background mode (timers never run there). The same ``step`` serves both.
"""

from __future__ import annotations

import concurrent.futures
import time

_executor: concurrent.futures.ThreadPoolExecutor | None = None


def executor() -> concurrent.futures.ThreadPoolExecutor:
    """The one thread that renders for jobs (created when first needed)."""
    global _executor
    if _executor is None:
        _executor = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="mogaface-render")
    return _executor


class RenderJob:
    """Render ``frames`` one after another.

    ``make_request(frame)`` builds a core :class:`RenderRequest` (main thread); ``on_result(result)``
    stores a finished render (main thread). ``error`` holds the message of a render that failed.
    """

    def __init__(self, frames, make_request, on_result, render=None):
        from ..core.scene_render import render as core_render

        self.frames = list(frames)
        self.done = 0
        self.error: str | None = None
        self.cancelled = False
        self._make_request = make_request
        self._on_result = on_result
        self._render = render or core_render
        self._future = None

    @property
    def fraction(self) -> float:
        return self.done / len(self.frames) if self.frames else 1.0

    @property
    def finished(self) -> bool:
        return self._future is None and (self.cancelled or self.error is not None or self.done == len(self.frames))

    def text(self) -> str:
        return f"frame {self.done}/{len(self.frames)}"

    def cancel(self) -> None:
        """Stop after the frame being rendered (its result is dropped)."""
        self.cancelled = True

    def step(self) -> bool:
        """Collect a finished render and start the next; True while the job is not finished."""
        from ..core.errors import MogafaceError

        if self._future is not None and self._future.done():
            future, self._future = self._future, None
            try:
                result = future.result()
            except (MogafaceError, OSError) as error:
                self.error = str(error)
            else:
                if not self.cancelled:
                    self._on_result(result)
                    self.done += 1
        if self._future is None and not self.finished:
            try:
                request = self._make_request(self.frames[self.done])
            except (MogafaceError, OSError) as error:
                self.error = str(error)
            else:
                self._future = executor().submit(self._render, request)
        return not self.finished

    def run(self, interval: float = 0.005, on_progress=None) -> "RenderJob":
        """Step until finished (background mode)."""
        while self.step():
            if on_progress is not None:
                on_progress(self)
            time.sleep(interval)
        return self
