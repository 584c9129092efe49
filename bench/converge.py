"""``bench converge``: time to quality at a real capture's scale, the number a user feels.

A synthetic capture at NeRSemble's scale is made once under ``--work`` (default
``out/bench_converge``; reused while its settings are the same): 802×550 rendered at that size
(``make-capture --size 802 --height 550``), 16 training cameras and the held-out frontal one,
:data:`TIMESTEPS` timesteps of which about three quarters train (``FREE`` and ``VAL`` are held
out), the default tracker error. Each variant (the ablation ladder's ``finetune``, Freeze + FLAME
fine-tuning, and ``full_prior``, the full method of the presets) trains from the default settings
for ``--minutes`` of training time (``train.max_minutes``) on the machine's cores. Every
:data:`EVERY` minutes of training time, with the training clock stopped, the held-out camera is
scored on the same evenly spaced training timesteps (the novel view: PSNR, SSIM, LPIPS), drawn as
``render`` draws the run (the MoGaFace modules included, :meth:`..core.train.trainer.Trainer.current_avatar`).

``--ranks N`` trains each variant data-parallel instead: N torchrun ranks on this machine, the
``--threads`` shared among them, N images a step under the square-root rule
(:func:`mogaface.core.train.config.for_batch`: the same images seen, the rates times √N); rank 0
keeps the clock and scores. ``--variants`` picks some of :data:`VARIANTS`; ``--config FILE.toml``
trains them under those settings (a schedule to compare; the curve is named after the file).

``--capture DIR`` trains on that capture instead (a Cycles capture, a tracked real one): the same
variants, clock and scores, on its held-out camera (its ``val`` split).

Prints JSON (the curve per variant, steps per second, Gaussians, the load average) and writes
``converge.png`` (the curves against minutes) in the work folder. ``--quick``: a 96×66 capture of
4 views, a few seconds per variant (a smoke run).

``--compare A.json,B.json,…`` trains nothing: it sets the curves of earlier reports side by side
(:func:`compare_reports`): one ``converge.png`` of them all and a table of where each ends and
when it first reaches the PSNR the first curve ends on (the baseline's).
"""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
import shutil
import subprocess
import sys
import time

WIDTH, HEIGHT = 802, 550
TRAIN_VIEWS = 16
TIMESTEPS = 400  # about 300 training timesteps
SUPERSAMPLE = 2
MINUTES = 60.0
EVERY = 5.0  # minutes of training time between scores
SCORED_FRAMES = 12
VARIANTS = ("finetune", "full_prior")
QUICK = {"size": 96, "height": 66, "views": 4, "timesteps": 20, "minutes": 0.08, "every": 0.04, "frames": 3}
WORK = "out/bench_converge"


def capture_settings(quick: bool):
    from mogaface.core.data.capture_settings import CaptureSettings

    if quick:
        return CaptureSettings(views=QUICK["views"], timesteps=QUICK["timesteps"], size=QUICK["size"],
                               height=QUICK["height"], supersample=1)
    return CaptureSettings(views=TRAIN_VIEWS + 1, timesteps=TIMESTEPS, size=WIDTH, height=HEIGHT,
                           supersample=SUPERSAMPLE)


def ensure_capture(folder: pathlib.Path, settings) -> tuple[pathlib.Path, float]:
    """The capture of ``settings`` in ``folder`` and the seconds it took to make (0: reused). A
    folder whose ``capture_info.json`` (written last) holds other settings, or none, is made again."""
    from mogaface.core.data.capture_info import INFO_FILE
    from mogaface.core.data.generator import make_capture

    info = folder / INFO_FILE
    if info.is_file() and json.loads(info.read_text(encoding="utf-8")).get("settings") == dataclasses.asdict(settings):
        return folder, 0.0
    shutil.rmtree(folder, ignore_errors=True)
    start = time.monotonic()
    make_capture(folder, settings, progress=False)
    return folder, time.monotonic() - start


