"""Choosing the refiner's and test-time fitting's settings on validation frames, never on test frames.

``python -m mogaface bench refiner_search --avatar RUN[,RUN…]`` (runs with ``refiner.pt``) scores
self-reenactment frames of the validation sequence (``capture_info.json``'s ``val_sequence``; 12
per run for the refiner, 8 for fitting, 4 with ``--quick``; the scored view never an input) for
each setting it tries, and prints every setting tried with its score (also a line on stderr as it
goes): mean PSNR over the runs, each run's, and the mesh and expression errors raw and in the
avatar's gauge. ``bench refiner`` then scores the test frames once.

The search goes one setting at a time from the current defaults (coordinate descent, two rounds
for the refiner, one for fitting, whose every try costs 30 fitting steps a frame). Every try is
kept in the first run's folder (``refiner_search_tries.json``) and reused by a later search over
the same runs and scoring code, so widening a grid costs only the new tries. A new value is
taken only when it raises the mean PSNR by more than :data:`MIN_GAIN_DB`: smaller gains are within
what other frames would move, and the incumbent keeps its place.

The refiner's inference settings (prior, gap rank, full-size steps, damping) are searched on the
trained refiner (:meth:`mogaface.core.refiner.model.LinearRefiner.with_settings`); its training
settings (grid, offsets) need a refiner trained per try: ``bench refiner_training_search``. Fitting's
step sizes (the prior's width over a divisor) and its prior weight are searched at 30 steps.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys

MIN_GAIN_DB = 0.05
REFINER_GRID = {"prior": (8.0, 16.0, 32.0, 64.0, 128.0), "gap_rank": (0, 1, 2, 4),
                "full_size_steps": (0, 1, 2, 3, 4, 5), "damping": (1e-5, 3e-5, 1e-4, 3e-4)}
FIT_GRID = {"rate_divisor": (2.5, 5.0, 10.0), "prior_weight": (0.0, 1e-5, 1e-4, 1e-3, 1e-2)}
FIT_SEARCH_STEPS = 30
REFINER_ROUNDS, FIT_ROUNDS = 2, 1
TRIES_FILE = "refiner_search_tries.json"  # in the first run's folder: every try's score, for a later search
TRY_VERSION = 1  # how a try is scored (the frames, the sources' inputs): a change makes kept tries stale


class _Run:
    """What scoring one setting on one run needs, loaded once."""

    def __init__(self, root, frames: int, fit_frames: int, needs_refiner: bool = True):
        from mogaface.core.evaluate.benchmark import run_gauge
        from mogaface.core.evaluate.protocols import protocol_frames
        from mogaface.core.evaluate.sources.base import training_cameras
        from mogaface.core.evaluate.sources.refined import run_refiner
        from mogaface.core.evaluate.sources.tracked import AlignedTrackedParams
        from mogaface.core.refiner.training import frozen_avatar
        from mogaface.core.run.cameras import InputCameras
        from mogaface.core.run.folder import RunFolder

        self.folder = RunFolder(root)
        self.capture = self.folder.open_capture()
        self.avatar = frozen_avatar(self.folder.root)
        self.refiner = run_refiner(self.folder.root, self.avatar)
        if self.refiner is None and needs_refiner:
            from mogaface.core.errors import InputError

            raise InputError(self.folder.root / "refiner.pt", None, "no refiner: run 'train-refiner RUN' first")
        self.start = AlignedTrackedParams(self.capture, self.folder)
        self.views = {"cameras": InputCameras.of_run(self.capture, self.folder.root),
                      "input_cameras": training_cameras(self.capture)}
        self.frames = protocol_frames(self.capture, "self_reenactment", frames, "validation")
        self.fit_frames = protocol_frames(self.capture, "self_reenactment", fit_frames, "validation")
        self.gauge = run_gauge(self.folder, self.capture)

    def score(self, source, frames) -> dict:
        from mogaface.core.evaluate.benchmark import score_source

        scores = score_source(self.avatar, self.capture, source, frames, self.folder.background,
                              lpips=False, gauge=self.gauge)
        return {k: round(v, 4) for k, v in scores.items() if k != "frames" and v is not None}

    def refiner_source(self, settings: dict):
        """The refiner with ``settings``, and the frames it is scored on."""
        from mogaface.core.evaluate.sources.base import INPUT_VIEWS
        from mogaface.core.evaluate.sources.refined import RefinedParams

        return RefinedParams(self.avatar, self.capture, self.start, self.refiner.with_settings(**settings),
                             self.folder.background, 1, max_views=INPUT_VIEWS, **self.views), self.frames

    def fit_source(self, settings: dict):
        """Fitting with ``settings``, and the frames it is scored on."""
        from mogaface.core.evaluate.sources.base import INPUT_VIEWS
        from mogaface.core.evaluate.sources.fitted import PRIOR_SIGMA, FittedParams

        rates = {k: v / settings["rate_divisor"] for k, v in PRIOR_SIGMA.items()}
        return FittedParams(self.avatar, self.capture, self.start, FIT_SEARCH_STEPS, self.folder.background,
                            rates=rates, prior_weight=settings["prior_weight"], views=INPUT_VIEWS, **self.views
                            ), self.fit_frames


def settings_key(settings: dict) -> str:
    return json.dumps(settings, sort_keys=True)


def _shown(value) -> str:
    return f"{value:g}" if isinstance(value, (int, float)) else str(value)


def settings_name(settings: dict) -> str:
    """A try's settings as a file name (``grid16_offsets_per_start4``; a word value after a dash)."""
    return "_".join(f"{k}{_shown(v)}" if isinstance(v, (int, float)) else f"{k}-{v}" for k, v in sorted(settings.items()))


