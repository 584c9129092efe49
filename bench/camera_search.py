"""Choosing camera refinement's settings on validation frames.

``python -m mogaface bench camera_search [--work DIR]`` makes a capture whose cameras are off
(as the camera tables' ``cap_cal``: 128², 48 timesteps, 1° and 5 mm per axis; made once, reused)
and trains Freeze with camera refinement (``--preset demo``, :data:`STEPS` steps a round) per
setting tried. Each try is scored on the validation sequence's self-reenactment frames: the
training cameras, at their true poses as every camera score is, on frames no step trained on. The
search goes one setting at a time from today's recommended settings (three rounds, the config's
rates, start and gauge), a new value kept only above :data:`.refiner_search.MIN_GAIN_DB`. Each
try's run folder stays in ``DIR/runs`` (a stopped search resumes; a wider grid trains only what
is new), and its camera error against the truth is reported beside its score, never chosen on.

``--test-subjects 1,2``: then the test table, measured once with what was chosen: for each
subject (its own noise draw: camera error, tracker error), a capture as the search's, trained with
today's recommended settings and with the chosen ones, scored on the test frames: novel view at the
true held-out camera (every frame, as ``eval --protocols novel_view`` scores it: the camera tables'
number) and self-reenactment of the unseen sequence, with the paired gain of the choice.
``--quick``: a tiny capture and a two-value grid (a smoke run).
"""

from __future__ import annotations

import os
import pathlib
import signal
import subprocess
import sys

from .refiner_search import coordinate_search, settings_name

WORK = "out/bench_camera_search"
STEPS = 1800
SCORED_FRAMES = 12
CAMERA_GRID = {"rotation_lr": (1e-3, 2e-3, 5e-3), "begin": (0.3, 0.45, 0.6), "gauge": ("rigid", "mean"),
               "rounds": (1, 2, 3)}
SEARCH_ROUNDS = 2
QUICK = {"size": 64, "views": 4, "timesteps": 24, "steps": 20, "frames": 2,
         "grid": {"rotation_lr": (1e-3, 2e-3)}, "start": {"rounds": 1}}


def capture_settings(quick: bool, subject: int = 0):
    """The search's capture (subject 0, draw 0) or a test subject's (subject ``s``, draw ``s``)."""
    from mogaface.core.data.capture_settings import CaptureSettings

    if quick:
        return CaptureSettings(views=QUICK["views"], timesteps=QUICK["timesteps"], size=QUICK["size"],
                               supersample=1, camera_noise=1.0, subject=subject, seed=subject)
    return CaptureSettings(size=128, timesteps=48, camera_noise=1.0, subject=subject, seed=subject)


def try_config(settings: dict, threads: int, steps: int):
    """Freeze under the demo preset with camera refinement set as ``settings``."""
    from mogaface.core.train import config as config_module

    return config_module.resolve("demo", None, {
        "train": {"steps": steps, "threads": threads, "seed": 0},
        "eval": {"at_end": False},
        "cameras": {"refine": True, **settings}})


def trained_run(capture: pathlib.Path, folder: pathlib.Path, settings: dict, threads: int, steps: int) -> pathlib.Path:
    """The try's run folder, trained by the ``train`` command (its rounds included) in a child
    process, which a Ctrl-C stops at a checkpoint as any training; a complete run is reused, a
    stopped one resumed."""
    from mogaface.core.io.atomic import write_text
    from mogaface.core.run.folder import is_complete
    from mogaface.core.train import config as config_module

    run = folder / settings_name(settings)
    if is_complete(run):
        return run
    if run.exists():
        arguments = ["--resume"]
    else:
        config_file = folder / f"{run.name}.toml"
        write_text(config_file, config_module.to_toml(try_config(settings, threads, steps)))
        arguments = ["--config", str(config_file)]
    done = subprocess.run([sys.executable, "-m", "mogaface", "train", str(capture), "--out", str(run), "--quiet",
                           *arguments], stderr=subprocess.PIPE, text=True)
    if done.returncode in (128 + signal.SIGINT, 128 + signal.SIGTERM):
        raise KeyboardInterrupt  # stopped at a checkpoint: the search resumes from it
    if done.returncode:
        raise RuntimeError(f"training {run} ended with status {done.returncode}:\n{done.stderr[-4000:]}")
    return run


def scored_try(run: pathlib.Path, frames: int) -> dict:
    """The run's validation self-reenactment scores (the tracked parameters, as Freeze renders) and
    its cameras' error against the truth."""
    from mogaface.core.workflows.ablation import score_variant

    scores = score_variant(run, frames, False, (), split="validation")
    tracked = scores["protocols"]["self_reenactment"]["tracked"]
    refined = scores["cameras"].get("refined", {})
    return {"psnr_db": round(tracked["psnr"], 4), "ssim": round(tracked["ssim"], 4),
            "rotation_deg": round(refined["rotation_deg"], 4) if refined else None,
            "position_mm": round(refined["position_mm"], 3) if refined else None,
            "calibrated_rotation_deg": round(scores["cameras"]["calibrated_refined_cameras"]["rotation_deg"], 4),
            "run": str(run)}


