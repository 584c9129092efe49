"""The evaluation protocols of the paper: which frames each scores, and how a frame is scored.

- **novel view**: the held-out camera at the training timesteps (the capture's ``val`` split);
- **self-reenactment**: the held-out sequence from every camera (the ``test`` split);
- **cross-identity reenactment**: subject A driven by subject B's tracked motion; renders only;
- **novel view, aligned** (on request): the held-out camera aligned to the avatar on half its
  frames, the other half scored (:mod:`.camera_alignment`), for runs whose cameras were refined;
- **novel view, colour aligned** (on request): the same halves, the held-out camera's affine colour
  fitted on the first, for captures whose cameras disagree in colour.

Images are full frames on the training background colour. Where an avatar's FLAME parameters
come from is a parameter source (:mod:`.sources`): each protocol asks it for one frame's
parameters and names the view being scored as ``exclude_view``, so a source that looks at images
must leave that view out. The scored image is never an input to anything. A frame is rendered
from its true camera where the capture keeps one (:class:`~..run.cameras.ScoringCameras`), a
training camera's in the colours the run learned for it (``camera_colours``).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterable, Iterator

import numpy as np

from ..avatar.avatar import render_frame
from ..data.capture import Capture, Frame
from ..data.capture_info import capture_info
from ..data.target import target_image
from ..errors import InputError
from ..run.cameras import ScoringCameras
from .protocol_names import ALIGNED_PROTOCOLS, ALL_PROTOCOLS, OPTIONAL_PROTOCOLS, PROTOCOLS, SCORE_SPLITS
from .sources.base import ParamSource, views_at
from .sources.driven import DrivenParams
from .sources.tracked import TrackedParams

__all__ = ["ALL_PROTOCOLS", "OPTIONAL_PROTOCOLS", "PROTOCOLS", "SCORE_SPLITS", "check_protocol", "check_split",
           "DrivenParams", "ParamSource", "Scored", "TrackedParams", "cross_identity", "novel_view",
           "novel_view_aligned", "novel_view_colour_aligned", "protocol_frames", "run_protocol", "score", "scored_views",
           "self_reenactment", "target_image", "views_at"]


# -- which frames a protocol scores --------------------------------------------------------------
def _spread(items: list, limit: int | None) -> list:
    """At most ``limit`` items, evenly spaced over the list (first and last kept)."""
    if limit is None or len(items) <= limit:
        return items
    if limit <= 0:
        return []
    picks = np.unique(np.round(np.linspace(0, len(items) - 1, limit)).astype(int))
    return [items[i] for i in picks]


def protocol_unavailable(capture: Capture, protocol: str, split: str = "test") -> str | None:
    """Why a protocol cannot be scored on this capture's ``split`` frames, or None when it can."""
    try:
        frames = _protocol_candidates(capture, protocol, split)
    except InputError as error:
        return error.problem
    if not frames and split == "validation":
        if protocol != "self_reenactment":
            return ("the validation frames are a sequence of their own: only self_reenactment scores them "
                    "(the held-out camera at training timesteps has no validation counterpart)")
        return "capture_info.json names no validation sequence (val_sequence), or it has no frames"
    if frames and protocol in ALIGNED_PROTOCOLS and len(frames) == len({f.camera_id for f in frames}):
        return "the held-out camera has a single frame: aligning it on some frames and scoring others needs two"
    if frames:
        return None
    split = "test" if protocol == "self_reenactment" else "val"
    what = "a held-out sequence" if protocol == "self_reenactment" else "a held-out camera"
    if split in capture.empty_splits:
        return f"the {split} split is empty ({capture.empty_splits[split]}), so there is no {what} to score"
    return f"the capture has no {split} split and capture_info.json names no {what}"


def _protocol_candidates(capture: Capture, protocol: str, split: str = "test") -> list[Frame]:
    info = capture_info(capture.root)
    validation = info.get("val_sequence")
    if check_split(split) == "validation":
        if check_protocol(protocol) != "self_reenactment" or not validation:
            return []
        return [f for f in capture.frames() if f.sequence == validation]
    if check_protocol(protocol) in ("novel_view", *ALIGNED_PROTOCOLS):
        if "val" in capture.splits:
            return capture.frames("val")
        camera = info.get("val_camera")
        return [f for f in capture.frames("train") if camera is not None and f.camera_id == camera]
    if "test" in capture.splits:  # self_reenactment; the validation sequence shares the test split
        return [f for f in capture.frames("test") if not validation or f.sequence != validation]
    sequence = info.get("test_sequence")
    return [f for f in capture.frames() if sequence is not None and f.sequence == sequence]


