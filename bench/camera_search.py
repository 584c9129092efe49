"""Choosing camera refinement's settings on validation frames.

``python -m mogaface bench camera_search [--subjects 0,1,2] [--work DIR]`` makes, per subject, a
capture whose cameras are off (as the camera tables' ``cap_cal``: 128², 48 timesteps, 1° and 5 mm
per axis; subject ``s`` with its own noise draw ``s``; made once, reused) and trains Freeze with
camera refinement (``--preset demo``, :data:`STEPS` steps a round) per setting tried and subject.
Each try is scored on the validation sequence's self-reenactment frames: the training cameras, at
their true poses as every camera score is, on frames no step trained on; the mean over the
subjects is what is chosen on (one subject's noise draw is not enough: a choice made on subject 0
alone lost on two others). The search goes one setting at a time from today's recommended
settings (three rounds, the config's rates, start and gauge), a new value kept only above
:data:`.refiner_search.MIN_GAIN_DB`. Each run folder stays in ``DIR`` (a stopped search resumes; a
wider grid or another subject trains only what is new), and each try's camera error against the
truth is reported beside its score, never chosen on.

``--test-subjects 3,4``: then the test table, measured once with what was chosen, on subjects no
choice was made on (a searched subject is refused): each trained with today's recommended
settings and with the chosen ones, scored on the test frames: novel view at the true held-out
camera (every frame, as ``eval --protocols novel_view`` scores it: the camera tables' number) and
self-reenactment of the unseen sequence, with the paired gain of the choice.
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
    """Subject ``s``'s capture, with its own noise draw ``s`` (camera and tracker errors)."""
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


def _camera_error(scores: dict) -> dict:
    """The refined cameras' error against the truth (``None`` for a run that kept its cameras)."""
    refined = scores["cameras"].get("refined", {})
    return {"rotation_deg": round(refined["rotation_deg"], 4) if refined else None,
            "position_mm": round(refined["position_mm"], 3) if refined else None}


def scored_try(run: pathlib.Path, frames: int) -> dict:
    """The run's validation self-reenactment scores (the tracked parameters, as Freeze renders) and
    its cameras' error against the truth."""
    from mogaface.core.workflows.ablation import score_variant

    scores = score_variant(run, frames, False, (), split="validation")
    tracked = scores["protocols"]["self_reenactment"]["tracked"]
    return {"psnr_db": round(tracked["psnr"], 4), "ssim": round(tracked["ssim"], 4), **_camera_error(scores),
            "calibrated_rotation_deg": round(scores["cameras"]["calibrated_refined_cameras"]["rotation_deg"], 4),
            "run": str(run)}


def tested_try(run: pathlib.Path, frames: int | None) -> dict:
    """The run's test scores: novel view at the true held-out camera, self-reenactment of the unseen
    sequence (the tracked parameters, as Freeze renders), and its cameras' error."""
    from mogaface.core.workflows.ablation import score_variant

    scores = score_variant(run, frames, False, (), split="test")
    protocols = scores["protocols"]
    return {"novel_view_psnr_db": round(protocols["novel_view"]["tracked"]["psnr"], 4),
            "self_reenactment_psnr_db": round(protocols["self_reenactment"]["tracked"]["psnr"], 4),
            **_camera_error(scores),
            "scored_frames": {name: len(views["frames"]) for name, views in scores["scored"].items()},
            "run": str(run)}


def parse_subjects(text: str, option: str) -> list[int]:
    """``"1,2"`` → ``[1, 2]``: distinct subject numbers from 0 up."""
    from mogaface.core.errors import InputError

    try:
        subjects = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise InputError(None, option, f"expected comma-separated subject numbers, got {text!r}") from None
    if not subjects or min(subjects) < 0 or len(set(subjects)) != len(subjects):
        raise InputError(None, option, f"expected distinct subject numbers from 0 up, got {text!r}")
    return subjects


