"""``bench train --scale real``: the full method at a real capture's size.

NeRSemble as GaussianAvatars uses it: 802×550 images, 16 training cameras, about 100k Gaussians
after densification. The synthetic capture (17 views: 16 training cameras and the held-out one,
16 timesteps) is rendered at 256² and resampled to 802 × 802, then cropped to 802×550 with the
intrinsics scaled and shifted to match, which is the same work for the trainer as a real capture
of that size. Every Gaussian gets jittered copies up to about 100k, densification is off, and the
steps run in a child process whose peak resident memory (VmHWM) is its own.

Reported: steps per second, the median step, peak memory, what training holds per timestep (so
memory at a capture's length is the measured peak plus that times the extra timesteps; the image
caches are byte-bounded), and the projected wall time of a paper-length run (10⁶ steps) on 2, 8
and 32 cores from the measured per-thread throughput.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time

WIDTH, HEIGHT = 802, 550
TRAIN_VIEWS = 16
TARGET_GAUSSIANS = 100_000
PAPER_STEPS = 1_000_000


def make_real_capture(folder: str) -> str:
    """A 802×550, 16-training-camera capture from a synthetic 256² one (resampled, cropped)."""
    import numpy as np
    from PIL import Image

    from mogaface.core.camera import Camera
    from mogaface.core.data.capture import Capture
    from mogaface.core.data.generator import CaptureSettings, make_capture
    from mogaface.core.data.writer import CaptureWriter

    small = os.path.join(folder, "small")
    make_capture(small, CaptureSettings(views=TRAIN_VIEWS + 1, timesteps=16, size=256, supersample=1), progress=False)
    source = Capture.open(small)
    root = os.path.join(folder, "real")
    scale = WIDTH / 256
    top = (WIDTH - HEIGHT) // 2

    def resample(array):
        image = Image.fromarray((np.clip(array, 0, 1) * 255 + 0.5).astype(np.uint8))
        return np.asarray(image.resize((WIDTH, WIDTH), Image.BILINEAR))[top:top + HEIGHT]

    written = set()
    with CaptureWriter(root, png_compress_level=1) as writer:
        for split, frames in source.splits.items():
            for frame in frames:
                camera = source.camera(frame)
                K = camera.K * np.array([[scale], [scale], [1.0]])
                K[1, 2] -= top
                rgb, mask = source.load_image(frame)
                if frame.timestep_index not in written:
                    writer.write_flame_params(frame.timestep_index, source.flame_params(frame.timestep_index))
                    written.add(frame.timestep_index)
                writer.add_frame(frame.timestep_index, Camera(K, camera.w2c, WIDTH, HEIGHT, camera.camera_id),
                                 resample(rgb), resample(mask), split=split, camera_index=frame.camera_index)
        canonical = source.canonical_flame_params()
        if canonical is not None:
            writer.write_canonical_flame_params(canonical)
    with open(os.path.join(small, "capture_info.json"), encoding="utf-8") as handle:
        info = json.load(handle)
    import shutil

    shutil.copyfile(os.path.join(small, info.get("model_file", "head.pkl")),
                    os.path.join(root, info.get("model_file", "head.pkl")))
    with open(os.path.join(root, "capture_info.json"), "w", encoding="utf-8") as handle:
        json.dump(info, handle)
    return root


def _peak_rss_mb() -> float:
    with open("/proc/self/status") as handle:
        for line in handle:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def worker(capture: str, run: str, threads: int, steps: int, out: str) -> None:
    """Time ``steps`` full-method steps at about 100k Gaussians; write the figures as JSON."""
    import torch

    from mogaface.bench.grow import grow
    from mogaface.core.train import config as config_module
    from mogaface.core.train.presets import FLAME_FINETUNE, FULL_METHOD
    from mogaface.core.train.trainer import Trainer

    config = config_module.resolve(overrides={
        "train": {"steps": 100000, "threads": threads, "checkpoint_every": 0},
        "densify": {"start": 100000, "stop": 100000, "opacity_reset_interval": 0},
        "eval": {"at_end": False}, "mogaface": {**FULL_METHOD, "encoder_views": 8}, "flame": FLAME_FINETUNE})
    trainer = Trainer(capture, run, config)
    grow(trainer, max(1, round(TARGET_GAUSSIANS / len(trainer.avatar.gaussians))))
    with torch.no_grad():
        trainer.avatar.gaussians.opacity_logit.fill_(2.0)
    trainer.train_step()  # warm-up: numba cache, first images
    times = []
    for _ in range(steps):
        start = time.perf_counter()
        trainer.train_step()
        times.append(time.perf_counter() - start)
    model = trainer.mogaface.model
    table_row = sum(v[0].numel() * v.element_size() for v in trainer.table.trainable().values())
    # Per timestep: its FLAME row and that row's two Adam moments (fine-tuning), its bank row
    # (views × expression) with the written flags.
    per_timestep = 3 * table_row + model.bank.values[0].numel() * 4 + model.bank.written[0].numel()
    result = {"gaussians": len(trainer.avatar.gaussians), "steps": steps, "threads": threads,
              "it_s": round(len(times) / sum(times), 3), "median_step_s": round(statistics.median(times), 3),
              "peak_rss_mb": round(_peak_rss_mb(), 1), "bytes_per_timestep": round(per_timestep),
              "image_cache_bound_mb": trainer.data.capture.memory_bound_bytes / 2**20,
              "view_cache_bound_mb": round(trainer.mogaface.views.max_items * 3 * trainer.mogaface.views.size**2
                                           / 2**20, 1),
              "frames": len(trainer.data.frames)}
    with open(out, "w", encoding="utf-8") as handle:
        json.dump(result, handle)
    trainer.events.close()


def projection(it_s: float, threads: int, allreduce_mb: float) -> dict:
    """Wall time of 10⁶ images (the paper's steps of one image) on 2, 8 and 32 cores.

    One rank per core, each rendering one image per step at the measured per-thread speed
    (``it_s / threads``: linear scaling, an upper bound), plus an all-reduce of the step's
    gradients: a ring moves 2·(W−1)/W of them per rank, here over 10 Gbit/s (1.25 GB/s).
    """
    per_image_s = threads / it_s
    out = {}
    for cores in (2, 8, 32):
        steps = PAPER_STEPS / cores
        comm_s = 2 * (cores - 1) / cores * allreduce_mb / 1250.0
        out[f"{cores}_cores_hours"] = round(steps * (per_image_s + comm_s) / 3600, 1)
    return out


def run(threads: int = 2, quick: bool = False) -> dict:
    steps = 2 if quick else 5
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="mogaface-bench-real-") as folder:
        start = time.perf_counter()
        capture = make_real_capture(folder)
        capture_s = time.perf_counter() - start
        out = os.path.join(folder, "result.json")
        done = subprocess.run([sys.executable, "-m", "mogaface.bench.train_real", "worker", capture,
                               os.path.join(folder, "run"), str(threads), str(steps), out],
                              capture_output=True, text=True)
        if done.returncode:
            raise RuntimeError(f"benchmark worker failed:\n{done.stderr[-4000:]}")
        with open(out, encoding="utf-8") as handle:
            result = json.load(handle)
    allreduce_mb = result["gaussians"] * 59 * 4 / 1e6  # 59 floats per Gaussian at SH degree 3
    return {
        "benchmark": "train",
        "scale": "real",
        "image": [WIDTH, HEIGHT],
        "training_cameras": TRAIN_VIEWS,
        "variant": "mogaface (full method, FLAME fine-tuning)",
        "capture_seconds": round(capture_s, 1),
        **result,
        "memory_at_2000_timesteps_mb": round(result["peak_rss_mb"]
                                             + (2000 - 16) * result["bytes_per_timestep"] / 2**20, 1),
        "allreduce_mb_per_step": round(allreduce_mb, 1),
        "paper_length_run": {"steps": PAPER_STEPS, **projection(result["it_s"], threads, allreduce_mb)},
        "load_average_before": [round(x, 2) for x in load_before],
        "load_average_after": [round(x, 2) for x in os.getloadavg()],
        "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()},
    }


if __name__ == "__main__":
    if len(sys.argv) == 7 and sys.argv[1] == "worker":
        worker(sys.argv[2], sys.argv[3], int(sys.argv[4]), int(sys.argv[5]), sys.argv[6])
    else:
        print("usage: python -m mogaface.bench.train_real worker CAPTURE RUN THREADS STEPS OUT.json", file=sys.stderr)
        sys.exit(2)