def check_split(name: str) -> str:
    """``name``, or an error naming the frames a protocol can score (:data:`SCORE_SPLITS`)."""
    if name not in SCORE_SPLITS:
        raise InputError(None, "split", f"unknown split {name!r} (have {', '.join(SCORE_SPLITS)})")
    return name


def check_protocol(name: str) -> str:
    """``name``, or an error naming the protocols there are."""
    if name not in ALL_PROTOCOLS:
        raise InputError(None, "protocols", f"unknown protocol {name!r} (have {', '.join(ALL_PROTOCOLS)})")
    return name


def protocol_frames(capture: Capture, protocol: str, max_frames: int | None = None, split: str = "test"
                    ) -> list[Frame]:
    """The frames a protocol scores, in capture order (evenly thinned to ``max_frames``).

    ``split``: ``test`` (the held-out sequence, the default) or ``validation`` (the validation
    sequence, ``capture_info.json``'s ``val_sequence``: self-reenactment only). Captures without
    ``val``/``test`` splits fall back on ``capture_info.json``'s ``val_camera`` and ``test_sequence``.
    """
    frames = _protocol_candidates(capture, protocol, split)
    if not frames:
        raise InputError(capture.root, protocol, protocol_unavailable(capture, protocol, split)
                         or "the capture holds no frames for this protocol")
    frames = sorted(frames, key=lambda f: (f.timestep_index, f.camera_index))
    return _spread(frames, max_frames)


def scored_views(capture: Capture, frames: list[Frame]) -> dict:
    """What a set of scored frames is, for every report that scores them: ``label`` (which
    cameras on which frames: training cameras on unseen frames is self-reenactment, the held-out
    camera on unseen frames a novel view of unseen frames, the held-out camera on training frames
    a novel view), ``cameras`` and ``frames`` by name (``TIMESTEP_ID/CAMERA``)."""
    info = capture_info(capture.root)
    held_out = {f.camera_id for f in capture.frames("val")} if "val" in capture.splits else set()
    held_out |= {info["val_camera"]} if info.get("val_camera") else set()
    trained = {f.timestep_index for f in capture.frames("train")}
    cameras = sorted({f.camera_id for f in frames})
    seen_by = sorted(set(cameras) & held_out)
    others = [c for c in cameras if c not in held_out]
    unseen = [f for f in frames if f.timestep_index not in trained]
    sequences = ", ".join(sorted({f.sequence or "?" for f in unseen})) or "?"
    held = f"held-out camera{'s' if len(seen_by) > 1 else ''} {', '.join(seen_by)}"
    if frames and len(unseen) == len(frames):
        where = f"unseen frames ({sequences})"
        label = {(True, False): f"self-reenactment: training cameras on {where}",
                 (False, True): f"novel view of unseen frames: {held} on {where}",
                 (True, True): f"self-reenactment and novel view of unseen frames: training cameras and {held} "
                               f"on {where}"}[bool(others), bool(seen_by)]
    elif frames and not unseen and not others:
        label = f"novel view: {held} on training frames"
    else:
        label = (f"{len(frames)} frames: cameras {', '.join(cameras)}, "
                 f"{len(unseen)} of them on frames no training step saw")
    return {"label": label, "cameras": cameras, "frames": [f"{f.timestep_id}/{f.camera_id}" for f in frames]}


# -- rendering and scoring -----------------------------------------------------------------------
@dataclasses.dataclass
class Scored:
    """One scored view: the prediction and its ground truth, ``(H,W,3)`` float32 in [0,1]."""

    frame: Frame
    prediction: np.ndarray
    alpha: np.ndarray
    target: np.ndarray
    params: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)  # what the source gave
    source_seconds: float = 0.0  # the source's time for this frame's parameters
    render_seconds: float = 0.0


def run_protocol(
    avatar, capture: Capture, source: ParamSource, frames: Iterable[Frame], background, cameras=None, shift=None,
    colour=None,
) -> Iterator[Scored]:
    """Render each frame from parameters that never saw its image, and pair it with the truth.

    ``cameras``: frame → the camera it is rendered from (default :class:`~..run.cameras.ScoringCameras`).
    ``shift``: frame → the move of its posed mesh (a run's camera delays), or None. ``colour``:
    frame → the colour its camera sees in (a change ``[M − I | b]``) or None; default: the colours
    the run learned for its training cameras (the avatar's ``camera_colours``), none for others."""
    recorded = capture_info(capture.root).get("background")
    cameras = ScoringCameras(capture) if cameras is None else cameras
    if colour is None:
        learned = getattr(avatar, "camera_colours", None) or {}

        def colour(frame):
            return learned.get(frame.camera_id)
    for frame in frames:
        start = time.perf_counter()
        params = source.params_for(frame, exclude_view=frame.camera_id)
        middle = time.perf_counter()
        prediction, alpha = render_frame(avatar, params, cameras(frame), background,
                                         vertex_shift=None if shift is None else shift(frame), colour=colour(frame))
        end = time.perf_counter()
        yield Scored(frame, prediction, alpha, target_image(capture, frame, background, recorded), params,
                     middle - start, end - middle)