def coordinate_search(grid: dict, start: dict, evaluate, rounds: int, min_gain: float = MIN_GAIN_DB,
                      known: dict | None = None) -> dict:
    """``{"chosen", "tried"}``: one setting at a time over ``grid`` from ``start``, keeping a value
    only when ``evaluate(settings)["psnr_db"]`` beats the incumbent's by more than ``min_gain``.
    Each setting is evaluated once (``tried`` in the order tried); ``known`` (:func:`settings_key`
    → an earlier result) is used instead of evaluating again and gains the new results."""
    tried: dict[str, dict] = {}
    known = {} if known is None else known

    def score(settings: dict) -> float:
        key = settings_key(settings)
        if key not in tried:
            reused = key in known
            if not reused:
                known[key] = evaluate(settings)  # (an evaluate that keeps its results may have stored it already)
            tried[key] = {"settings": dict(settings), **known[key], "reused": reused}
            shown = " ".join(f"{k}={_shown(v)}" for k, v in settings.items())
            print(f"{'kept' if reused else 'tried'} {shown}: {tried[key]['psnr_db']:.3f} dB", file=sys.stderr, flush=True)
        return tried[key]["psnr_db"]

    current = dict(start)
    best = score(current)
    for _ in range(rounds):
        changed = False
        for name, values in grid.items():
            for value in values:
                candidate = {**current, name: value}
                candidate_score = score(candidate)
                if candidate_score > best + min_gain:
                    current, best, changed = candidate, candidate_score, True
        if not changed:
            break
    return {"chosen": current, "chosen_psnr_db": best, "tried": list(tried.values())}


def _evaluator(runs: list[_Run], make_source):
    def evaluate(settings: dict) -> dict:
        per_run = [run.score(*make_source(run, settings)) for run in runs]
        keys = [k for k in per_run[0] if all(k in r for r in per_run)]
        means = {k: round(sum(r[k] for r in per_run) / len(per_run), 4) for k in keys}
        return {"psnr_db": means.pop("psnr"), "mean": means, "per_run_psnr_db": [r["psnr"] for r in per_run]}

    return evaluate


def _file_hash(path) -> str | None:
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else None


