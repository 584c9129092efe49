"""Progress of long work: a terminal progress bar, and JSON-lines events for other readers."""

from __future__ import annotations

import json
import sys
import time


class ProgressBar:
    """A one-line bar on a terminal (plain periodic lines elsewhere), with rate and ETA."""

    def __init__(self, total: int, label: str, stream=None, width: int = 30):
        self.total = max(int(total), 1)
        self.label = label
        self.stream = stream or sys.stderr
        self.width = width
        self.done = 0
        self.start = time.monotonic()
        self._last_draw = 0.0
        self._interactive = getattr(self.stream, "isatty", lambda: False)()

    def update(self, count: int = 1, note: str = "") -> None:
        self.done = min(self.done + count, self.total)
        now = time.monotonic()
        finished = self.done == self.total
        # Redraw at most 10×/s on a terminal; elsewhere a line every 10% is enough.
        if self._interactive and not finished and now - self._last_draw < 0.1:
            return
        if not self._interactive and not finished and self.done % max(self.total // 10, 1):
            return
        self._last_draw = now
        elapsed = now - self.start
        rate = self.done / elapsed if elapsed > 0 else 0.0
        eta = (self.total - self.done) / rate if rate > 0 else 0.0
        filled = int(self.width * self.done / self.total)
        bar = "#" * filled + "-" * (self.width - filled)
        text = f"{self.label} [{bar}] {self.done}/{self.total} {rate:.1f}/s ETA {eta:.0f}s {note}".rstrip()
        end = "\n" if finished or not self._interactive else ""
        self.stream.write(("\r" if self._interactive else "") + text + end)
        self.stream.flush()


def stage_bars(command: str):
    """A listener that draws one :class:`ProgressBar` per stage of ``iter`` events
    (``{"stage", "step", "steps"}``), labelled ``command (stage)``."""
    bar = {}

    def show(event: dict) -> None:
        if event["event"] != "iter":
            return
        if bar.get("stage") != event["stage"]:
            bar.update(stage=event["stage"], bar=ProgressBar(event["steps"], f"{command} ({event['stage']})"))
        bar["bar"].update(event["step"] - bar["bar"].done)

    return show


def emit_event(stream, event: str, **fields) -> None:
    """Write one JSON-lines progress event (``{"event": …, …}``) and flush it."""
    stream.write(json.dumps({"event": event, **fields}) + "\n")
    stream.flush()
