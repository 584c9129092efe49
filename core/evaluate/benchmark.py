"""Every parameter source of one run on the protocols: images and parameters against the truth.

The benchmark an image-driven correction is measured on: on the held-out sequence (frames no
training step saw) and on the held-out camera, each source's parameters are scored as images
(PSNR, SSIM, LPIPS of the self-reenactment / novel-view render) and, on synthetic captures, against
the true parameters (expression RMSE, expression-only and whole-mesh vertex error in mm), with the
time per frame. The standard sources are the tracked parameters, their temporal smoothing, test-time
fitting at two step counts, the method's own image-assisted inference and the truth (the ceiling).
"""

from __future__ import annotations

import hashlib
import math
import pathlib

import numpy as np

from ..errors import InputError
from ..run.folder import RunFolder
from .expression_error import frame_errors
from .protocols import (
    PROTOCOLS,
    check_lpips_size,
    check_split,
    protocol_frames,
    protocol_unavailable,
    run_protocol,
    score,
    scored_views,
)
from .sources.base import ParamSource

FIT_STEPS = (10, 30)
REFINER_PASSES = (1, 3)
IMAGE_METRICS = ("psnr", "ssim", "lpips")
PARAMETER_METRICS = ("expr_rmse", "expr_vertex_mm", "vertex_mm", "expr_vertex_mm_gauge", "vertex_mm_gauge")
# The code that decides a score, relative to the package's core/: the protocols, metrics, the
# scoring cameras and images, every parameter source and the refiner's inference. Scores kept on
# disk are stale once any of these files changes (:func:`scoring_code_hash`).
SCORING_CODE = ("evaluate/benchmark.py", "evaluate/protocols.py", "metrics/images.py", "metrics/lpips_alex.py",
                "avatar/avatar.py", "evaluate/expression_error.py", "evaluate/camera_error.py",
                "evaluate/sources/*.py", "refiner/*.py", "data/target.py", "data/camera_file.py", "run/cameras.py")
CORE = pathlib.Path(__file__).resolve().parents[1]


