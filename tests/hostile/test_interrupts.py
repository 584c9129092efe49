"""A second interrupt ends a process inside a long splat kernel, not after it."""

import os
import pathlib
import signal
import subprocess
import sys
import textwrap
import time

REPO = pathlib.Path(__file__).resolve().parents[2]

CHILD = textwrap.dedent("""
    import signal, sys
    sys.path.insert(0, {bench!r})
    from splat import head_scene
    from mogaface.core.interrupts import exit_on_second_signal
    from mogaface.core.splat import rasterize

    signal.signal(signal.SIGINT, lambda number, frame: print("handler", flush=True))  # the trainer's first stop
    assert exit_on_second_signal()
    small, view, K = head_scene(100, 32, 32)
    rasterize(*small, view, K, 32, 32)  # kernels loaded
    scene, view, K = head_scene(300_000, 4096, 4096)  # several seconds of compositing
    print("kernel start", flush=True)
    rasterize(*scene, view, K, 4096, 4096)
    print("kernel end", flush=True)
""")


def test_second_sigint_exits_while_the_kernel_runs():
    child = subprocess.Popen([sys.executable, "-c", CHILD.format(bench=str(REPO / "bench"))], cwd=REPO,
                             stdout=subprocess.PIPE, text=True, env={**os.environ, "OMP_WAIT_POLICY": "PASSIVE"})
    try:
        assert child.stdout.readline().strip() == "kernel start"
        time.sleep(1.0)  # into the kernel
        child.send_signal(signal.SIGINT)
        time.sleep(0.3)  # two signals sent together may arrive as one
        child.send_signal(signal.SIGINT)
        code = child.wait(timeout=120)  # a harness against a hang, not a timing
    finally:
        child.kill()
    rest = child.stdout.read()
    assert code == 128 + signal.SIGINT
    assert "kernel end" not in rest  # it left inside the kernel, without waiting for it
