"""``bench batch``: what a batch of several images a step does to the quality per image seen.

Data-parallel training gives each rank one image a step, so N machines shorten the time to an
avatar only as far as a batch of N images reaches, in as many images, the quality of one image a
step. This trains Freeze on a synthetic capture (the default subject and tracker error at 128²,
made once under ``--work``, default ``out/bench_batch``) for :data:`IMAGES` images at each batch
of :data:`BATCHES`, under each rule of :func:`mogaface.core.train.config.for_batch` (the
schedule's step counts divided by the batch; the rates times √B, or as given), for
:data:`SEEDS` seeds, and scores the held-out camera at the end (PSNR, SSIM, LPIPS on
:data:`SCORED_FRAMES` frames). Differences against batch 1 are paired by seed.

Images seen, not time: one process renders a batch's images one after another, so every run costs
about the same and the load average moves no score here (``bench distributed`` times the ranks).
Complete runs are reused while their settings are the same (an interrupted bench goes on).
"""

from __future__ import annotations

import json
import os
import pathlib

IMAGES = 4000  # the default run's images (4 000 steps of one)
BATCHES = (1, 2, 4, 8)
SEEDS = 2
SCORED_FRAMES = 16
SIZE = 128
WORK = "out/bench_batch"
QUICK = {"size": 48, "views": 4, "timesteps": 16, "images": 48, "batches": (1, 4), "seeds": 1, "frames": 2}
METRICS = (("psnr", 2), ("ssim", 4), ("lpips", 4))


def _runs(batches, rules) -> list[tuple[int, str]]:
    """(batch, rule) pairs: batch 1 once (no rule changes it)."""
    return [(1, "none")] + [(b, rule) for b in batches if b > 1 for rule in rules]


def train_one(capture: pathlib.Path, run: pathlib.Path, batch: int, rule: str, seed: int, images: int,
              frames: int, threads: int) -> dict:
    """Train (or reuse) one run; its scores at the held-out camera and what it cost."""
    from mogaface.core.run.folder import is_complete
    from mogaface.core.run.names import CONFIG_FILE, METRICS_TRAIN_END_FILE, RUN_FILE
    from mogaface.core.train import config as config_module
    from mogaface.core.train.trainer import Trainer

    base = config_module.resolve(overrides={"train": {"steps": images, "threads": threads, "seed": seed},
                                            "eval": {"max_frames": frames}})
    config = config_module.for_batch(base, batch, rule)
    info, metrics = run / RUN_FILE, run / METRICS_TRAIN_END_FILE
    same = (run / CONFIG_FILE).is_file() and (run / CONFIG_FILE).read_text() == config_module.to_toml(config)
    if not (same and metrics.is_file() and is_complete(run)):
        import shutil

        shutil.rmtree(run, ignore_errors=True)
        trainer = Trainer(capture, run, config)
        try:
            trainer.run()
        finally:
            trainer.events.close()
    summary, scores = json.loads(info.read_text()), json.loads(metrics.read_text())
    return {"steps": summary.get("final_step"), "gaussians": summary.get("gaussians"),
            "training_s": summary.get("wall_time_s"), **{name: scores[name] for name, _ in METRICS}}


def summarise(runs: dict, seeds: int) -> tuple[list[dict], str]:
    """Rows (mean ± std over seeds, Δ against batch 1 paired by seed) and their markdown table."""
    from mogaface.core.evaluate.seed_stats import format_difference, format_mean_std, mean_std, paired_difference

    reference = runs["1 none"]
    rows, lines = [], ["| batch | rule | steps | PSNR | Δ PSNR | SSIM | LPIPS | Δ LPIPS | Gaussians |",
                       "|---:|---|---:|---|---|---|---|---|---:|"]
    for key, by_seed in runs.items():
        batch, rule = key.split()
        row = {"batch": int(batch), "rule": rule, "steps": by_seed[0]["steps"], "seeds": seeds}
        for name, _ in METRICS:
            values = [r[name] for r in by_seed]
            row[name] = mean_std(values)[:2]
            row[f"delta_{name}"] = paired_difference(values, [r[name] for r in reference])
        row["gaussians"] = mean_std([r["gaussians"] for r in by_seed])[0]
        rows.append(row)
        cell = {name: format_mean_std([r[name] for r in by_seed], digits) for name, digits in METRICS}
        same = int(batch) == 1
        lines.append(f"| {batch} | {'–' if same else rule} | {row['steps']} | {cell['psnr']} | "
                     f"{'–' if same else format_difference(row['delta_psnr'], 2)} | {cell['ssim']} | {cell['lpips']} | "
                     f"{'–' if same else format_difference(row['delta_lpips'], 4)} | {row['gaussians']:.0f} |")
    return rows, "\n".join(lines)


def run(threads: int = 2, quick: bool = False, work: str | None = None) -> dict:
    from mogaface.bench.converge import ensure_capture
    from mogaface.core.data.capture_settings import CaptureSettings
    from mogaface.core.train.config import BATCH_RULES

    folder = pathlib.Path(work or WORK)
    if quick:
        settings = CaptureSettings(views=QUICK["views"], timesteps=QUICK["timesteps"], size=QUICK["size"],
                                   supersample=1)
        images, batches, seeds, frames = QUICK["images"], QUICK["batches"], QUICK["seeds"], QUICK["frames"]
    else:
        settings, images, batches, seeds, frames = CaptureSettings(size=SIZE), IMAGES, BATCHES, SEEDS, SCORED_FRAMES
    capture, made_s = ensure_capture(folder / "capture", settings)
    load_before = os.getloadavg()
    runs = {f"{batch} {rule}": [train_one(capture, folder / "runs" / f"batch{batch}_{rule}_seed{seed}", batch, rule,
                                          seed, images, frames, threads) for seed in range(seeds)]
            for batch, rule in _runs(batches, BATCH_RULES)}
    rows, markdown = summarise(runs, seeds)
    return {
        "benchmark": "batch",
        "capture": {"path": str(capture), "size": settings.size, "views": settings.views,
                    "timesteps": settings.timesteps, "made_in_s": round(made_s, 1)},
        "images": images, "seeds": seeds, "scored_frames": frames, "threads": threads,
        "variant": "Freeze (the defaults)", "rules": {"sqrt": "rates × √batch", "none": "rates as for batch 1"},
        "rows": rows, "runs": runs, "markdown": markdown,
        "load_average_before": [round(x, 2) for x in load_before],
        "load_average_after": [round(x, 2) for x in os.getloadavg()],
    }
