"""Fuzz of the splat engine with degenerate Gaussians and intrinsics.

Every case is finite input; the engine must finish each in bounded time with finite images and
finite gradients. Cases run one after another in a child process that prints a line per finished
case, so a parent can put a deadline on each case (a hang is a missed deadline, not a slow test).
``python -m mogaface bench splat_fuzz`` runs many cases and prints a JSON summary.
"""

from __future__ import annotations

import json
import os
import queue
import subprocess
import sys
import threading
import time

MAGNITUDES = (0.0, 1e-30, 1e-8, 1.0, 1e8, 1e21, 1e30, 3e38)
FOCALS = (1e-6, 1e-2, 1.0, 100.0, 1e8, 1e15, 1e21, 1e25, 1e30, 1e300)


def make_case(seed: int) -> dict:
    """A random scene whose some Gaussians, or the camera, take extreme but finite values."""
    import numpy as np

    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 40))
    means = rng.normal(scale=0.1, size=(n, 3))
    means[:, 2] += 1.0
    scales = rng.random((n, 3)) * 0.05
    quats = rng.normal(size=(n, 4))
    opacities = rng.random(n)
    colors = rng.random((n, 3))
    for _ in range(int(rng.integers(0, 4))):  # a few hostile Gaussians
        g = int(rng.integers(n))
        kind = int(rng.integers(5))
        mag = float(rng.choice(MAGNITUDES)) * float(rng.choice((-1.0, 1.0)))
        if kind == 0:
            means[g] = mag * rng.random(3)
        elif kind == 1:
            scales[g] = abs(mag) * rng.random(3)
        elif kind == 2:
            quats[g] = mag * rng.normal(size=4)
        elif kind == 3:
            means[g] = mag
            scales[g] = abs(mag)
        else:
            colors[g] = mag
    width, height = int(rng.integers(1, 70)), int(rng.integers(1, 70))
    fx = float(rng.choice(FOCALS)) if rng.random() < 0.5 else 60.0
    fy = float(rng.choice(FOCALS)) if rng.random() < 0.3 else fx
    cx = float(rng.choice((0.5 * width, -1e30, 1e30, 1e8, 0.0)) if rng.random() < 0.2 else 0.5 * width)
    cy = 0.5 * height
    as32 = lambda a: np.clip(a, -3e38, 3e38).astype(np.float32).tolist()  # noqa: E731
    return {"seed": seed, "means": as32(means), "scales": as32(scales), "quats": as32(quats),
            "opacities": as32(opacities), "colors": as32(colors), "K": [fx, fy, cx, cy],
            "width": width, "height": height}


def run_case(case: dict) -> dict:
    """Render the case forward and backward; report whether outputs and gradients are finite."""
    import numpy as np
    import torch

    from ..core.splat.api import rasterize

    tensors = [torch.tensor(case[k], dtype=torch.float32).requires_grad_(True)
               for k in ("means", "quats", "scales", "opacities", "colors")]
    fx, fy, cx, cy = case["K"]
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    out = rasterize(*tensors, np.eye(4), K, case["width"], case["height"])
    images_finite = all(bool(torch.isfinite(t).all()) for t in (out.rgb, out.alpha, out.depth))
    (out.rgb.sum() + out.alpha.sum() + 1e-3 * out.depth.sum()).backward()
    grads_finite = all(t.grad is not None and bool(torch.isfinite(t.grad).all()) for t in tensors)
    return {"seed": case["seed"], "images_finite": images_finite, "grads_finite": grads_finite}


def child_main(seeds) -> None:
    """Child process: one JSON line per finished case, in order."""
    for seed in seeds:
        start = time.perf_counter()
        result = run_case(make_case(seed))
        result["seconds"] = time.perf_counter() - start
        print(json.dumps(result), flush=True)


def run_with_deadline(seeds, per_case_s: float, first_case_s: float = 120.0) -> dict:
    """Run the cases in a child process; a case that misses its deadline is reported as a hang
    (and the child killed). ``first_case_s`` covers imports and kernel compilation."""
    code = ("import sys, json; from mogaface.bench.splat_fuzz import child_main; "
            "child_main(json.loads(sys.argv[1]))")
    proc = subprocess.Popen([sys.executable, "-c", code, json.dumps(list(seeds))],
                            stdout=subprocess.PIPE, text=True)
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [lines.put(x) for x in proc.stdout] + [lines.put(None)],
                     daemon=True).start()
    results, hang, times = [], None, []
    for k, seed in enumerate(seeds):
        start = time.perf_counter()
        try:
            line = lines.get(timeout=first_case_s if k == 0 else per_case_s)
        except queue.Empty:
            hang = seed
            break
        if line is None:
            hang = seed  # the child died on this case
            break
        times.append(time.perf_counter() - start)
        results.append(json.loads(line))
    if proc.poll() is None:
        proc.kill()
    proc.wait()
    return {"results": results, "hang_or_crash_seed": hang, "case_seconds": times,
            "returncode": proc.returncode}


def run(threads: int = 2, quick: bool = False) -> dict:
    """Run 400 cases (40 with ``quick``); the summary names any seed that hung, crashed or gave
    non-finite values."""
    os.environ.setdefault("NUMBA_NUM_THREADS", str(threads))
    count = 40 if quick else 400
    report = run_with_deadline(range(count), per_case_s=30.0)
    bad = [r["seed"] for r in report["results"] if not (r["images_finite"] and r["grads_finite"])]
    times = sorted(r["seconds"] for r in report["results"][1:]) or [0.0]  # the first includes compiling
    with open("/proc/loadavg") as handle:
        load = handle.read().split()[:3]
    return {
        "benchmark": "splat_fuzz", "cases": count, "finished": len(report["results"]),
        "hang_or_crash_seed": report["hang_or_crash_seed"], "non_finite_seeds": bad,
        "slowest_case_s": round(times[-1], 3), "median_case_s": round(times[len(times) // 2], 4),
        "loadavg": load,
    }


if __name__ == "__main__":
    print(json.dumps(run(), indent=2))
