"""The evaluation protocols of the paper, and :func:`evaluate_run`.

- **novel view**: the held-out camera at the training timesteps (the capture's ``val`` split);
- **self-reenactment**: the held-out sequence from every camera (the ``test`` split);
- **cross-identity reenactment**: subject A driven by subject B's tracked motion; renders only.

Images are full frames on the training background colour. Where an avatar's FLAME parameters
come from is a :class:`ParamSource`: each protocol asks it for one frame's parameters and names
the view being scored as ``exclude_view``, so a source that looks at images (a later correction
module) must leave that view out. The scored image is never an input to anything.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
from collections.abc import Iterable, Iterator
from typing import Protocol

import numpy as np
import torch

from ..data.capture import Capture, Frame
from ..errors import InputError
from .run_folder import IDENTITY_KEYS, MOTION_KEYS, RunFolder, capture_info

PROTOCOLS = ("novel_view", "self_reenactment")


# -- where parameters come from ------------------------------------------------------------------
class ParamSource(Protocol):
    """One frame's FLAME parameters (numpy, ``(n,)`` each, ``static_offset (V,3)``).

    ``exclude_view`` is the camera id of the image being scored: a source may look at the
    other views of the timestep, never at that one.
    """

    def params_for(self, frame: Frame, exclude_view: str | None) -> dict[str, np.ndarray]: ...


class TrackedParams:
    """Parameter-driven inference: the run's own parameters for training timesteps, the
    capture's tracked ones (with the run's identity: shape, static offset) for the rest.

    Looks at no image, so ``exclude_view`` is satisfied trivially.
    """

    uses_images = False
    description = "parameter-driven (tracked FLAME parameters; no image input)"

    def __init__(self, capture: Capture, run: RunFolder | None = None):
        self.capture = capture
        self.run = run
        self._identity = run.identity_params() if run is not None else None

    def params_for(self, frame: Frame | int, exclude_view: str | None = None) -> dict[str, np.ndarray]:
        timestep = frame if isinstance(frame, int) else frame.timestep_index
        trained = self.run.flame_params(timestep) if self.run is not None else None
        if trained is not None:
            return trained
        params = dict(self.capture.flame_params(timestep))
        if self._identity:
            params.update(self._identity)
        return params


class DrivenParams:
    """Cross-identity: subject A's identity (shape, static offset) with subject B's tracked
    motion (expression, jaw, eyes, neck, head rotation and translation) of one B timestep.

    ``n_expr`` (A's model's count) trims B's expression or pads it with zeros when the two
    were tracked with different numbers of components.
    """

    uses_images = False

    def __init__(self, identity: dict[str, np.ndarray], driver: Capture, n_expr: int | None = None):
        if "shape" not in identity:
            raise InputError(None, "shape", "the driven subject's identity parameters need a shape")
        self.identity = identity
        self.driver = driver
        self.n_expr = n_expr

    def params_for(self, frame: Frame | int, exclude_view: str | None = None) -> dict[str, np.ndarray]:
        timestep = frame if isinstance(frame, int) else frame.timestep_index
        motion = self.driver.flame_params(timestep)
        params = {k: motion[k] for k in MOTION_KEYS}
        if self.n_expr is not None and len(params["expr"]) != self.n_expr:
            expr = np.zeros(self.n_expr, np.float32)
            kept = min(self.n_expr, len(params["expr"]))
            expr[:kept] = params["expr"][:kept]
            params["expr"] = expr
        params.update({k: v for k, v in self.identity.items() if k in IDENTITY_KEYS})
        return params


def views_at(capture: Capture, timestep: int, exclude_view: str | None, split: str | None = None) -> list[Frame]:
    """The frames of one timestep other than the excluded view: what an image-assisted source may see."""
    return [f for f in capture.frames(split) if f.timestep_index == timestep and f.camera_id != exclude_view]


# -- which frames a protocol scores --------------------------------------------------------------
def _spread(items: list, limit: int | None) -> list:
    """At most ``limit`` items, evenly spaced over the list (first and last kept)."""
    if limit is None or len(items) <= limit:
        return items
    if limit <= 0:
        return []
    picks = np.unique(np.round(np.linspace(0, len(items) - 1, limit)).astype(int))
    return [items[i] for i in picks]


def protocol_unavailable(capture: Capture, protocol: str) -> str | None:
    """Why a protocol cannot be scored on this capture, or None when it can."""
    try:
        frames = _protocol_candidates(capture, protocol)
    except InputError as error:
        return error.problem
    if frames:
        return None
    split = {"novel_view": "val", "self_reenactment": "test"}[protocol]
    what = {"novel_view": "a held-out camera", "self_reenactment": "a held-out sequence"}[protocol]
    if split in capture.empty_splits:
        return f"the {split} split is empty ({capture.empty_splits[split]}), so there is no {what} to score"
    return f"the capture has no {split} split and capture_info.json names no {what}"


def _protocol_candidates(capture: Capture, protocol: str) -> list[Frame]:
    info = capture_info(capture.root)
    if protocol == "novel_view":
        if "val" in capture.splits:
            return capture.frames("val")
        camera = info.get("val_camera")
        return [f for f in capture.frames("train") if camera is not None and f.camera_id == camera]
    if protocol == "self_reenactment":
        if "test" in capture.splits:
            return capture.frames("test")
        sequence = info.get("test_sequence")
        return [f for f in capture.frames() if sequence is not None and f.sequence == sequence]
    raise InputError(None, "protocol", f"unknown protocol {protocol!r} (have {', '.join(PROTOCOLS)})")


def protocol_frames(capture: Capture, protocol: str, max_frames: int | None = None) -> list[Frame]:
    """The frames a protocol scores, in capture order (evenly thinned to ``max_frames``).

    Captures without ``val``/``test`` splits fall back on ``capture_info.json``'s
    ``val_camera`` and ``test_sequence``.
    """
    frames = _protocol_candidates(capture, protocol)
    if not frames:
        raise InputError(capture.root, protocol, protocol_unavailable(capture, protocol)
                         or "the capture holds no frames for this protocol")
    frames = sorted(frames, key=lambda f: (f.timestep_index, f.camera_index))
    return _spread(frames, max_frames)


# -- rendering and scoring -----------------------------------------------------------------------
@dataclasses.dataclass
class Scored:
    """One scored view: the prediction and its ground truth, ``(H,W,3)`` float32 in [0,1]."""

    frame: Frame
    prediction: np.ndarray
    alpha: np.ndarray
    target: np.ndarray


def target_image(capture: Capture, frame: Frame, background, capture_background=None) -> np.ndarray:
    """The ground truth on the training background: as stored when the capture was recorded on
    that background, else composited onto it through the foreground mask."""
    rgb, mask = capture.load_image(frame)
    if capture_background is not None and np.allclose(capture_background, background):
        return np.asarray(rgb, dtype=np.float32)
    bg = np.asarray(background, dtype=np.float32)
    return (rgb * mask[..., None] + bg * (1.0 - mask[..., None])).astype(np.float32)


def render_frame(
    avatar, params: dict[str, np.ndarray], camera, background, clamp: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """``(rgb (H,W,3), alpha (H,W))`` of the avatar posed by ``params``, as numpy float32.

    ``clamp=False`` keeps colours outside [0, 1] (SH can overshoot) for compositing later.
    """
    from ..avatar.avatar import flame_params_to_torch

    with torch.no_grad():
        out = avatar.render(flame_params_to_torch(params), camera, background)
    rgb = out.rgb.clamp(0.0, 1.0) if clamp else out.rgb
    return rgb.numpy().astype(np.float32), out.alpha.clamp(0.0, 1.0).numpy().astype(np.float32)


def run_protocol(
    avatar, capture: Capture, source: ParamSource, frames: Iterable[Frame], background
) -> Iterator[Scored]:
    """Render each frame from parameters that never saw its image, and pair it with the truth."""
    recorded = capture_info(capture.root).get("background")
    for frame in frames:
        params = source.params_for(frame, exclude_view=frame.camera_id)
        prediction, alpha = render_frame(avatar, params, capture.camera(frame), background)
        yield Scored(frame, prediction, alpha, target_image(capture, frame, background, recorded))


def novel_view(avatar, capture, source, background, max_frames=None) -> Iterator[Scored]:
    return run_protocol(avatar, capture, source, protocol_frames(capture, "novel_view", max_frames), background)


def self_reenactment(avatar, capture, source, background, max_frames=None) -> Iterator[Scored]:
    return run_protocol(avatar, capture, source, protocol_frames(capture, "self_reenactment", max_frames), background)


def cross_identity(
    avatar, capture: Capture, source: DrivenParams, background, cameras: list[str] | None = None,
    max_frames: int | None = None,
) -> Iterator[tuple[int, str, np.ndarray, np.ndarray]]:
    """Subject A (``avatar``, seen by ``capture``'s cameras) performing the driver's timesteps.

    Yields ``(driver timestep, camera id, rgb, alpha)``; there is no ground truth.
    """
    cameras = list(capture.cameras) if cameras is None else cameras
    for camera_id in cameras:
        if camera_id not in capture.cameras:
            raise InputError(capture.root, "camera", f"no camera {camera_id!r} (have {', '.join(capture.cameras)})")
    for timestep in _spread(list(source.driver.timesteps), max_frames):
        params = source.params_for(timestep)
        for camera_id in cameras:
            rgb, alpha = render_frame(avatar, params, capture.cameras[camera_id], background)
            yield timestep, camera_id, rgb, alpha


# -- the whole evaluation of a run ---------------------------------------------------------------
def _mean(values: list[float]) -> float | None:
    """The mean (infinite when a PSNR is: identical images), None for no values."""
    return float(np.mean(values)) if values else None


def _summary(rows: list[dict], keys: tuple[str, ...]) -> dict:
    return {"frames": len(rows), **{k: _mean([r[k] for r in rows]) for k in keys}}


def score(item: Scored, with_lpips: bool = True) -> dict[str, float]:
    """PSNR, SSIM (and LPIPS) of one scored view on the full image."""
    from . import metrics

    row = {"psnr": metrics.psnr(item.prediction, item.target), "ssim": metrics.ssim(item.prediction, item.target)}
    if with_lpips:
        row["lpips"] = metrics.lpips(item.prediction, item.target)
    return row


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
) -> dict:
    """Score a run on the protocols; write ``metrics.json``, ``metrics.md`` and ``eval/`` images.

    Returns the metrics: per protocol the mean ``psnr``, ``ssim`` (and ``lpips``) with
    breakdowns per camera and per sequence. With ``driver`` (another capture), also renders
    the cross-identity reenactment (images only; ``driver_cameras`` of the run's capture, default
    all). Outputs go to ``out_dir`` (default: the run). ``avatar`` and ``source`` replace the
    run's avatar and :class:`TrackedParams`, e.g. for image-assisted inference.
    """
    from ..io.atomic import write_json, write_text
    from ..progress import ProgressBar
    from . import report

    run = RunFolder(run_dir, capture)
    protocols = list(protocols)
    for name in protocols:
        if name not in PROTOCOLS:
            raise InputError(None, "protocols", f"unknown protocol {name!r} (have {', '.join(PROTOCOLS)})")
    out = pathlib.Path(out_dir) if out_dir is not None else run.root
    cap = run.open_capture()
    if avatar is None and source is None:
        from .mogaface_source import run_inference

        avatar, source = run_inference(run, cap)  # MoGaFace runs: modules + image-assisted inference
    avatar = run.load_avatar() if avatar is None else avatar
    source = TrackedParams(cap, run) if source is None else source
    skipped = {name: reason for name in protocols if (reason := protocol_unavailable(cap, name)) is not None}
    if skipped and len(skipped) == len(protocols):
        raise InputError(cap.root, "protocols", "; ".join(f"{k}: {v}" for k, v in skipped.items()))
    plans = {name: protocol_frames(cap, name, max_frames) for name in protocols if name not in skipped}
    total = sum(len(f) for f in plans.values())
    bar = ProgressBar(total, "eval") if progress and total else None
    keys = ("psnr", "ssim", "lpips") if lpips else ("psnr", "ssim")
    result = {
        "run": str(run.root.resolve()),
        "capture": str(cap.root.resolve()),
        "background": list(run.background),
        "inference": getattr(source, "description", type(source).__name__),
        "protocols": {},
        "skipped": skipped,
    }
    for name, frames in plans.items():
        rows = []
        for index, item in enumerate(run_protocol(avatar, cap, source, frames, run.background)):
            row = score(item, lpips)
            frame = item.frame
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
        result["protocols"][name] = summary
    if driver is not None:
        result["cross_identity"] = report.write_cross_identity(
            avatar, cap, run, driver, out / report.EVAL_DIR / "cross_identity", max_frames, progress, driver_cameras
        )
    write_json(out / "metrics.json", report.json_safe(result))
    write_text(out / "metrics.md", report.markdown_table(result))
    return result
