"""A second interrupt ends the process at once, even while a compiled kernel runs.

Python runs signal handlers only between bytecodes, so a handler cannot act while the main thread
is inside a numba kernel. The interpreter's C-level handler does write each signal's number to
the wake-up fd at once; a daemon thread waits on it and, at the second SIGINT/SIGTERM, exits with
status 128 + the signal number. It can run then because the long kernels (the splat compositing)
release the GIL. Every file the project writes is written under a temporary name and renamed, so
leaving this way half-writes nothing; the next run removes leftover temporary files.
"""

from __future__ import annotations

import os
import signal
import threading

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def exit_on_second_signal() -> bool:
    """Start the watcher (main thread only; once per process). False where it cannot be started."""
    if threading.current_thread() is not threading.main_thread() or getattr(exit_on_second_signal, "started", False):
        return False
    read_end, write_end = os.pipe()
    os.set_blocking(write_end, False)
    try:
        signal.set_wakeup_fd(write_end, warn_on_full_buffer=False)
    except ValueError:
        os.close(read_end)
        os.close(write_end)
        return False

    def watch():
        seen = 0
        while True:
            for number in os.read(read_end, 64):
                if number in STOP_SIGNALS:
                    seen += 1
                    if seen >= 2:
                        os._exit(128 + number)

    threading.Thread(target=watch, name="second-interrupt", daemon=True).start()
    exit_on_second_signal.started = True
    return True