def _scored_trainer(every_s: float, frames: int):
    """A trainer that scores the held-out camera every ``every_s`` seconds of training time. The
    score runs where the trainer's own quick check runs (``eval.every = 1``), which the training
    clock does not count."""
    from mogaface.core.train.trainer import Trainer

    class ScoredTrainer(Trainer):
        curve: list

        def _quick_check(self) -> None:
            if self.elapsed >= self.next_score:
                self.score()

        def score(self) -> None:
            from mogaface.core.train.config import EvalSection
            from mogaface.core.train.quick_eval import evaluate_val

            while self.next_score <= self.elapsed:
                self.next_score += every_s
            table, avatar = self.current_avatar()
            metrics = evaluate_val(avatar, self.data, table, EvalSection(max_frames=frames, lpips=True))
            self.curve.append({"minutes": round(self.elapsed / 60, 3), "step": self.step,
                               "gaussians": len(self.avatar.gaussians),
                               **{k: round(metrics[k], 4) for k in ("psnr", "ssim", "lpips")}})

    return ScoredTrainer


def minutes_to_reach(curve: list[dict], psnr: float) -> float | None:
    """The training minutes at which ``curve`` first reaches ``psnr`` (linear between its scores),
    or None if it never does."""
    for before, after in zip(curve, curve[1:]):
        if after["psnr"] >= psnr:
            if before["psnr"] >= psnr:
                return before["minutes"]
            share = (psnr - before["psnr"]) / (after["psnr"] - before["psnr"])
            return before["minutes"] + share * (after["minutes"] - before["minutes"])
    return curve[0]["minutes"] if curve and curve[0]["psnr"] >= psnr else None


def compare_reports(paths: list[str], work: pathlib.Path) -> dict:
    """The curves of earlier ``bench converge`` reports together: ``converge.png`` in ``work`` and
    a markdown table, the first report's first curve the reference whose final PSNR every curve
    is timed to."""
    from mogaface.core.errors import InputError

    from .plot import line_plots

    curves = {}
    for path in paths:
        try:
            report = json.loads(pathlib.Path(path).read_text(encoding="utf-8"))
            variants = report["variants"]
            for name, variant in variants.items():
                if not variant["curve"]:
                    raise KeyError("curve")
                curves[name if name not in curves else f"{name} ({pathlib.Path(path).stem})"] = {
                    **variant, "load_average": [report["load_average_before"], report["load_average_after"]]}
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as error:
            raise InputError(path, "variants", f"expected a bench converge report with its curves ({error})") from None
    reference_name, reference = next(iter(curves.items()))
    target = reference["curve"][-1]["psnr"]
    rows = []
    for name, variant in curves.items():
        end = variant["curve"][-1]
        reached = minutes_to_reach(variant["curve"], target)
        rows.append({"curve": name, "training_minutes": variant["training_minutes"], "steps": variant["steps"],
                     "gaussians": variant["gaussians"], "psnr": end["psnr"], "ssim": end["ssim"],
                     "lpips": end["lpips"], "delta_psnr": round(end["psnr"] - target, 4),
                     "minutes_to_reference": None if reached is None else round(reached, 2),
                     "load_average": variant["load_average"]})
    lines = [f"| curve | training minutes | steps | Gaussians | PSNR / SSIM / LPIPS at the end | Δ PSNR vs "
             f"{reference_name} | minutes to {target:.2f} dB |", "|---|---:|---:|---:|---|---:|---:|"]
    for row in rows:
        reached = "not reached" if row["minutes_to_reference"] is None else f"{row['minutes_to_reference']:.1f}"
        lines.append(f"| {row['curve']} | {row['training_minutes']:.1f} | {row['steps']} | {row['gaussians']} | "
                     f"{row['psnr']:.2f} / {row['ssim']:.4f} / {row['lpips']:.4f} | {row['delta_psnr']:+.2f} | "
                     f"{reached} |")
    work.mkdir(parents=True, exist_ok=True)
    plot = work / "converge.png"
    line_plots(plot, [{"title": f"held-out camera {metric.upper()}", "x_label": "minutes of training",
                       "series": {name: [(p["minutes"], p[metric]) for p in v["curve"]] for name, v in curves.items()}}
                      for metric in ("psnr", "ssim", "lpips")])
    return {"reference": reference_name, "reference_psnr": target, "rows": rows, "plot": str(plot),
            "markdown": "\n".join(lines)}


