"""Progress events of a run: JSON lines in ``RUN/events.jsonl`` and to any other listener.

Every event is one object with ``"event"`` (its kind), ``"time"`` (Unix seconds) and its fields;
see docs/training.md for the kinds. A resumed run appends to the same file after a ``resume``
event, so steps after the last checkpoint may appear twice: readers keep the last line per step.
"""

from __future__ import annotations

import math
import os
import time
from typing import Callable

from ..io.atomic import open_for_append
from ..progress import emit_event

Listener = Callable[[dict], None]


def _plain(value):
    """A JSON-safe value: floats rounded to 6 significant digits, NaN/inf as None."""
    if isinstance(value, float):
        return float(f"{value:.6g}") if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value


class EventLog:
    """Appends events to a JSON-lines file and hands them to listeners (progress bar, UI)."""

    def __init__(self, path: str | os.PathLike | None, listeners: list[Listener] | None = None):
        self.path = path
        self.listeners = list(listeners or [])
        self._handle = open_for_append(path) if path is not None else None

    def emit(self, event: str, **fields) -> dict:
        record = {"event": event, "time": round(time.time(), 3), **_plain(fields)}
        if self._handle is not None:
            emit_event(self._handle, event, **{k: v for k, v in record.items() if k != "event"})
        for listener in self.listeners:
            listener(record)
        return record

    def close(self) -> None:
        if self._handle is not None:
            self._handle.close()
            self._handle = None