def scoring_code_hash(patterns=None, root: pathlib.Path | None = None) -> str:
    """SHA-256 over the names and bytes of the scoring code's files (:data:`SCORING_CODE` under
    :data:`CORE`): a cache of scores keyed by it is invalidated by any edit of the code that
    computed them."""
    patterns = SCORING_CODE if patterns is None else patterns
    root = CORE if root is None else pathlib.Path(root)
    digest = hashlib.sha256()
    for pattern in patterns:
        files = sorted(root.glob(pattern))
        if not files:
            raise FileNotFoundError(f"no scoring code matches {root / pattern}")
        for path in files:
            digest.update(path.relative_to(root).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def standard_sources(run: RunFolder, capture, avatar, fit_steps=FIT_STEPS,
                     refiner_passes=REFINER_PASSES) -> dict[str, ParamSource]:
    """name → source, in table order: tracked, tracked_aligned (runs that fine-tuned their
    parameters), smoothed, fit_N…, refined_K… and refined_fit_N (runs with a refiner; the refiner's
    one pass, then fitting from there where training did not fit, as ``refine-tracking`` does),
    method (MoGaFace runs), true, and true_gauge (the truth in the avatar's gauge, the image
    ceiling; :func:`.expression_error.truth_gauge`). Fitting and the refiner start from the aligned tracked parameters
    (:class:`.sources.tracked.AlignedTrackedParams`) and read the same views: per frame
    :data:`.sources.base.INPUT_VIEWS` other views of the training cameras, spread over the rig (the
    held-out camera's images are the novel-view protocols' to score, never an input)."""
    from ..data.capture_info import capture_info
    from ..run.cameras import InputCameras
    from .sources.base import INPUT_VIEWS, training_cameras
    from .sources.corrected import MoGaFaceParams
    from .sources.fitted import FittedParams
    from .sources.refined import RefinedParams, RefinerInference, run_refiner
    from .sources.smoothed import SmoothedParams, choose_sigmas
    from .sources.tracked import AlignedTrackedParams, TrackedParams
    from .sources.true import TrueParams, truth_dir

    tracked = TrackedParams(capture, run)
    start = AlignedTrackedParams(capture, run)
    inputs = InputCameras.of_run(capture, run.root)  # the run's refined cameras, where it refined them
    sources: dict[str, ParamSource] = {"tracked": tracked}
    if start.offset:
        sources["tracked_aligned"] = start
    try:
        truth_dir(capture)
        has_truth = True
    except InputError:
        has_truth = False
    if has_truth:  # σ from the training sequences: neither the test nor the validation sequence
        info = capture_info(capture.root)
        held_out = [info.get("test_sequence"), info.get("val_sequence")]
        sources["smoothed"] = SmoothedParams(capture, tracked, choose_sigmas(capture, held_out))
    views = {"cameras": inputs, "input_cameras": training_cameras(capture)}
    for steps in fit_steps:
        sources[f"fit_{steps}"] = FittedParams(avatar, capture, start, steps, run.background, views=INPUT_VIEWS,
                                               **views)
    refiner = run_refiner(run.root, avatar)
    if refiner is not None:
        for passes in refiner_passes:
            sources[f"refined_{passes}"] = RefinedParams(avatar, capture, start, refiner, run.background, passes,
                                                         max_views=INPUT_VIEWS, **views)
        if fit_steps:
            sources[f"refined_fit_{fit_steps[0]}"] = RefinerInference(avatar, capture, run, refiner, passes=1,
                                                                      views=INPUT_VIEWS, fit_steps=fit_steps[0],
                                                                      **views)
    model = getattr(avatar, "model", None)
    if model is not None and model.mode != "off":
        sources["method"] = MoGaFaceParams(capture, run, model, image_assisted=True)
    if has_truth:
        sources["true"] = TrueParams(capture, run)
        sources["true_gauge"] = TrueParams(capture, run, run_gauge(run, capture))
    return sources


def run_gauge(run: RunFolder, capture) -> dict:
    """The run's gauge (:func:`.expression_error.truth_gauge`) on a synthetic capture; empty without a truth."""
    from .expression_error import truth_gauge
    from .sources.true import true_params, truth_dir

    try:
        truth_dir(capture)
    except InputError:
        return {}
    return truth_gauge(run, lambda t: true_params(capture, t))


def score_source(avatar, capture, source: ParamSource, frames, background, lpips: bool = True,
                 gauge: dict | None = None) -> dict:
    """Mean image scores, parameter errors (where the truth is known; with ``gauge`` from
    :func:`run_gauge`, also against the truth in the avatar's gauge) and seconds per frame."""
    from .expression_error import gauge_errors
    from .sources.true import true_params

    rows = []
    try:
        true_params(capture, frames[0].timestep_index)
        truth_known = True
    except (InputError, IndexError):
        truth_known = False
    for item in run_protocol(avatar, capture, source, frames, background):
        row = score(item, lpips)
        if truth_known:
            truth = true_params(capture, item.frame.timestep_index)
            row.update(frame_errors(avatar.flame, item.params, truth))
            if gauge:
                row.update(gauge_errors(avatar.flame, item.params, truth, gauge))
        row["source_s"] = item.source_seconds
        row["frame_s"] = item.source_seconds + item.render_seconds
        rows.append(row)
    keys = [k for k in (*IMAGE_METRICS, *PARAMETER_METRICS, "source_s", "frame_s") if rows and k in rows[0]]
    out = {"frames": len(rows)}
    for key in keys:
        values = [r[key] for r in rows]
        out[key] = float(np.mean(values)) if all(math.isfinite(v) for v in values) else None
    return out


def benchmark_run(run_dir, protocols=PROTOCOLS, max_frames: int | None = None, lpips: bool = True,
                  fit_steps=FIT_STEPS, sources: dict[str, ParamSource] | None = None, avatar=None,
                  split: str = "test") -> dict:
    """``{"split": …, "protocols": {protocol: {source: scores}}, "scored": {protocol: what it
    scored}, "sources": {name: description}, "cameras": …, "skipped": {protocol: why}}``
    (``scored``: :func:`.protocols.scored_views`). ``split``: the test frames or the validation
    frames (:data:`.protocol_names.SCORE_SPLITS`); protocols without frames there are skipped."""
    from .camera_error import camera_errors

    run = RunFolder(run_dir)
    capture = run.open_capture()
    avatar = run.load_avatar() if avatar is None else avatar
    if lpips:
        check_lpips_size(capture)
    sources = standard_sources(run, capture, avatar, fit_steps) if sources is None else sources
    result = {"sources": {name: getattr(s, "description", type(s).__name__) for name, s in sources.items()},
              "split": check_split(split), "protocols": {}, "scored": {}, "skipped": {},
              "cameras": camera_errors(capture, run.root)}
    gauge = run_gauge(run, capture)
    for protocol in protocols:
        if split != "test" and (reason := protocol_unavailable(capture, protocol, split)) is not None:
            result["skipped"][protocol] = reason
            continue
        frames = protocol_frames(capture, protocol, max_frames, split)
        result["scored"][protocol] = scored_views(capture, frames)
        result["protocols"][protocol] = {
            name: score_source(avatar, capture, source, frames, run.background, lpips, gauge)
            for name, source in sources.items()
        }
    if not result["protocols"]:
        raise InputError(capture.root, "split", "; ".join(f"{k}: {v}" for k, v in result["skipped"].items()))
    return result


def matching_fit_length(psnr_by_steps: dict[int, float], target: float) -> dict:
    """The test-time fitting length that reaches ``target`` PSNR, from its PSNR measured at a few
    lengths: linear in log-steps between the two measured lengths around the first crossing.

    ``{"steps": …, "status": "interpolated"}``; ``status`` "not reached" (``steps`` None) when
    every length stays below ``target``; "reached by the shortest" (``steps`` that length) when the
    shortest measured length is at or above it already (fewer steps were not measured).
    """
    points = sorted((int(steps), float(psnr)) for steps, psnr in psnr_by_steps.items())
    if not points or min(steps for steps, _ in points) < 1:
        raise ValueError(f"expected PSNR at positive fitting lengths, got {psnr_by_steps!r}")
    if points[0][1] >= target:
        return {"steps": points[0][0], "status": "reached by the shortest"}
    for (s0, p0), (s1, p1) in zip(points, points[1:]):
        if p1 >= target:
            share = (target - p0) / (p1 - p0)
            steps = math.exp(math.log(s0) + share * (math.log(s1) - math.log(s0)))
            return {"steps": steps, "status": "interpolated"}
    return {"steps": None, "status": "not reached"}


def seconds_at_length(seconds_by_steps: dict[int, float], steps: float) -> float:
    """Fitting's seconds per frame at ``steps`` (possibly fractional): linear in the number of
    steps between the measured lengths around it (a step costs the same at any length)."""
    points = sorted((int(s), float(t)) for s, t in seconds_by_steps.items())
    if len(points) == 1 or steps <= points[0][0]:
        s0, t0 = points[0]
        return t0 * steps / s0
    for (s0, t0), (s1, t1) in zip(points, points[1:]):
        if steps <= s1:
            return t0 + (steps - s0) * (t1 - t0) / (s1 - s0)
    (s0, t0), (s1, t1) = points[-2], points[-1]
    return t1 + (steps - s1) * (t1 - t0) / (s1 - s0)
