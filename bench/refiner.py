"""The multi-view refiner against test-time fitting on the same unseen frames: seconds per frame
(the source's own time, not the render that scores it), their ratio, and what each buys in PSNR
over the tracked parameters, in one run so the ratio holds however loaded the machine is.

``python -m mogaface bench refiner --avatar RUN`` (a run folder with ``refiner.pt``, from
``train-refiner``) prints JSON with the load average. Frames: the self-reenactment protocol (the
unseen sequence, every scored view left out of the sources' inputs), 12 spread over it (4 with
``--quick``; ``--split validation``: of the validation sequence instead, where settings are
chosen); the report names them and the cameras they are scored on (``scored``). The refiner
and fitting read the same views of each frame (``input_views``; :func:`..core.evaluate.benchmark.
standard_sources`). Every source computes one frame untimed before the timed ones, so first calls
and first disk reads are no source's time.

``--fit-steps 10,30,100`` (the default) times fitting at each length, for its curve of PSNR against
time; ``equal_quality`` sets each refiner's time against the fitting length that reaches the same
PSNR (interpolated in log-steps between the measured lengths; "not reached" when the refiner beats
the longest), beside the ratios at the fixed lengths.

On synthetic captures every source also gets its mesh and expression errors (mm) against the raw
truth and in the avatar's gauge (the truth plus the run's mean offset from it on training
timesteps, :func:`..core.evaluate.expression_error.truth_gauge`), and the truth itself is scored
both ways: ``true`` (raw) and ``true_gauge``, the image ceiling of a correction.

``--avatar RUN,RUN,…`` benchmarks several runs (each report kept in its run folder and reused,
:func:`cached_report`) and adds the table over them by subject (:mod:`.refiner_table`): the
``markdown`` of the results page, also written beside ``--out`` as ``.md``.
"""

from __future__ import annotations

import os

# tracked_aligned: runs that fine-tuned; refined_fit_N: N fitting steps (the first of fit_steps) from
# the refiner's one pass on the timesteps training did not fit (`refine-tracking --fit-steps N`)
PASSES = (1, 3)
FIT_STEPS = (10, 30, 100)
PARAMETER_ERRORS = ("vertex_mm", "expr_vertex_mm", "vertex_mm_gauge", "expr_vertex_mm_gauge")
REPORT_FILE = "bench_refiner.json"


def _warm_up_frame(capture, frames, split):
    """A frame of the protocol that is not scored, at a timestep none of ``frames`` has where there
    is one (its views are then read for the first time when they are timed), else the first."""
    from mogaface.core.evaluate.protocols import protocol_frames

    timesteps = {f.timestep_index for f in frames}
    spare = [f for f in protocol_frames(capture, "self_reenactment", split=split) if f not in frames]
    elsewhere = [f for f in spare if f.timestep_index not in timesteps]
    return (elsewhere or spare or frames)[0]


def _equal_quality(scores: dict, fit_steps) -> dict:
    """Per refiner source: the fitting length of the same PSNR, fitting's time there, the ratio."""
    from mogaface.core.evaluate.benchmark import matching_fit_length, seconds_at_length

    psnr = {steps: scores[f"fit_{steps}"]["psnr"] for steps in fit_steps}
    seconds = {steps: scores[f"fit_{steps}"]["source_s"] for steps in fit_steps}
    out = {}
    for passes in PASSES:
        refined = scores.get(f"refined_{passes}")
        if refined is None:
            continue
        match = matching_fit_length(psnr, refined["psnr"])
        entry = {"psnr_db": round(refined["psnr"], 3), "fit_steps": None, "status": match["status"],
                 "fit_seconds_per_frame": None, "fitting_time_over_refiner": None}
        if match["steps"] is not None:
            fit_seconds = seconds_at_length(seconds, match["steps"])
            entry.update(fit_steps=round(match["steps"], 1), fit_seconds_per_frame=round(fit_seconds, 4),
                         fitting_time_over_refiner=round(fit_seconds / max(refined["source_s"], 1e-9), 2))
        out[f"refined_{passes}"] = entry
    return out


def _input_views(sources: dict, names) -> dict:
    """Per image-reading source, the cameras it read for each scored frame (``scored camera``: …)."""
    out = {}
    for name in names:
        inputs = getattr(sources.get(name), "inputs", None)
        if inputs:
            out[name] = [{"scored": scored, "read": list(read)} for scored, read in inputs]
    return out


