"""The parameter-source interface and what every source shares."""

from __future__ import annotations

from typing import Protocol

import numpy as np

from ...data.capture import Capture, Frame
from ...data.capture_info import capture_info
from ...run.cameras import InputCameras


class ParamSource(Protocol):
    """One frame's FLAME parameters (numpy, ``(n,)`` each, ``static_offset (V,3)``).

    ``exclude_view`` is the camera id of the image being scored: a source may look at the
    other views of the timestep, never at that one. ``uses_images`` says whether it looks at
    any image at all; ``description`` names it in reports.
    """

    uses_images: bool
    description: str

    def params_for(self, frame: Frame | int, exclude_view: str | None = None) -> dict[str, np.ndarray]: ...


def timestep_of(frame: Frame | int) -> int:
    return frame if isinstance(frame, int) else frame.timestep_index


def views_at(capture: Capture, timestep: int, exclude_view: str | None, split: str | None = None) -> list[Frame]:
    """The frames of one timestep other than the excluded view: what an image-assisted source may see."""
    return [f for f in capture.frames(split) if f.timestep_index == timestep and f.camera_id != exclude_view]


# How many other views the refiner and test-time fitting read per frame: the same views for both,
# so their comparison is one of methods, not of how much each was shown (docs/evaluation.md).
INPUT_VIEWS = 4


def training_cameras(capture: Capture) -> list[str]:
    """The cameras of the capture's training frames, without the held-out one (``val_camera``)."""
    from ...data.capture_info import capture_info

    held_out = capture_info(capture.root).get("val_camera")
    return sorted({f.camera_id for f in capture.frames("train")} - {held_out})


def input_views(capture: Capture, timestep: int, exclude_view: str | None, count: int | None = None,
                cameras=None) -> list[Frame]:
    """The views an image-assisted source reads for one frame: the other views of its timestep
    (:func:`views_at`), from ``cameras`` only (ids; None: any), at most ``count`` of them spread
    evenly over the rig (None: all)."""
    frames = views_at(capture, timestep, exclude_view)
    if cameras is not None:
        allowed = set(cameras)
        frames = [f for f in frames if f.camera_id in allowed]
    if count is None or len(frames) <= count:
        return frames
    return [frames[i] for i in np.unique(np.round(np.linspace(0, len(frames) - 1, count)).astype(int))]



class ImageAssistedSource:
    """What an image-assisted source (test-time fitting, the refiner) shares: the avatar, the capture
    with the cameras its input views are rendered from, the source it improves (``base``), the
    background; and the improving itself. A frame's parameters are ``base``'s, improved by the
    subclass's ``improve(start, frames, timestep)`` from at most ``max_inputs`` other views of its
    timestamp (:func:`input_views`, from ``input_cameras``: ids, None: any) where there are any and
    ``rounds`` > 0. Every set of views read is recorded in :attr:`inputs` (scored view, views
    read), so tests can check that the scored view is never one."""

    uses_images = True

    def __init__(self, avatar, capture: Capture, base: ParamSource, background, rounds: int,
                 max_inputs: int | None, cameras=None, input_cameras=None):
        self.avatar = avatar
        self.capture = capture
        self.cameras = cameras or InputCameras(capture)
        self.base = base
        self.background = tuple(float(v) for v in background)
        self.rounds, self.max_inputs = rounds, max_inputs
        self.input_cameras = None if input_cameras is None else list(input_cameras)
        self.recorded = capture_info(capture.root).get("background")
        self.inputs: list[tuple[str | None, list[str]]] = []

    def params_for(self, frame: Frame | int, exclude_view: str | None = None) -> dict[str, np.ndarray]:
        timestep = timestep_of(frame)
        start = self.base.params_for(frame, exclude_view)  # a base that reads images leaves it out too
        frames = input_views(self.capture, timestep, exclude_view, self.max_inputs, self.input_cameras)
        if not frames or self.rounds <= 0:
            return start
        self.inputs.append((exclude_view, [f.camera_id for f in frames]))
        return self.improve(start, frames, timestep)
