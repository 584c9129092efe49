"""SIGTERM while a command is leaving (its output written, the interpreter exiting) still ends with
``terminated by SIGTERM`` and status 143, or finds the process gone with the command's own status:
never a silent death by the signal (-15).

The interpreter's own exit sets the signals back to the system's default before it tears the modules
down (torch's and numba's took tenths of a second). The child stands for that tear-down with an
object whose ``__del__`` sleeps, and marks the end of the exit work that runs (``atexit``) with a line.
It runs ``check-capture`` on a folder that is not there (an error, status 2) with the imports of torch
and numba skipped: what is probed is the ending every command goes through, cheaply.
"""

import signal
import subprocess
import sys
import textwrap
import time

CHILD = textwrap.dedent("""
    import atexit
    import runpy
    import sys
    import time

    class TearDown:  # stands for torch's and numba's tear-down when the interpreter exits
        def __del__(self):
            time.sleep(10)

    tear_down = TearDown()

    def last_exit_work():
        print("exiting", flush=True)
        time.sleep(0.2)

    atexit.register(last_exit_work)  # registered first, so it runs last of the atexit work
    import mogaface.core.cli
    mogaface.core.cli._load_heavy_modules_uninterrupted = lambda: False
    sys.argv = ["mogaface", *sys.argv[1:]]
    runpy.run_module("mogaface", run_name="__main__", alter_sys=True)
""")


def _sigterm_at_the_end(argv, delay, tmp_path):
    """Run ``python -m mogaface ARGV`` through the child; SIGTERM ``delay`` s after its exit began."""
    child = subprocess.Popen([sys.executable, "-c", CHILD, *argv], cwd=tmp_path, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    try:
        for line in child.stdout:
            if line.strip() == "exiting":
                break
        time.sleep(delay)
        child.send_signal(signal.SIGTERM)
        err = child.communicate(timeout=60)[1]  # a harness against a hang, not a timing
    finally:
        if child.poll() is None:
            child.kill()
    return child.returncode, err


def test_sigterm_while_leaving_says_so_or_finds_the_process_gone(tmp_path):
    for delay in (0.05, 0.3, 0.5):  # inside the last atexit work, then after it
        code, err = _sigterm_at_the_end(["check-capture", str(tmp_path / "missing")], delay, tmp_path)
        assert "missing: not a folder" in err and "Traceback" not in err, err
        assert code in (2, 128 + signal.SIGTERM), (delay, code, err)
        assert ("terminated by SIGTERM" in err) == (code == 128 + signal.SIGTERM), (delay, err)
        if delay < 0.2:  # the handler answers inside the exit work too
            assert code == 128 + signal.SIGTERM, (delay, err)
