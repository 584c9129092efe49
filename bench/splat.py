"""Benchmark of the CPU splat engine: forward and forward+backward medians, peak memory, and the
speed ratio against the pure-torch reference on the same scenes in the same run.

Scene: a head-sized ellipsoid shell (radii 8, 11, 10 cm) 0.6 m in front of the camera, covering
about 45% of the image; flattened, randomly rotated Gaussians whose size shrinks as 1/sqrt(N);
opacity uniform in [0.2, 0.95]; RGB colours. Each configuration runs in its own child process so
that its peak memory (VmHWM - VmRSS before the step, Linux) is its own.
"""

from __future__ import annotations

import json
import math
import os
import platform
import statistics
import subprocess
import sys
import time

RADII = (0.08, 0.11, 0.10)
DISTANCE = 0.6
COVERAGE = 0.45
REFERENCE_PAIRS = 3e8  # (pixel, splat) pairs the reference may visit per pass (time)
REFERENCE_NS_PER_PAIR = 60  # what the reference costs per pair and pass on this machine, roughly
REFERENCE_FLOATS_PER_PAIR = 24  # its working set per pair (autograd temporaries)
REFERENCE_BAND_BYTES = 1.5e9  # its largest band's working set (memory)


def head_scene(n, width, height, seed=0):
    """Scene tensors and camera (``viewmat``, ``K``) of the benchmark."""
    import torch

    g = torch.Generator().manual_seed(seed)
    normals = torch.randn(n, 3, generator=g)
    normals /= normals.norm(dim=1, keepdim=True)
    radii = torch.tensor(RADII)
    means = normals * radii + torch.tensor([0.0, 0.0, DISTANCE])
    a, b, c = RADII
    area = 4 * math.pi * (((a * b) ** 1.6 + (a * c) ** 1.6 + (b * c) ** 1.6) / 3) ** (1 / 1.6)
    size = 0.6 * math.sqrt(area / n)
    scales = size * (0.5 + torch.rand(n, 3, generator=g))
    scales[:, 2] *= 0.1  # flattened
    quats = torch.randn(n, 4, generator=g)
    quats /= quats.norm(dim=1, keepdim=True)
    opacities = 0.2 + 0.75 * torch.rand(n, generator=g)
    colors = torch.rand(n, 3, generator=g)
    # focal length so the silhouette (about an ellipse of semi-axes a/d, b/d) covers COVERAGE
    f = math.sqrt(COVERAGE * width * height / (math.pi * (a / DISTANCE) * (b / DISTANCE)))
    K = torch.tensor([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]], dtype=torch.float64)
    return (means, quats, scales, opacities, colors), torch.eye(4, dtype=torch.float64), K


def _rss_kb(field):
    with open("/proc/self/status") as handle:
        for line in handle:
            if line.startswith(field + ":"):
                return int(line.split()[1])
    return 0


def _reset_peak():
    try:
        with open("/proc/self/clear_refs", "w") as handle:
            handle.write("5")
        return True
    except OSError:
        return False


def _median_ms(fn, repeats, cpu=None):
    """Median and best wall time in ms; with ``cpu`` (a list), also appends the median process
    CPU time, which other processes on the machine do not inflate (threads spinning do)."""
    times, cpu_times = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
        cpu_times.append((time.process_time() - c0) * 1e3)
    if cpu is not None:
        cpu.append(round(statistics.median(cpu_times), 2))
    return round(statistics.median(times), 2), round(min(times), 2)


