"""How long SIGINT takes to stop work that is inside a raster kernel.

Two measurements, each in child processes that the benchmark signals:

- ``render``: a process set up as ``train`` sets itself up (Python handlers for SIGINT/SIGTERM,
  ``splat.cancel.arm``) renders the benchmark head scene (``bench/splat.py``) at the largest
  allowed frame (50 M pixels; 2048² with ``quick``), forward and backward, over and over; SIGINT
  comes part-way into a render. Reported: one whole render, SIGINT to the render's stop
  (``RenderCancelled`` caught), and SIGINT to the process's exit (it writes a small file
  atomically first, as a checkpoint would be; exit includes tearing down torch and numba).
- ``train``: a real ``train`` on a small synthetic capture gets SIGINT mid-run; reported: SIGINT
  to exit with status 130 and its checkpoint written.

``python -m mogaface bench cancel_latency`` prints JSON with the load average.
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time

LIMIT_SIZE = (7072, 7070)  # 50 M pixels, the image limit (core/limits.py)

CHILD = r"""
import json, os, signal, sys, time
import torch
from mogaface.bench.splat import head_scene
from mogaface.core.io.atomic import atomic_open
from mogaface.core.splat import cancel
from mogaface.core.splat.api import rasterize

width, height, n, out = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
asked = []
for number in (signal.SIGINT, signal.SIGTERM):
    signal.signal(number, lambda s, f: asked.append(s))
cancel.arm()
(means, quats, scales, opacities, colors), viewmat, K = head_scene(n, width, height)
means.requires_grad_(True)

def render():
    out = rasterize(means, quats, scales, opacities, colors, viewmat, K, width, height)
    (out.rgb.sum() + out.alpha.sum()).backward()

t0 = time.perf_counter()
render()
print(json.dumps({"render_s": time.perf_counter() - t0}), flush=True)
try:
    while not asked:
        print("start", flush=True)
        render()
except cancel.RenderCancelled:
    print(json.dumps({"stopped_at": time.time()}), flush=True)
with atomic_open(out, "w") as handle:  # what a checkpoint would be
    json.dump({"stopped": asked}, handle)
sys.exit(128 + asked[0])
"""


def _render_trial(width, height, n, threads, seed):
    env = dict(os.environ, NUMBA_NUM_THREADS=str(threads))
    with tempfile.TemporaryDirectory() as folder:
        marker = os.path.join(folder, "stopped.json")
        proc = subprocess.Popen([sys.executable, "-c", CHILD, str(width), str(height), str(n), marker],
                                stdout=subprocess.PIPE, text=True, env=env)
        try:
            render_s = json.loads(proc.stdout.readline())["render_s"]
            assert proc.stdout.readline().strip() == "start"
            time.sleep(random.Random(seed).uniform(0.2, 0.8) * render_s)  # part-way into a render
            sent, sent_wall = time.perf_counter(), time.time()
            proc.send_signal(signal.SIGINT)
            line = proc.stdout.readline()
            while line.strip() == "start":
                line = proc.stdout.readline()
            stopped = json.loads(line)["stopped_at"] - sent_wall if line.startswith("{") else None
            proc.wait(timeout=600)
            latency = time.perf_counter() - sent
        finally:
            if proc.poll() is None:
                proc.kill()
        return {"render_s": round(render_s, 3),
                "sigint_to_render_stopped_s": None if stopped is None else round(stopped, 3),
                "sigint_to_exit_s": round(latency, 3),
                "returncode": proc.returncode, "checkpoint_written": os.path.exists(marker)}


def _train_trial(threads):
    from mogaface.core.data.generator import CaptureSettings, make_capture
    from mogaface.core.run.names import CHECKPOINT_DIR, EVENTS_FILE
    from mogaface.core.train import config as C

    with tempfile.TemporaryDirectory() as folder:
        capture = os.path.join(folder, "capture")
        make_capture(capture, CaptureSettings(views=2, timesteps=16, size=128, supersample=1), progress=False)
        config = os.path.join(folder, "long.toml")
        with open(config, "w") as handle:
            handle.write(C.to_toml(C.resolve(overrides={
                "train": {"steps": 100000, "threads": threads, "checkpoint_every": 0},
                "eval": {"at_end": False, "lpips": False}})))
        out = os.path.join(folder, "run")
        proc = subprocess.Popen([sys.executable, "-m", "mogaface", "train", capture, "--out", out, "--config", config,
                                 "--quiet"], stderr=subprocess.PIPE, text=True)
        events = os.path.join(out, EVENTS_FILE)
        try:
            deadline = time.monotonic() + 600
            while not (os.path.exists(events) and '"iter"' in open(events).read()):
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"train did not start: {proc.communicate()[1][-2000:]}")
                time.sleep(0.1)
            time.sleep(random.Random(0).uniform(0.0, 0.5))
            sent = time.perf_counter()
            proc.send_signal(signal.SIGINT)
            proc.wait(timeout=600)
            latency = time.perf_counter() - sent
        finally:
            if proc.poll() is None:
                proc.kill()
        checkpoints = sorted(os.listdir(os.path.join(out, CHECKPOINT_DIR)))
        return {"sigint_to_exit_s": round(latency, 3), "returncode": proc.returncode,
                "checkpoints": checkpoints}


def run(threads: int = 2, quick: bool = False) -> dict:
    width, height = (2048, 2048) if quick else LIMIT_SIZE
    n = 200_000
    renders = [_render_trial(width, height, n, threads, seed) for seed in range(2 if quick else 3)]
    with open("/proc/loadavg") as handle:
        load = handle.read().split()[:3]
    return {
        "benchmark": "cancel_latency", "threads": threads,
        "render": {"width": width, "height": height, "gaussians": n, "trials": renders,
                   "worst_stop_over_render": round(max((r["sigint_to_render_stopped_s"] or r["sigint_to_exit_s"])
                                                           / r["render_s"] for r in renders), 3)},
        "train": _train_trial(threads),
        "loadavg": load,
    }


if __name__ == "__main__":
    print(json.dumps(run(quick="--quick" in sys.argv), indent=2))
