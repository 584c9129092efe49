"""The whole evaluation of a run: every protocol scored, the report written (``eval`` command)."""

from __future__ import annotations

import os
import pathlib
from collections.abc import Iterable

import numpy as np

from ..errors import InputError
from ..run.cameras import ScoringCameras
from ..run.folder import RunFolder
from ..train.camera_delays import delayed_views
from . import report
from .camera_alignment import split_frames
from .protocol_names import ALIGNED_PROTOCOLS
from .protocols import (
    PROTOCOLS,
    DrivenParams,
    ParamSource,
    TrackedParams,
    check_lpips_size,
    check_protocol,
    check_split,
    cross_identity,
    novel_view_aligned,
    novel_view_colour_aligned,
    protocol_frames,
    protocol_unavailable,
    run_protocol,
    score,
    scored_views,
)


def _mean(values: list[float]) -> float | None:
    """The mean (infinite when a PSNR is: identical images), None for no values."""
    return float(np.mean(values)) if values else None


def _summary(rows: list[dict], keys: tuple[str, ...]) -> dict:
    return {"frames": len(rows), **{k: _mean([r[k] for r in rows]) for k in keys}}


def evaluate_run(
    run_dir: str | os.PathLike,
    protocols: Iterable[str] = PROTOCOLS,
    max_frames: int | None = None,
    lpips: bool = True,
    *,
    driver: str | os.PathLike | None = None,
    out_dir: str | os.PathLike | None = None,
    capture: str | os.PathLike | None = None,
    comparisons: int = 3,
    progress: bool = False,
    avatar=None,
    source: ParamSource | None = None,
    driver_cameras: list[str] | None = None,
    split: str = "test",
) -> dict:
    """Score a run on the protocols; write ``metrics.json``, ``metrics.md`` and ``eval/`` images.

    Returns the metrics: per protocol the mean ``psnr``, ``ssim`` (and ``lpips``) with
    breakdowns per camera and per sequence. With ``driver`` (another capture), also renders
    the cross-identity reenactment (images only; ``driver_cameras`` of the run's capture, default
    all). Outputs go to ``out_dir`` (default: the run). ``avatar`` and ``source`` replace the
    run's avatar and :class:`TrackedParams`, e.g. for image-assisted inference. ``split``: the
    test frames (default) or the validation sequence's (``--split validation``: settings are chosen
    there, the test frames scored once with them).
    """
    from ..io.atomic import check_output_target, write_json, write_text
    from ..progress import ProgressBar

    run = RunFolder(run_dir, capture)
    protocols = [check_protocol(name) for name in protocols]
    check_split(split)
    out = pathlib.Path(out_dir) if out_dir is not None else run.root
    for place in (out, out / report.EVAL_DIR):  # before any scoring: a FIFO or device there is refused now
        check_output_target(place, folder=True)
    for name in ("metrics.json", "metrics.md"):
        check_output_target(out / name)
    cap = run.open_capture()
    if avatar is None and source is None:
        from .sources.corrected import run_inference

        avatar, source = run_inference(run, cap)  # MoGaFace runs: modules + image-assisted inference
        avatar, source = _with_refiner(run, cap, avatar, source)
    avatar = run.load_avatar() if avatar is None else avatar
    source = TrackedParams(cap, run, avatar.flame) if source is None else source
    shift = delayed_views(cap, avatar, run.delays_path)  # a run that learned its cameras' delays
    skipped = {name: reason for name in protocols if (reason := protocol_unavailable(cap, name, split)) is not None}
    if skipped and len(skipped) == len(protocols):
        raise InputError(cap.root, "protocols", "; ".join(f"{k}: {v}" for k, v in skipped.items()))
    plans = {name: protocol_frames(cap, name, max_frames, split) for name in protocols if name not in skipped}
    total = sum(len(split_frames(f)[1]) if name in ALIGNED_PROTOCOLS else len(f) for name, f in plans.items())
    bar = ProgressBar(total, "eval") if progress and total else None
    if lpips:
        check_lpips_size(cap)
    keys = ("psnr", "ssim", "lpips") if lpips else ("psnr", "ssim")
    result = {
        "run": str(run.root.resolve()),
        "capture": str(cap.root.resolve()),
        "background": list(run.background),
        "inference": getattr(source, "description", type(source).__name__),
        "scoring_cameras": ScoringCameras(cap).source,
        "split": split,
        "protocols": {},
        "skipped": skipped,
    }
    for name, frames in plans.items():
        rows, alignment, scored = [], None, []
        if name in ALIGNED_PROTOCOLS:
            align = novel_view_aligned if name == "novel_view_aligned" else novel_view_colour_aligned
            items, alignment = align(avatar, cap, source, run.background, frames)
        else:
            items = run_protocol(avatar, cap, source, frames, run.background, shift=shift)
        for index, item in enumerate(items):
            row = score(item, lpips)
            frame = item.frame
            scored.append(frame)
            rows.append({"timestep": frame.timestep_index, "camera": frame.camera_id, "sequence": frame.sequence, **row})
            if index < comparisons:
                stem = f"{name}_{frame.timestep_index:05d}_{frame.camera_id}"
                report.write_comparison(out / report.EVAL_DIR / f"{stem}.png", item)
            if bar:
                bar.update(note=name)
        summary = _summary(rows, keys)
        for field, group in (("camera", "per_camera"), ("sequence", "per_sequence")):
            values = sorted({r[field] for r in rows if r[field] is not None})
            summary[group] = {v: _summary([r for r in rows if r[field] == v], keys) for v in values}
        summary["per_frame"] = rows
        summary["scored"] = scored_views(cap, scored)
        if alignment is not None:
            summary["alignment"] = alignment
        result["protocols"][name] = summary
    if driver is not None:
        result["cross_identity"] = write_cross_identity(
            avatar, cap, run, driver, out / report.EVAL_DIR / "cross_identity", max_frames, progress, driver_cameras
        )
    write_json(out / "metrics.json", report.json_safe(result))
    write_text(out / "metrics.md", report.markdown_table(result))
    return result