def tested_try(run: pathlib.Path, frames: int | None) -> dict:
    """The run's test scores: novel view at the true held-out camera, self-reenactment of the unseen
    sequence (the tracked parameters, as Freeze renders), and its cameras' error."""
    from mogaface.core.workflows.ablation import score_variant

    scores = score_variant(run, frames, False, (), split="test")
    refined = scores["cameras"].get("refined", {})
    protocols = scores["protocols"]
    return {"novel_view_psnr_db": round(protocols["novel_view"]["tracked"]["psnr"], 4),
            "self_reenactment_psnr_db": round(protocols["self_reenactment"]["tracked"]["psnr"], 4),
            "rotation_deg": round(refined["rotation_deg"], 4) if refined else None,
            "position_mm": round(refined["position_mm"], 3) if refined else None,
            "scored_frames": {name: len(views["frames"]) for name, views in scores["scored"].items()},
            "run": str(run)}


def parse_subjects(text: str) -> list[int]:
    """``"1,2"`` → ``[1, 2]``: the test subjects, never the search's own subject 0."""
    from mogaface.core.errors import InputError

    try:
        subjects = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise InputError(None, "--test-subjects", f"expected comma-separated subject numbers, got {text!r}") from None
    if not subjects or min(subjects) < 1 or len(set(subjects)) != len(subjects):
        raise InputError(None, "--test-subjects", f"expected distinct subjects from 1 up (0 is the search's own), "
                                                  f"got {text!r}")
    return subjects


def test_table(folder: pathlib.Path, subjects: list[int], today: dict, chosen: dict, threads: int, steps: int,
               frames: int | None, quick: bool) -> dict:
    """Today's settings against the chosen ones on subjects the search never saw: one row per
    subject and setting, and the chosen settings' paired gain over today's."""
    from mogaface.core.evaluate.seed_stats import paired_difference

    from .converge import ensure_capture

    rows = []
    for subject in subjects:
        capture, _ = ensure_capture(folder / f"test_capture_s{subject}", capture_settings(quick, subject))
        for label, settings in (("today", today), ("chosen", chosen)):
            run = trained_run(capture, folder / f"test_runs_s{subject}", settings, threads, steps)
            rows.append({"subject": subject, "settings": label, **settings, **tested_try(run, frames)})
            print(f"test subject {subject} {label}: novel view {rows[-1]['novel_view_psnr_db']:.3f} dB",
                  file=sys.stderr, flush=True)

    def column(label, key):
        return [row[key] for row in rows if row["settings"] == label]

    gains = {key: paired_difference(column("chosen", key), column("today", key))
             for key in ("novel_view_psnr_db", "self_reenactment_psnr_db", "rotation_deg")}
    return {"split": "test", "subjects": subjects, "rows": rows, "chosen_minus_today": gains}


def run(threads: int = 2, quick: bool = False, work: str | None = None, split: str = "validation",
        test_subjects: str | None = None) -> dict:
    from mogaface.core.errors import InputError
    from mogaface.core.train.config import CamerasSection

    from .converge import ensure_capture

    if split != "validation":
        raise InputError(None, "split", "settings are chosen on the validation frames only")
    subjects = parse_subjects(test_subjects) if test_subjects else []  # refused before any training
    folder = pathlib.Path(work or WORK)
    capture, made_s = ensure_capture(folder / "capture", capture_settings(quick))
    steps, frames = (QUICK["steps"], QUICK["frames"]) if quick else (STEPS, SCORED_FRAMES)
    grid = QUICK["grid"] if quick else CAMERA_GRID
    defaults = CamerasSection()
    start = {"rotation_lr": defaults.rotation_lr, "begin": defaults.begin, "gauge": defaults.gauge, "rounds": 3,
             **(QUICK["start"] if quick else {})}
    runs = folder / ("runs_quick" if quick else "runs")
    load_before = os.getloadavg()
    found = coordinate_search(grid, start, lambda settings: scored_try(
        trained_run(capture, runs, settings, threads, steps), frames), SEARCH_ROUNDS)
    test = test_table(folder, subjects, start, found["chosen"], threads, steps,
                      QUICK["frames"] if quick else None, quick) if subjects else None
    return {"split": "validation", "capture": str(capture), "capture_made_s": round(made_s, 1),
            "steps_per_round": steps, "scored_frames": frames, "threads": threads, "start": start, **found, "test": test,
            "load_average_before": [round(x, 2) for x in load_before],
            "load_average_after": [round(x, 2) for x in os.getloadavg()]}
