"""The cameras a method that reads images sees a run's capture through (the refiner, test-time
fitting): the run's refined poses where training refined them, else the capture's calibration."""

from __future__ import annotations

import pathlib

from ..data.camera_file import read_cameras
from ..data.capture import Capture, Frame
from .names import REFINED_CAMERAS_FILE


class InputCameras:
    """The camera an image-assisted source renders an input view from: the run's refined camera
    (``RUN/cameras_refined.json``, written by camera refinement in training) where it has one, else
    the capture's calibration. The avatar was trained against the refined cameras, so fitting to a
    view through its calibrated pose would fit the calibration error. Scoring does not use this:
    the scored view keeps its scoring camera (:class:`..evaluate.images.ScoringCameras`)."""

    def __init__(self, capture: Capture, refined: dict | None = None):
        self.capture = capture
        self.refined = dict(refined or {})

    @classmethod
    def of_run(cls, capture: Capture, run_root) -> "InputCameras":
        path = pathlib.Path(run_root) / REFINED_CAMERAS_FILE
        return cls(capture, read_cameras(path) if path.exists() else None)

    def __call__(self, frame: Frame):
        return self.refined.get(frame.camera_id) or self.capture.camera(frame)

    def at(self, camera_id: str, timestep: int):
        """Camera ``camera_id`` as an input at ``timestep`` (also where no frame shows it there)."""
        return self.refined.get(camera_id) or self.capture.camera_at(camera_id, timestep)