class KeptTries:
    """Every try's result in the first run's folder (:data:`TRIES_FILE`), reused by a later search
    over the same runs, frames and scoring code (a grid made wider evaluates only what is new);
    written after each new try, so a stopped search loses nothing. The tries of searches over other
    runs, frames or code stay in the file beside them (a search over one run does not wipe the one
    over two)."""

    def __init__(self, runs: list[_Run]):
        from mogaface.core.evaluate.benchmark import scoring_code_hash
        from mogaface.core.refiner.files import REFINER_FILE

        self.path = runs[0].folder.root / TRIES_FILE
        self.key = {"code": scoring_code_hash(), "version": TRY_VERSION, "fit_steps": FIT_SEARCH_STEPS,
                    "runs": [[str(r.folder.root), _file_hash(r.folder.root / REFINER_FILE), len(r.frames),
                              len(r.fit_frames)] for r in runs]}
        self.parts = {"refiner": {}, "fitting": {}}  # and whatever other searches keep here
        self.others: list[dict] = []  # the other searches' entries, written back as they were
        try:
            kept = json.loads(self.path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            kept = None
        entries = kept.get("searches", [kept]) if isinstance(kept, dict) else []  # [kept]: the one-search layout
        for entry in entries if isinstance(entries, list) else []:
            if not (isinstance(entry, dict) and isinstance(entry.get("parts"), dict)):
                continue
            if entry.get("key") == self.key:
                self.parts.update({k: dict(v) for k, v in entry["parts"].items() if isinstance(v, dict)})
            else:
                self.others.append(entry)

    def evaluator(self, part: str, evaluate):
        from mogaface.core.io.atomic import write_json

        self.parts.setdefault(part, {})

        def evaluate_and_keep(settings: dict) -> dict:
            result = evaluate(settings)
            self.parts[part][settings_key(settings)] = result
            write_json(self.path, {"searches": [*self.others, {"key": self.key, "parts": self.parts}]})
            return result

        return evaluate_and_keep


def run(threads: int = 2, quick: bool = False, avatar: str | None = None, split: str = "validation") -> dict:
    import torch

    from mogaface.core.errors import InputError
    from mogaface.core.evaluate.protocols import scored_views
    from mogaface.core.evaluate.sources.fitted import PRIOR_SIGMA, PRIOR_WEIGHT, RATES
    from mogaface.core.refiner.training import DEFAULT_SPEC

    if split != "validation":
        raise InputError(None, "split", "settings are chosen on the validation frames only; the test frames are "
                                        "scored once, by 'bench refiner'")
    torch.set_num_threads(threads)
    runs = [_Run(root, 4 if quick else 12, 4 if quick else 8) for root in (avatar or "out/demo/run").split(",") if root]
    kept = KeptTries(runs)
    load_before = os.getloadavg()
    refiner_start = {k: DEFAULT_SPEC[k] for k in REFINER_GRID}
    refiner = coordinate_search(REFINER_GRID, refiner_start,
                                kept.evaluator("refiner", _evaluator(runs, lambda run, s: run.refiner_source(s))),
                                REFINER_ROUNDS, known=kept.parts["refiner"])
    fit_start = {"rate_divisor": round(PRIOR_SIGMA["expr"] / RATES["expr"], 6), "prior_weight": PRIOR_WEIGHT}
    fitting = coordinate_search(FIT_GRID, fit_start,
                                kept.evaluator("fitting", _evaluator(runs, lambda run, s: run.fit_source(s))),
                                FIT_ROUNDS, known=kept.parts["fitting"])
    return {
        "split": "validation", "runs": [str(r.folder.root) for r in runs],
        "scored": [scored_views(r.capture, r.frames) for r in runs],
        "scored_by_fitting": [scored_views(r.capture, r.fit_frames) for r in runs],
        "min_gain_db": MIN_GAIN_DB, "threads": threads, "kept_tries": str(kept.path),
        "refiner": {"defaults": refiner_start, **refiner},
        "fitting": {"steps": FIT_SEARCH_STEPS, "defaults": fit_start, **fitting},
        "load_average_before": [round(x, 2) for x in load_before],
        "load_average_after": [round(x, 2) for x in os.getloadavg()],
    }