def variant_config(variant: str, minutes: float, threads: int, ranks: int = 1, config_path: str | None = None):
    """The default settings (under the TOML at ``config_path``, if any) with the ladder's
    ``variant``, ``minutes`` of training time and, for ``ranks`` > 1, a batch of one image per rank
    under the square-root rule."""
    from mogaface.core.train import config as config_module
    from mogaface.core.workflows.ablation import LADDER, merge_sections

    overrides = merge_sections({"train": {"max_minutes": minutes, "threads": threads, "seed": 0},
                                "eval": {"every": 1, "at_end": False}}, LADDER[variant])
    config = config_module.resolve(None, config_path, overrides)
    return config_module.for_batch(config, ranks, "sqrt") if ranks > 1 else config


def train_variant(capture: pathlib.Path, run: pathlib.Path, config, every: float, frames: int, comm=None) -> dict:
    """Train with ``config`` for its minutes of training time from scratch, scoring as it goes
    (``comm``: this process's place among data-parallel ranks; rank 0 scores and reports)."""
    if comm is None or comm.is_writer:
        shutil.rmtree(run, ignore_errors=True)
    if comm is not None:
        comm.barrier()  # the folder is fresh before any rank reads it
    trainer = _scored_trainer(every * 60, frames)(capture, run, config, comm=comm)
    trainer.curve, trainer.next_score = [], 0.0
    writer = comm is None or comm.is_writer
    if writer:
        trainer.score()  # the start: minute 0
    try:
        result = trainer.run()
    finally:
        trainer.events.close()
    if not writer:
        return {}
    if trainer.curve[-1]["step"] != trainer.step:  # the state the budget ends on, unless just scored
        trainer.next_score = trainer.elapsed
        trainer.score()
    return {"curve": trainer.curve, "steps": result["step"], "training_minutes": round(trainer.elapsed / 60, 3),
            "it_s": round(result["step"] / max(trainer.elapsed, 1e-9), 3), "batch": config.train.batch,
            "images_per_s": round(result["step"] * config.train.batch / max(trainer.elapsed, 1e-9), 3),
            "gaussians": len(trainer.avatar.gaussians)}


def worker(capture: str, run: str, variant: str, minutes: float, every: float, frames: int, threads: int,
           out: str, config_path: str = "") -> None:
    """One rank of a data-parallel variant (started by torchrun); rank 0 writes the result."""
    from mogaface.core.train.distributed import communicator_from_environment

    comm = communicator_from_environment()
    try:
        config = variant_config(variant, minutes, threads, comm.world, config_path or None)
        result = train_variant(pathlib.Path(capture), pathlib.Path(run), config, every, frames, comm)
        if comm.is_writer:
            pathlib.Path(out).write_text(json.dumps(result), encoding="utf-8")
    finally:
        comm.close()


