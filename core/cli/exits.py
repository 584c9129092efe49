"""How the command line ends on a signal that no command handles: one line saying so and the
status 128 + the signal's number (130 for SIGINT, 143 for SIGTERM), never a silent death.

``python -m mogaface`` arms SIGTERM on its first line (``__main__``: nothing is written yet, so it
leaves at once); :func:`mogaface.core.cli.main` then turns it into :class:`Terminated`, which
unwinds like an interrupt (temporary files of atomic writes are removed on the way). Commands that
stop gracefully (``train``: finish the step, write a checkpoint) install their own handlers.
"""

from __future__ import annotations

import signal
import threading


class Terminated(BaseException):
    """SIGTERM (or another ending signal) reached the command line."""

    def __init__(self, number: int):
        super().__init__(number)
        self.number = number


def ending_line(number: int) -> str:
    return "interrupted" if number == signal.SIGINT else f"terminated by {signal.Signals(number).name}"


def _raise_terminated(number, frame):
    raise Terminated(number)


def raise_on_sigterm():
    """Make SIGTERM raise :class:`Terminated` (main thread only); returns what to give to :func:`restore`."""
    if threading.current_thread() is not threading.main_thread():
        return None
    return signal.signal(signal.SIGTERM, _raise_terminated)


def restore(previous) -> None:
    if previous is not None and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, previous)
