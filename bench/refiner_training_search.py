"""Choosing the refiner's training settings on validation frames: its feature grid and the rendered
offsets it learns from.

``python -m mogaface bench refiner_training_search --avatar RUN[,RUN…]`` trains a refiner per
setting tried (``RUN/refiner_tries/<setting>.pt``; the run's own ``refiner.pt`` is left alone) and
scores its one pass with the default inference settings on the validation sequence's
self-reenactment frames, exactly as ``bench refiner_search`` scores a try (the same frames, views
and gauge). The search goes one setting at a time from today's training defaults, two rounds, a
new value taken only above :data:`..refiner_search.MIN_GAIN_DB`; every try is kept beside the
others (``refiner_search_tries.json``, part "training") and a trained try is reused, so a wider
grid costs only its new refiners. The inference settings are then searched on the refiner trained
with the chosen settings (``bench refiner_search``). ``--quick``: a tiny refiner (a smoke run).
"""

from __future__ import annotations

import os

from .refiner_search import KeptTries, _evaluator, _Run, coordinate_search, settings_name

TRAINING_GRID = {"grid": (8, 12, 16, 24), "offsets_per_start": (2, 4, 8)}
TRAINING_ROUNDS = 2
TRIES_DIR = "refiner_tries"
QUICK = {"starts": 2, "gap_timesteps": 2, "curvature_timesteps": 1}


def refiner_settings(settings: dict, threads: int, quick: bool):
    """The :class:`RefinerSettings` of a try: its grid in the spec, its offsets per start."""
    from mogaface.core.refiner.training import RefinerSettings

    return RefinerSettings(offsets_per_start=settings["offsets_per_start"], threads=threads,
                           spec={"grid": settings["grid"]}, **(QUICK if quick else {}))


def trained_refiner(run: _Run, settings: dict, threads: int, quick: bool):
    """The run's refiner trained with ``settings`` (trained once, then read from its file)."""
    from mogaface.core.refiner.files import is_outdated, load_refiner
    from mogaface.core.refiner.training import train_refiner

    name = settings_name(settings) + ("_quick" if quick else "")
    path = run.folder.root / TRIES_DIR / f"{name}.pt"
    if not path.is_file() or is_outdated(path):
        train_refiner(run.folder.root, refiner_settings(settings, threads, quick), out=path)
    return load_refiner(path, run.avatar.flame.n_expr)[0]


def refiner_source(run: _Run, settings: dict, threads: int, quick: bool):
    """The one pass of the refiner trained with ``settings``, and the frames it is scored on."""
    from mogaface.core.evaluate.sources.base import INPUT_VIEWS
    from mogaface.core.evaluate.sources.refined import RefinedParams

    return RefinedParams(run.avatar, run.capture, run.start, trained_refiner(run, settings, threads, quick),
                         run.folder.background, 1, max_views=INPUT_VIEWS, **run.views), run.frames


def run(threads: int = 2, quick: bool = False, avatar: str | None = None, split: str = "validation") -> dict:
    import torch

    from mogaface.core.errors import InputError
    from mogaface.core.evaluate.protocols import scored_views
    from mogaface.core.refiner.training import DEFAULT_SPEC, RefinerSettings

    if split != "validation":
        raise InputError(None, "split", "settings are chosen on the validation frames only; the test frames are "
                                        "scored once, by 'bench refiner'")
    torch.set_num_threads(threads)
    runs = [_Run(root, 4 if quick else 12, 1, needs_refiner=False) for root in (avatar or "out/demo/run").split(",") if root]
    kept = KeptTries(runs)
    part = "training_quick" if quick else "training"
    load_before = os.getloadavg()
    start = {"grid": DEFAULT_SPEC["grid"], "offsets_per_start": RefinerSettings().offsets_per_start}
    evaluate = kept.evaluator(part, _evaluator(runs, lambda one, settings: refiner_source(one, settings, threads,
                                                                                         quick)))
    found = coordinate_search(TRAINING_GRID, start, evaluate, TRAINING_ROUNDS, known=kept.parts[part])
    return {
        "split": "validation", "runs": [str(r.folder.root) for r in runs],
        "scored": [scored_views(r.capture, r.frames) for r in runs], "threads": threads,
        "kept_tries": str(kept.path), "refiners": [str(r.folder.root / TRIES_DIR) for r in runs],
        "training": {"defaults": start, **found},
        "load_average_before": [round(x, 2) for x in load_before],
        "load_average_after": [round(x, 2) for x in os.getloadavg()],
    }