def report(folder, threads: int = 2, quick: bool = False, fit_steps: tuple[int, ...] = FIT_STEPS,
           split: str = "test") -> dict:
    """One run's comparison (the module docstring): images, parameter errors, seconds, ratios."""
    import torch

    from mogaface.core.errors import InputError
    from mogaface.core.evaluate.benchmark import run_gauge, score_source, standard_sources
    from mogaface.core.evaluate.protocols import protocol_frames, scored_views
    from mogaface.core.refiner.files import REFINER_FILE

    torch.set_num_threads(threads)
    if not (folder.root / REFINER_FILE).exists():
        raise InputError(folder.root / REFINER_FILE, None, "no refiner: run 'train-refiner RUN' first")
    capture = folder.open_capture()
    trained = folder.load_avatar()
    fit_steps = tuple(sorted(set(fit_steps)))
    sources = standard_sources(folder, capture, trained, fit_steps=fit_steps, refiner_passes=PASSES)
    names = [name for name in ["tracked", "tracked_aligned", *(f"refined_{k}" for k in PASSES),
                               *(f"fit_{n}" for n in fit_steps), f"refined_fit_{fit_steps[0]}", "true", "true_gauge"]
             if name in sources]
    frames = protocol_frames(capture, "self_reenactment", 4 if quick else 12, split)
    warm = _warm_up_frame(capture, frames, split)
    for name in names:  # untimed: first calls, first reads of the capture and the run
        sources[name].params_for(warm, exclude_view=warm.camera_id)
        getattr(sources[name], "inputs", []).clear()
    gauge = run_gauge(folder, capture)
    load_before = os.getloadavg()
    scores = {name: score_source(trained, capture, sources[name], frames, folder.background, lpips=False, gauge=gauge)
              for name in names}
    tracked = scores["tracked"]["psnr"]
    return {
        "run": str(folder.root), "capture": str(capture.root), "subject": _subject(capture),
        "frames": len(frames), "threads": threads, "split": split,
        "scored": scored_views(capture, frames),
        "warm_up_frame": f"{warm.timestep_id}/{warm.camera_id}",
        "fit_steps": list(fit_steps),
        "sources": {name: sources[name].description for name in names if hasattr(sources[name], "description")},
        "seconds_per_frame": {name: round(s["source_s"], 4) for name, s in scores.items()},
        "psnr_db": {name: round(s["psnr"], 3) for name, s in scores.items()},
        "psnr_gain_over_tracked_db": {name: round(s["psnr"] - tracked, 3) for name, s in scores.items()},
        "parameter_errors_mm": {name: {key: round(s[key], 4) for key in PARAMETER_ERRORS if s.get(key) is not None}
                                for name, s in scores.items()},
        "fitting_time_over_refiner": {
            f"fit_{steps}/refined_{passes}": round(
                scores[f"fit_{steps}"]["source_s"] / max(scores[f"refined_{passes}"]["source_s"], 1e-9), 2)
            for steps in fit_steps for passes in PASSES if f"refined_{passes}" in scores},
        "equal_quality": _equal_quality(scores, fit_steps),
        "input_views": _input_views(sources, names),
        "load_average_before": [round(x, 2) for x in load_before],
        "load_average_after": [round(x, 2) for x in os.getloadavg()],
    }


def _subject(capture) -> dict:
    """Which procedural subject and tracker-error draw a synthetic capture is (empty otherwise)."""
    from mogaface.core.data.capture_info import capture_info

    settings = capture_info(capture.root).get("settings") or {}
    return {key: settings[key] for key in ("subject", "seed") if isinstance(settings, dict) and key in settings}


def cached_report(folder, threads: int, quick: bool, fit_steps, split: str) -> dict:
    """:func:`report`, kept in the run folder (``bench_refiner.json``; ``_validation`` for that
    split) and reused while the scoring code, this module, the refiner file and the options are
    unchanged: a table over many runs can be stopped and taken up again."""
    import hashlib
    import json
    import pathlib

    from mogaface.core.evaluate.benchmark import scoring_code_hash
    from mogaface.core.io.atomic import write_json
    from mogaface.core.refiner.files import REFINER_FILE
    from mogaface.core.workflows.ablation import split_name

    path = folder.root / split_name(REPORT_FILE, split)
    code = scoring_code_hash() + hashlib.sha256(pathlib.Path(__file__).read_bytes()).hexdigest()  # and this report's
    key = {"code": hashlib.sha256(code.encode()).hexdigest(),
           "refiner": hashlib.sha256((folder.root / REFINER_FILE).read_bytes()).hexdigest(),
           "threads": threads, "quick": quick, "fit_steps": sorted(set(fit_steps)), "split": split}
    if path.is_file():
        try:
            kept = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            kept = None
        if isinstance(kept, dict) and kept.get("key") == key:
            return kept["report"]
    result = report(folder, threads, quick, fit_steps, split)
    write_json(path, {"key": key, "report": result})
    return result


def run(threads: int = 2, quick: bool = False, avatar: str | None = None,
        fit_steps: tuple[int, ...] = FIT_STEPS, split: str = "test") -> dict:
    """One run (``--avatar RUN``): its report. Several (``--avatar RUN,RUN,…``): each run's report
    (kept in its folder, :func:`cached_report`) and the table over them, grouped by subject
    (:mod:`.refiner_table`)."""
    from mogaface.core.run.folder import RunFolder

    from .refiner_table import summary_table

    roots = [part for part in (avatar or "out/demo/run").split(",") if part]
    if len(roots) == 1:
        return report(RunFolder(roots[0]), threads, quick, fit_steps, split)
    reports = [cached_report(RunFolder(root), threads, quick, fit_steps, split) for root in roots]
    return {"runs": reports, **summary_table(reports)}
