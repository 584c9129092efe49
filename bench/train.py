"""Benchmark of the full training step (render, loss, backward, Adam, densify bookkeeping).

Makes a small synthetic capture (10 views, 256², default head) in a temporary folder, then times
training steps of the default settings with densification off, at the avatar's starting size
(one Gaussian per triangle) and, unless ``quick``, with every Gaussian tripled (jittered copies,
the size a densified avatar reaches). Each size is timed for the baseline (Freeze) and for the
full MoGaFace step (8 encoder views at 128², cross-attention, bank, texture attention). Reports
steps per second, the median step and the load average, since a busy machine slows every number here.
"""

from __future__ import annotations

import os
import platform
import statistics
import tempfile
import time


def _make_capture(folder, size):
    from mogaface.core.data.generator import CaptureSettings, make_capture

    return make_capture(folder, CaptureSettings(views=VIEWS, timesteps=16, size=size, supersample=1), progress=False)


VIEWS = 10  # 9 training cameras: 8 other views for the encoder, the held-out one aside


def _variants() -> dict:
    """Settings over the defaults; "mogaface" is the full method as its preset trains it."""
    from mogaface.core.train.presets import FLAME_FINETUNE, FULL_METHOD

    return {"freeze": {}, "mogaface": {"mogaface": {**FULL_METHOD, "encoder_views": 8}, "flame": FLAME_FINETUNE}}


def _time_steps(trainer, warmup, steps):
    for _ in range(warmup):
        trainer.train_step()
    times = []
    for _ in range(steps):
        start = time.perf_counter()
        trainer.train_step()
        times.append(time.perf_counter() - start)
    return times


def run(threads: int = 2, quick: bool = False, scale: str = "small") -> dict:
    """``scale="real"``: the full method at a real capture's size instead (see :mod:`.train_real`)."""
    if scale == "real":
        from .train_real import run as run_real

        return run_real(threads=threads, quick=quick)
    from mogaface.core.train import config as config_module
    from mogaface.core.train.trainer import Trainer

    from .grow import grow

    size = 256
    steps = 10 if quick else 40
    factors = (1,) if quick else (1, 3)
    results = []
    with tempfile.TemporaryDirectory(prefix="mogaface-bench-train-") as folder:
        start = time.perf_counter()
        capture = _make_capture(os.path.join(folder, "capture"), size)
        capture_s = time.perf_counter() - start
        for factor, (variant, settings) in ((f, v) for f in factors for v in _variants().items()):
            config = config_module.resolve(overrides={
                "train": {"steps": 100000, "threads": threads, "checkpoint_every": 0},
                "densify": {"start": 100000, "stop": 100000, "opacity_reset_interval": 0},
                "eval": {"at_end": False},
                **settings,
            })
            trainer = Trainer(capture, os.path.join(folder, f"run{factor}_{variant}"), config)
            if factor > 1:
                grow(trainer, factor)
            # Warm up (numba cache, first images) with opacities raised as a trained avatar has them.
            import torch

            with torch.no_grad():
                trainer.avatar.gaussians.opacity_logit.fill_(2.0)
            times = _time_steps(trainer, 3, steps)
            results.append({
                "variant": variant,
                "gaussians": len(trainer.avatar.gaussians),
                "steps": steps,
                "it_s": round(len(times) / sum(times), 3),
                "median_step_ms": round(1000 * statistics.median(times), 2),
                "min_step_ms": round(1000 * min(times), 2),
            })
            trainer.events.close()
    return {
        "benchmark": "train",
        "threads": threads,
        "quick": quick,
        "image": [size, size],
        "capture_views": VIEWS,
        "capture_seconds": round(capture_s, 1),
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()},
        "results": results,
    }
