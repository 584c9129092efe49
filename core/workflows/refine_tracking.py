"""A capture's tracking improved by a run's refiner: every timestep refined from its views
(optionally then fitted to them from there) and written as ``flame_param`` files in the capture's
own layout, so Blender's Import Tracking and ``render --params`` read them like the tracker's.

The output folder (default ``RUN/refined_tracking``) holds the capture's ``flame_param`` paths
(``flame_param/00042.npz``; each sequence's own folder in a union capture) and
``refined_tracking.json`` (what was done, from what). It is written under a temporary name and
renamed when complete: a cancelled or failed job leaves the previous result as it was. A run
without a refiner, or with one of an earlier version, gets one first
(:func:`..refiner.training.train_refiner`, its stages reported as usual).
"""

from __future__ import annotations

import os
import pathlib
import shutil
import time

from ..data import layout
from ..errors import InputError
from ..evaluate.expression_error import tracking_errors
from ..evaluate.sources.refined import RefinerInference, run_refiner
from ..evaluate.sources.tracked import TrackedParams
from ..io.atomic import check_output_target, write_json
from ..io.npz import save_npz
from ..refiner.files import REFINER_FILE, is_outdated
from ..refiner.training import RefinerSettings, frozen_avatar, train_refiner
from ..run.cameras import InputCameras
from ..run.folder import RunFolder

REFINED_TRACKING_DIR = "refined_tracking"
RECORD_FILE = "refined_tracking.json"


def _staging(out: pathlib.Path, suffix: str) -> pathlib.Path:
    """A hidden sibling of ``out``, emptied of what a killed job may have left there."""
    path = out.with_name(f".{out.name}.{suffix}")
    if path.is_dir():
        shutil.rmtree(path)
    else:
        path.unlink(missing_ok=True)
    return path


def _check_replaceable(out: pathlib.Path) -> None:
    """Only a folder this command wrote (or none) is replaced: never a user's own folder."""
    if out.exists() and not (out / RECORD_FILE).is_file():
        raise InputError(out, None, f"exists and is not a refined tracking folder (no {RECORD_FILE}): "
                                    "choose another output folder")


def _replace(staging: pathlib.Path, out: pathlib.Path) -> None:
    previous = _staging(out, "previous")
    if out.exists():
        os.replace(out, previous)
    os.replace(staging, out)
    shutil.rmtree(previous, ignore_errors=True)


def _train_first(run_root: pathlib.Path, settings: RefinerSettings, listeners, should_stop) -> None:
    """Train the run's refiner; one stopped half-way is dropped (it would lack the capture gap)."""
    partial = _staging(run_root / REFINER_FILE, "partial")
    try:
        train_refiner(run_root, settings, out=partial, listeners=listeners, should_stop=should_stop)
        if not should_stop():
            check_output_target(run_root / REFINER_FILE)  # a file, or nothing: never a device or FIFO
            os.replace(partial, run_root / REFINER_FILE)
    finally:
        partial.unlink(missing_ok=True)


def refine_tracking(run_dir, out=None, capture=None, passes: int = 1, views: int = 4, fit_steps: int = 0,
                    threads: int = 2, refiner_settings: RefinerSettings | None = None, listeners=(),
                    should_stop=lambda: False) -> dict:
    """Refine every timestep of the run's capture (``capture``: that capture, moved); returns what
    was written.

    ``passes``, ``views`` and ``fit_steps`` are those of
    :class:`..evaluate.sources.refined.RefinerInference`: the refiner on every timestep (``views``
    spread over the rig), then, with ``fit_steps``, fitting to all the views of each timestep whose
    parameters training did not fit (three times slower; docs/notebook/2026-11-26-multiview-refiner.md).
    Events: the
    refiner's own when it is trained first, then ``iter`` with ``stage="frames"`` per timestep,
    then ``done`` (or ``stopped`` when ``should_stop`` said so).
    """
    import torch

    if passes < 1 or views < 1:
        raise InputError(None, "passes" if passes < 1 else "views", "must be at least 1")
    if fit_steps < 0:
        raise InputError(None, "fit_steps", "must be 0 (no fitting) or more")

    where = {"stage": "frames", "step": 0, "steps": 0}  # the last progress, for a stop

    def emit(event: str, **fields):
        if event in ("start", "iter"):
            where.update({k: fields[k] for k in where})
        for listener in listeners:
            listener({"event": event, **fields})

    run = RunFolder(run_dir, capture)
    out = pathlib.Path(out) if out is not None else run.root / REFINED_TRACKING_DIR
    _check_replaceable(out)
    cap = run.open_capture()
    if not (run.root / REFINER_FILE).exists() or is_outdated(run.root / REFINER_FILE):
        def stage_progress(event):  # its stages' steps; its start and done are not this job's
            if event["event"] == "iter":
                emit(**{**event, "stage": f"refiner {event['stage']}"})

        _train_first(run.root, refiner_settings or RefinerSettings(threads=threads), [stage_progress], should_stop)
    torch.set_num_threads(threads)
    if should_stop():  # while the refiner trained
        emit("stopped", **where)
        return {"state": "stopped", "path": str(out)}
    avatar = frozen_avatar(run.root)
    refiner = run_refiner(run.root, avatar)
    source = RefinerInference(avatar, cap, run, refiner, passes=passes, views=views, fit_steps=fit_steps,
                              cameras=InputCameras.of_run(cap, run.root))
    staging = _staging(out, "partial")
    began, folders, refined = time.perf_counter(), set(), {}
    steps = len(cap.timesteps)
    emit("start", step=0, steps=steps, stage="frames", timesteps=steps)
    try:
        for index, timestep in enumerate(cap.timesteps):
            if should_stop():
                emit("stopped", **where)
                return {"state": "stopped", "path": str(out)}
            relative = cap.path(cap.timestep_frame(timestep), "flame_param_path").relative_to(cap.root)
            params = refined[timestep] = source.params_for(timestep)
            save_npz(staging / relative, layout.batched_flame_params(params))
            folders.add(relative.parent.as_posix())
            elapsed = time.perf_counter() - began
            emit("iter", step=index + 1, steps=steps, stage="frames",
                 eta_s=elapsed / (index + 1) * (steps - index - 1))
        fitted_count = sum(source.fits(t) for t in cap.timesteps)
        record = {"run": str(run.root.resolve()), "capture": str(cap.root.resolve()), "passes": passes,
                  "views": views, "fit_steps": fit_steps, "fitted_timesteps": fitted_count, "timesteps": steps,
                  "folders": sorted(folders), "seconds": time.perf_counter() - began}
        errors = tracking_errors(run, cap, {"tracked": TrackedParams(cap, run).params_for,
                                            "start": source.start.params_for, "refined": refined.__getitem__})
        if errors is not None:  # a synthetic capture: how far from the truth, before and after
            record["truth_errors"] = errors
        write_json(staging / RECORD_FILE, record)
        _replace(staging, out)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    result = {"state": "done", "path": str(out), **record, "folders": [str(out / f) for f in record["folders"]]}
    emit("done", step=steps, steps=steps, stage="frames", path=str(out), folders=result["folders"],
         seconds=record["seconds"], truth_errors=record.get("truth_errors"))
    return result