def train_ranks(capture: pathlib.Path, run: pathlib.Path, variant: str, minutes: float, every: float, frames: int,
                threads: int, ranks: int, config_path: str | None = None) -> dict:
    """``variant`` on ``ranks`` torchrun ranks of this machine, the threads shared among them."""
    per_rank = max(1, threads // ranks)
    out = run.parent / f"{run.name}.result.json"
    out.unlink(missing_ok=True)
    command = [sys.executable, "-m", "torch.distributed.run", "--standalone", f"--nproc_per_node={ranks}",
               "-m", "mogaface.bench.converge", "worker", str(capture), str(run), variant, str(minutes), str(every),
               str(frames), str(per_rank), str(out), config_path or ""]
    done = subprocess.run(command, env={**os.environ, "OMP_NUM_THREADS": str(per_rank)}, capture_output=True,
                          text=True)
    if done.returncode:
        raise RuntimeError(f"{variant} on {ranks} ranks failed:\n{done.stderr[-4000:]}")
    return {**json.loads(out.read_text(encoding="utf-8")), "ranks": ranks, "threads_per_rank": per_rank}


def run(threads: int = 2, quick: bool = False, minutes: float | None = None, work: str | None = None,
        ranks: int | None = None, variants: str | None = None, config: str | None = None,
        compare: str | None = None, capture: str | None = None) -> dict:
    from mogaface.core.data.capture import Capture

    from .plot import line_plots

    folder = pathlib.Path(work or WORK)
    if compare is not None:
        return compare_reports([path for path in compare.split(",") if path], folder)
    names = tuple(variants.split(",")) if variants else VARIANTS
    unknown = [name for name in names if name not in VARIANTS]
    if unknown:
        from mogaface.core.errors import InputError

        raise InputError(None, "--variants", f"unknown {', '.join(unknown)} (known: {', '.join(VARIANTS)})")
    ranks = ranks or 1
    settings = capture_settings(quick)
    minutes = minutes if minutes is not None else (QUICK["minutes"] if quick else MINUTES)
    every = QUICK["every"] if quick else EVERY
    frames = QUICK["frames"] if quick else SCORED_FRAMES
    capture, made_s = (pathlib.Path(capture), 0.0) if capture else ensure_capture(folder / "capture", settings)
    opened = Capture.open(capture)
    opened.frames("val")  # the held-out camera the curve scores: a capture without one fails here, named
    size = opened.camera(opened.frames("train")[0])
    load_before = os.getloadavg()
    if config is not None:  # a bad file fails here, before the first variant trains
        variant_config(names[0], minutes, threads, ranks, config)
    variants = {}
    for name in names:
        label = name + (f"_{pathlib.Path(config).stem}" if config else "") + (f"_{ranks}ranks" if ranks > 1 else "")
        if ranks == 1:
            variants[label] = train_variant(capture, folder / "runs" / label,
                                            variant_config(name, minutes, threads, 1, config), every, frames)
        else:
            variants[label] = train_ranks(capture, folder / "runs" / label, name, minutes, every, frames, threads,
                                          ranks, config)
    plot = folder / "converge.png"
    line_plots(plot, [{"title": f"held-out camera {metric.upper()}", "x_label": "minutes of training",
                       "series": {name: [(p["minutes"], p[metric]) for p in v["curve"]] for name, v in variants.items()}}
                      for metric in ("psnr", "ssim", "lpips")])
    return {
        "capture": {"path": str(capture), "width": size.width, "height": size.height,
                    "training_cameras": len({f.camera_id for f in opened.frames("train")}),
                    "training_timesteps": len({f.timestep_index for f in opened.frames("train")}),
                    "training_images": len(opened.frames("train")), "made_in_s": round(made_s, 1)},
        "minutes": minutes, "every_minutes": every, "scored_frames": frames, "threads": threads, "ranks": ranks,
        "variants": variants, "plot": str(plot),
        "load_average_before": [round(x, 2) for x in load_before],
        "load_average_after": [round(x, 2) for x in os.getloadavg()],
    }


if __name__ == "__main__":
    if len(sys.argv) == 11 and sys.argv[1] == "worker":
        worker(sys.argv[2], sys.argv[3], sys.argv[4], float(sys.argv[5]), float(sys.argv[6]), int(sys.argv[7]),
               int(sys.argv[8]), sys.argv[9], sys.argv[10])
    else:
        print("usage: python -m mogaface.bench.converge worker CAPTURE RUN VARIANT MINUTES EVERY FRAMES THREADS "
              "OUT.json CONFIG.toml|''", file=sys.stderr)
        sys.exit(2)