def novel_view(avatar, capture, source, background, max_frames=None) -> Iterator[Scored]:
    return run_protocol(avatar, capture, source, protocol_frames(capture, "novel_view", max_frames), background)


def self_reenactment(avatar, capture, source, background, max_frames=None) -> Iterator[Scored]:
    return run_protocol(avatar, capture, source, protocol_frames(capture, "self_reenactment", max_frames), background)


def novel_view_aligned(avatar, capture, source, background, frames: list[Frame]) -> tuple[Iterator[Scored], dict]:
    """The scored half of ``frames`` (novel-view frames), each held-out camera first aligned to the
    avatar on the other half; returns the scored items and, per camera, what the alignment moved."""
    from .camera_alignment import MAX_FIT_FRAMES, align_camera, split_frames

    fit, scored = split_frames(frames)
    if not scored:
        raise InputError(capture.root, "novel_view_aligned", "needs two or more frames of the held-out camera "
                                                             "(one to align on, one to score): raise --max-frames")
    recorded = capture_info(capture.root).get("background")
    truth = ScoringCameras(capture)
    aligned, report = {}, {}
    for camera_id in sorted({f.camera_id for f in scored}):
        camera = truth(next(f for f in fit if f.camera_id == camera_id))
        if any(not np.allclose(truth(f).w2c, camera.w2c) for f in frames if f.camera_id == camera_id):
            raise InputError(capture.root, "novel_view_aligned", f"camera {camera_id!r} moves between frames; "
                                                                 "aligning it needs one pose for all its frames")
        own = _spread([f for f in fit if f.camera_id == camera_id], MAX_FIT_FRAMES)
        views = [(source.params_for(f, exclude_view=f.camera_id), target_image(capture, f, background, recorded))
                 for f in own]
        aligned[camera_id], report[camera_id] = align_camera(avatar, camera, views, background)
    return run_protocol(avatar, capture, source, scored, background, lambda f: aligned[f.camera_id]), report


def novel_view_colour_aligned(avatar, capture, source, background, frames: list[Frame]
                              ) -> tuple[Iterator[Scored], dict]:
    """The scored half of ``frames`` (novel-view frames), each held-out camera seen through the affine
    colour fitted on the other half (:func:`.camera_alignment.fit_colour`); returns the scored items
    and, per camera, what the fit found. The fit renders from the scoring cameras, as the scored
    half is rendered."""
    from .camera_alignment import MAX_FIT_FRAMES, fit_colour, split_frames

    fit, scored = split_frames(frames)
    if not scored:
        raise InputError(capture.root, "novel_view_colour_aligned", "needs two or more frames of the held-out "
                                                                    "camera (one to fit on, one to score): raise "
                                                                    "--max-frames")
    recorded = capture_info(capture.root).get("background")
    truth = ScoringCameras(capture)
    fitted, report = {}, {}
    for camera_id in sorted({f.camera_id for f in scored}):
        own = _spread([f for f in fit if f.camera_id == camera_id], MAX_FIT_FRAMES)
        renders = [render_frame(avatar, source.params_for(f, exclude_view=f.camera_id), truth(f), background,
                                clamp=False) for f in own]
        targets = [target_image(capture, f, background, recorded) for f in own]
        fitted[camera_id], report[camera_id] = fit_colour(renders, targets, background)
    return run_protocol(avatar, capture, source, scored, background, colour=lambda f: fitted[f.camera_id]), report


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


def check_lpips_size(capture: Capture) -> None:
    """Refuse LPIPS before any scoring where the capture's images are too small for it, naming the
    capture (the metric itself knows no file)."""
    from ..metrics.images import LPIPS_MIN_SIZE

    camera = min(capture.cameras.values(), key=lambda c: min(c.width, c.height))
    if min(camera.width, camera.height) < LPIPS_MIN_SIZE:
        raise InputError(capture.root, "images", f"LPIPS needs images of at least {LPIPS_MIN_SIZE} x {LPIPS_MIN_SIZE} "
                                                 f"pixels, this capture has {camera.width} x {camera.height}: score "
                                                 f"without it (--no-lpips)")


def score(item: Scored, with_lpips: bool = True) -> dict[str, float]:
    """PSNR, SSIM (and LPIPS) of one scored view on the full image."""
    from ..metrics import images as metrics

    row = {"psnr": metrics.psnr(item.prediction, item.target), "ssim": metrics.ssim(item.prediction, item.target)}
    if with_lpips:
        row["lpips"] = metrics.lpips(item.prediction, item.target)
    return row
