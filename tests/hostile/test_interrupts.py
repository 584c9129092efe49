"""A second interrupt ends a process at once, also inside a compiled pass that does not read the
cancel flag (the first one only stops the raster kernels, which do)."""

import os
import pathlib
import signal
import subprocess
import sys
import textwrap
import time

REPO = pathlib.Path(__file__).resolve().parents[2]

CHILD = textwrap.dedent("""
    import signal
    import numba
    from mogaface.core.splat import cancel

    @numba.njit(nogil=True)
    def busy(n):  # a long pass that never looks at the flag, like projection or binning at the limits
        total = 0.0
        for i in range(n):
            total += (i % 7) * 1e-9
        return total

    busy(10)
    signal.signal(signal.SIGINT, lambda number, frame: print("handler", flush=True))  # the trainer's first stop
    cancel.arm((signal.SIGINT,))
    print("kernel start", flush=True)
    busy(10 ** 11)
    print("kernel end", flush=True)
""")


def test_second_sigint_exits_inside_a_kernel_that_ignores_the_flag():
    child = subprocess.Popen([sys.executable, "-c", CHILD], cwd=REPO, stdout=subprocess.PIPE, text=True,
                             env={**os.environ, "OMP_WAIT_POLICY": "PASSIVE"})
    try:
        assert child.stdout.readline().strip() == "kernel start"
        time.sleep(0.5)  # into the kernel
        child.send_signal(signal.SIGINT)
        time.sleep(0.3)  # two signals sent together may arrive as one
        child.send_signal(signal.SIGINT)
        code = child.wait(timeout=120)  # a harness against a hang, not a timing
    finally:
        child.kill()
    rest = child.stdout.read()
    assert code == 128 + signal.SIGINT
    assert "kernel end" not in rest and "handler" not in rest  # it left inside the kernel
