"""How the command line ends on a signal that no command handles: one line saying so and the
status 128 + the signal's number (130 for SIGINT, 143 for SIGTERM), never a silent death.

``python -m mogaface`` arms SIGTERM on its first line (``__main__``: nothing is written yet, so it
leaves at once); :func:`mogaface.core.cli.main` then turns it into :class:`Terminated`, which
unwinds like an interrupt (temporary files of atomic writes are removed on the way). Commands that
stop gracefully (``train``: finish the step, write a checkpoint) install their own handlers.
When the command has returned, :func:`leave` ends the process with the handlers still in place.
"""

from __future__ import annotations

import atexit
import os
import signal
import sys
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


def _leave_at_once(number, frame):  # the command is done and its files are written: say so and go
    os.write(2, f"{ending_line(number)}\n".encode())
    os._exit(128 + number)


def leave(code: int):
    """End the process with ``code`` once the command has returned, a signal still answered as at
    any other moment (``terminated by SIGTERM``, status 143; SIGINT 130).

    The interpreter's own exit sets every signal back to the system's default before it tears the
    modules down (torch's and numba's take tenths of a second), and a SIGTERM then killed the
    process without a word (status -15). So this does what that exit does first (waits for
    threads, runs ``atexit``, flushes the output) and leaves without the tear-down: every file is
    written atomically and closed by now.
    """
    if threading.current_thread() is threading.main_thread():
        for number in (signal.SIGINT, signal.SIGTERM):
            signal.signal(number, _leave_at_once)
    shutdown = getattr(threading, "_shutdown", None)  # what the interpreter's exit calls: joins threads
    if shutdown is not None:
        shutdown()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            if stream is not None:
                stream.flush()
        except (OSError, ValueError):  # a closed pipe: the interpreter's exit would say 120 too
            code = code or 120
    os._exit(code)
