"""The parameter-source interface and what every source shares."""

from __future__ import annotations

from typing import Protocol

import numpy as np

from ...data.capture import Capture, Frame


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