class Subjects:
    """One capture and one folder of runs per subject, whatever the subject serves (the search or the
    test table), so a subject's run of a setting is trained once: subject 0 in ``capture`` and
    ``runs``, subject ``s`` in ``capture_s<s>`` and ``runs_s<s>`` (``_quick`` after each at the
    quick size)."""

    def __init__(self, folder: pathlib.Path, quick: bool, threads: int, steps: int):
        self.folder, self.quick, self.threads, self.steps = folder, quick, threads, steps
        self.captures: dict[int, pathlib.Path] = {}
        self.made_s: dict[int, float] = {}

    def _folder(self, kind: str, subject: int) -> pathlib.Path:
        return self.folder / (kind + (f"_s{subject}" if subject else "") + ("_quick" if self.quick else ""))

    def capture(self, subject: int) -> pathlib.Path:
        """The subject's capture, made (or checked) once per search."""
        from .converge import ensure_capture

        if subject not in self.captures:
            self.captures[subject], self.made_s[subject] = ensure_capture(
                self._folder("capture", subject), capture_settings(self.quick, subject))
        return self.captures[subject]

    def run(self, subject: int, settings: dict) -> pathlib.Path:
        return trained_run(self.capture(subject), self._folder("runs", subject), settings, self.threads, self.steps)


def searched_try(subjects: Subjects, search_subjects: list[int], settings: dict, frames: int) -> dict:
    """A setting's validation scores on every search subject, and their mean (what is chosen on)."""
    from mogaface.core.evaluate.seed_stats import mean_std

    each = [{"subject": s, **scored_try(subjects.run(s, settings), frames)} for s in search_subjects]
    means = {key: mean_std([t[key] for t in each])[0]
             for key in ("psnr_db", "ssim", "rotation_deg", "position_mm", "calibrated_rotation_deg")}
    return {**{key: None if m is None else round(m, 4) for key, m in means.items()}, "subjects": each}


def test_table(subjects: Subjects, test_subjects: list[int], today: dict, chosen: dict, frames: int | None) -> dict:
    """Today's settings against the chosen ones on subjects the search never saw: one row per
    subject and setting, and the chosen settings' paired gain over today's."""
    from mogaface.core.evaluate.seed_stats import paired_difference

    rows = []
    for subject in test_subjects:
        for label, settings in (("today", today), ("chosen", chosen)):
            rows.append({"subject": subject, "settings": label, **settings,
                         **tested_try(subjects.run(subject, settings), frames)})
            print(f"test subject {subject} {label}: novel view {rows[-1]['novel_view_psnr_db']:.3f} dB",
                  file=sys.stderr, flush=True)

    def column(label, key):
        return [row[key] for row in rows if row["settings"] == label]

    gains = {key: paired_difference(column("chosen", key), column("today", key))
             for key in ("novel_view_psnr_db", "self_reenactment_psnr_db", "rotation_deg")}
    return {"split": "test", "subjects": test_subjects, "rows": rows, "chosen_minus_today": gains}


def run(threads: int = 2, quick: bool = False, work: str | None = None, split: str = "validation",
        subjects: str | None = None, test_subjects: str | None = None) -> dict:
    from mogaface.core.errors import InputError
    from mogaface.core.train.config import CamerasSection

    if split != "validation":
        raise InputError(None, "split", "settings are chosen on the validation frames only")
    searched = parse_subjects(subjects or "0", "--subjects")  # refused before any training
    tested = parse_subjects(test_subjects, "--test-subjects") if test_subjects else []
    if seen := sorted(set(searched) & set(tested)):
        raise InputError(None, "--test-subjects", f"subject(s) {seen} are searched on: a test subject must be one "
                                                  "no choice was made on")
    steps, frames = (QUICK["steps"], QUICK["frames"]) if quick else (STEPS, SCORED_FRAMES)
    folders = Subjects(pathlib.Path(work or WORK), quick, threads, steps)
    grid = QUICK["grid"] if quick else CAMERA_GRID
    defaults = CamerasSection()
    start = {"rotation_lr": defaults.rotation_lr, "begin": defaults.begin, "gauge": defaults.gauge, "rounds": 3,
             **(QUICK["start"] if quick else {})}
    load_before = os.getloadavg()
    found = coordinate_search(grid, start, lambda settings: searched_try(folders, searched, settings, frames),
                              SEARCH_ROUNDS)
    test = test_table(folders, tested, start, found["chosen"], QUICK["frames"] if quick else None) if tested else None
    return {"split": "validation", "subjects": searched,
            "captures": {s: str(folders.capture(s)) for s in searched + tested},
            "capture_made_s": {s: round(t, 1) for s, t in folders.made_s.items()},
            "steps_per_round": steps, "scored_frames": frames, "threads": threads, "start": start, **found, "test": test,
            "load_average_before": [round(x, 2) for x in load_before],
            "load_average_after": [round(x, 2) for x in os.getloadavg()]}