def _child(config):
    """One configuration, measured in this (fresh) process; prints one JSON line."""
    import numba
    import torch

    from mogaface.core.splat import rasterize
    from mogaface.core.splat.reference import rasterize_reference

    numba.set_num_threads(config["threads"])
    torch.set_num_threads(config["threads"])
    n, size, repeats = config["n"], config["size"], config["repeats"]
    scene, viewmat, K = head_scene(n, size, size)
    target = torch.rand(size, size, 3, generator=torch.Generator().manual_seed(1))

    def step(fn, backward):
        params = [p.clone().requires_grad_(True) for p in scene]
        out = fn(*params, viewmat, K, size, size)
        rgb = out["rgb"] if isinstance(out, dict) else out.rgb
        if backward:
            (rgb - target).abs().mean().backward()
        return out

    small, sv, sk = head_scene(100, 32, 32)
    rasterize(*[p.clone().requires_grad_(True) for p in small], sv, sk, 32, 32).rgb.sum().backward()  # load kernels
    result = {"n": n, "size": size, "load_average_1min": round(os.getloadavg()[0], 2)}
    base = _rss_kb("VmRSS")
    if _reset_peak():
        out = step(rasterize, True)
        result["peak_mem_mb"] = round((_rss_kb("VmHWM") - base) / 1024, 1)
        result["process_peak_rss_mb"] = round(_rss_kb("VmHWM") / 1024, 1)
    else:
        out = step(rasterize, True)
    result["coverage"] = round(float((out.alpha > 0.5).float().mean()), 3)
    result["visible"] = int((out.radii > 0).sum())
    cpu = []
    result["forward_ms"], result["forward_best_ms"] = _median_ms(lambda: step(rasterize, False), repeats, cpu)
    result["fwd_bwd_ms"], result["fwd_bwd_best_ms"] = _median_ms(lambda: step(rasterize, True), repeats, cpu)
    result["forward_cpu_ms"], result["fwd_bwd_cpu_ms"] = cpu

    # reference: bands of rows, each against the splats whose 3-sigma radius reaches it, under
    # gradient checkpointing; its cost is about (pixel, splat) pairs visited
    band = 16
    my, radii = out.means2d.detach()[:, 1], out.radii
    seen = radii > 0
    pairs, widest = 0, 0
    for r0 in range(0, size, band):
        reach = seen & (my + radii.float() >= r0) & (my - radii.float() <= r0 + band)
        pairs += band * size * int(reach.sum())
        widest = max(widest, int(reach.sum()))
    band_bytes = band * size * widest * 4 * REFERENCE_FLOATS_PER_PAIR
    result["reference_pairs"] = pairs
    if pairs > REFERENCE_PAIRS or band_bytes > REFERENCE_BAND_BYTES:
        result["reference"] = (f"skipped: {pairs:.2e} pixel-splat pairs (budget {REFERENCE_PAIRS:.0e}, about "
                               f"{pairs * REFERENCE_NS_PER_PAIR * 1e-9:.0f} s per pass) and {band_bytes / 1e9:.1f} GB "
                               f"for the widest band")
        return result
    ref_repeats = 3 if pairs < 5e7 else 1
    run_ref = lambda backward: step(lambda *a: rasterize_reference(*a, band_rows=band, use_checkpoint=True),
                                    backward)
    ref_fwd, _ = _median_ms(lambda: run_ref(False), ref_repeats)
    ref_step, _ = _median_ms(lambda: run_ref(True), ref_repeats)
    result["reference_forward_ms"] = ref_fwd
    result["reference_fwd_bwd_ms"] = ref_step
    result["speedup_forward"] = round(ref_fwd / result["forward_ms"], 1)
    result["speedup_fwd_bwd"] = round(ref_step / result["fwd_bwd_ms"], 1)
    return result


def run(threads: int = 2, quick: bool = False) -> dict:
    sizes = [256] if quick else [256, 512]
    counts = [10_000] if quick else [10_000, 30_000, 100_000]
    repeats = 3 if quick else 11
    # OpenMP threads that spin while waiting hold a core another thread needs; on a shared machine
    # that costs 2-3x at 2 threads. torch and numba share torch's libgomp, which reads this when
    # torch is imported, so it is set for the child processes (an explicit setting is kept).
    env = dict(os.environ)
    env.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    results = []
    for size in sizes:
        for n in counts:
            config = {"n": n, "size": size, "threads": threads, "repeats": repeats}
            code = f"import json; from mogaface.bench.splat import _child; print(json.dumps(_child({config!r})))"
            proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
            if proc.returncode != 0:
                results.append({"n": n, "size": size, "error": proc.stderr.strip().splitlines()[-1:]})
                continue
            results.append(json.loads(proc.stdout.strip().splitlines()[-1]))
    return {
        "benchmark": "splat",
        "threads": threads,
        "quick": quick,
        "omp_wait_policy": env["OMP_WAIT_POLICY"],
        "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform(),
                    "processor": platform.processor() or platform.machine()},
        "note": "timings are wall-clock on a shared machine; load_average_1min above the thread count "
                "means other processes competed for the cores, compare ratios and best-of times then",
        "units": {"time": "ms, median (and best) of repeats; one step = rasterize (+ L1 loss backward)",
                  "cpu_ms": "median process CPU time of a step, all threads summed (spin-waits included)",
                  "peak_mem_mb": "peak RSS growth during one forward+backward over the RSS before it "
                                 "(scene tensors already allocated; Linux VmHWM after clear_refs)"},
        "results": results,
    }
