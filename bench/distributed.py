"""Benchmark of data-parallel training: 2 ranks × 1 thread against 1 process × 2 threads.

Both train the same synthetic capture (10 views, 256², default head, every Gaussian tripled as in
``bench train``) with the same global batch of two images per step, densification off. The
one-process run renders both images on two threads; torchrun's two ranks render one each on one
thread and all-reduce gradients and losses once per step (gloo, loopback). Reports steps per
second, the median step, and per step the bytes every rank contributes to the all-reduce and the
time spent in it, for Freeze and the full MoGaFace method, with the load average. A multi-machine
projection from these figures is in docs/training.md.

Each configuration runs as its own process(es): ``python -m mogaface.bench.distributed worker …``.
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

SIZE = 256
BATCH = 2


def _settings(variant: str, threads: int) -> dict:
    from mogaface.core.train.presets import FLAME_FINETUNE, FULL_METHOD

    extra = {"mogaface": {**FULL_METHOD, "encoder_views": 8}, "flame": FLAME_FINETUNE} if variant == "mogaface" else {}
    return {"train": {"steps": 100000, "threads": threads, "checkpoint_every": 0, "batch": BATCH},
            "densify": {"start": 100000, "stop": 100000, "opacity_reset_interval": 0},
            "eval": {"at_end": False}, **extra}


def worker(capture: str, run: str, variant: str, threads: int, steps: int, out: str) -> None:
    """One rank (or the single process): time ``steps`` steps after a warm-up; rank 0 writes JSON."""
    import torch

    from mogaface.bench.grow import grow
    from mogaface.core.train import config as config_module
    from mogaface.core.train.distributed import communicator_from_environment
    from mogaface.core.train.trainer import Trainer

    comm = communicator_from_environment()
    try:
        trainer = Trainer(capture, run, config_module.resolve(overrides=_settings(variant, threads)), comm=comm)
        grow(trainer, 3)
        with torch.no_grad():
            trainer.avatar.gaussians.opacity_logit.fill_(2.0)
        for _ in range(3):
            trainer.train_step()
        comm.barrier()
        sent, waited = comm.bytes_sent, comm.seconds
        times = []
        for _ in range(steps):
            start = time.perf_counter()
            trainer.train_step()
            times.append(time.perf_counter() - start)
        if comm.is_writer:
            result = {"variant": variant, "ranks": comm.world, "threads_per_rank": threads,
                      "gaussians": len(trainer.avatar.gaussians), "steps": steps,
                      "it_s": round(len(times) / sum(times), 3),
                      "median_step_ms": round(1000 * statistics.median(times), 2),
                      "allreduce_bytes_per_step": round((comm.bytes_sent - sent) / steps),
                      "allreduce_ms_per_step": round(1000 * (comm.seconds - waited) / steps, 2)}
            with open(out, "w", encoding="utf-8") as handle:
                json.dump(result, handle)
        trainer.events.close()
    finally:
        comm.close()


def _launch(ranks: int, threads: int, args: list[str]) -> None:
    module = ["-m", "mogaface.bench.distributed", "worker", *args]
    env = {**os.environ, "OMP_NUM_THREADS": str(threads)}
    if ranks == 1:
        command = [sys.executable, *module]
    else:
        command = [sys.executable, "-m", "torch.distributed.run", "--standalone", f"--nproc_per_node={ranks}",
                   *module]
    done = subprocess.run(command, env=env, capture_output=True, text=True)
    if done.returncode:
        raise RuntimeError(f"benchmark worker failed:\n{done.stderr[-4000:]}")


def run(threads: int = 2, quick: bool = False) -> dict:
    from mogaface.bench.train import _make_capture

    steps = 6 if quick else 20
    variants = ("freeze",) if quick else ("freeze", "mogaface")
    layouts = ((1, threads), (threads, 1))  # one process × threads, threads ranks × one
    results = []
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="mogaface-bench-dist-") as folder:
        capture = _make_capture(os.path.join(folder, "capture"), SIZE)
        for variant in variants:
            for ranks, per_rank in layouts:
                name = f"{variant}_{ranks}x{per_rank}"
                out = os.path.join(folder, name + ".json")
                _launch(ranks, per_rank, [str(capture), os.path.join(folder, name), variant, str(per_rank),
                                          str(steps), out])
                with open(out, encoding="utf-8") as handle:
                    results.append(json.load(handle))
    ratios = {}
    for variant in variants:
        one, many = (next(r for r in results if r["variant"] == variant and r["ranks"] == k) for k in (1, threads))
        ratios[variant] = round(many["it_s"] / one["it_s"], 3)
    return {
        "benchmark": "distributed",
        "image": [SIZE, SIZE],
        "batch": BATCH,
        "ranks_vs_threads_speed_ratio": ratios,
        "load_average_before": [round(x, 2) for x in load_before],
        "load_average_after": [round(x, 2) for x in os.getloadavg()],
        "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()},
        "results": results,
    }


if __name__ == "__main__":
    if len(sys.argv) == 8 and sys.argv[1] == "worker":
        worker(sys.argv[2], sys.argv[3], sys.argv[4], int(sys.argv[5]), int(sys.argv[6]), sys.argv[7])
    else:
        print("usage: python -m mogaface.bench.distributed worker CAPTURE RUN VARIANT THREADS STEPS OUT.json",
              file=sys.stderr)
        sys.exit(2)