def _with_refiner(run, capture, avatar, source):
    """A run with a refiner (``RUN/refiner.pt``) is scored with it as ``refine-tracking`` applies it
    (:class:`.sources.refined.RefinerInference`, its defaults): what is scored is what a user gets."""
    from ..run.cameras import InputCameras
    from .sources.base import training_cameras
    from .sources.refined import RefinerInference, run_refiner

    avatar = run.load_avatar() if avatar is None else avatar
    refiner = run_refiner(run.root, avatar)
    if refiner is None:
        return avatar, source
    return avatar, RefinerInference(avatar, capture, run, refiner, cameras=InputCameras.of_run(capture, run.root),
                                    input_cameras=training_cameras(capture))


def write_cross_identity(avatar, capture, run, driver, out: pathlib.Path, max_frames, progress, cameras=None) -> dict:
    """Render subject A (the run) driven by ``driver``'s tracked motion: PNGs and a strip, no metrics."""
    from ..data.capture import Capture
    from ..progress import ProgressBar

    driving = Capture.open(driver)
    identity = run.identity_params() or {
        k: v for k, v in capture.flame_params(capture.timesteps[0]).items() if k in ("shape", "static_offset")
    }
    source = DrivenParams(identity, driving, n_expr=avatar.flame.n_expr)
    cameras = list(capture.cameras) if cameras is None else list(cameras)
    count = len(cameras) * min(len(driving.timesteps), max_frames or len(driving.timesteps))
    bar = ProgressBar(count, "cross-identity") if progress else None
    images: dict[str, list[tuple[int, np.ndarray]]] = {c: [] for c in cameras}  # cross_identity checks the ids
    written = []
    for timestep, camera_id, rgb, _ in cross_identity(avatar, capture, source, run.background, cameras, max_frames):
        path = out / f"{timestep:05d}_{camera_id}.png"
        report.write_png(path, rgb)
        written.append(str(path))
        images[camera_id].append((timestep, rgb))
        if bar:
            bar.update()
    columns = max(len(v) for v in images.values())
    picks = np.unique(np.round(np.linspace(0, columns - 1, min(columns, report.STRIP_COLUMNS))).astype(int))
    strip = out / "strip.png"
    report.write_png(strip, report.strip_image([[row[i][1] for i in picks] for row in images.values()]))
    driver = str(pathlib.Path(driver).resolve())
    return {"driver": driver, "frames": len(written), "strip": str(strip), "images": written}
