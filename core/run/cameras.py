"""The camera a frame is seen through: one rule, two choices of cameras.

A frame is seen through a chosen camera of its ``camera_id`` where one is chosen, else through the
capture's calibration. The choice differs by use, for a reason:

- :class:`ScoringCameras` (a scored frame's render): the true cameras where the capture keeps them
  (``cameras_gt.json``, synthetic captures with camera noise). A calibration error of the training
  cameras then costs what it costs, and a method that refines cameras can show it; the held-out
  camera is never scored at a perturbed pose.
- :class:`InputCameras` (an input view of a method that reads images: the refiner, test-time
  fitting): the run's refined cameras (``RUN/cameras_refined.json``). The avatar was trained against
  them, so fitting to a view through its calibrated pose would fit the calibration error. The scored
  view keeps its scoring camera.
"""

from __future__ import annotations

import pathlib

from ..data.camera_file import read_cameras
from ..data.capture import Capture, Frame
from ..data.capture_info import capture_info
from .names import REFINED_CAMERAS_FILE


class FrameCameras:
    """``chosen`` cameras by id where there is one, else the capture's calibration."""

    def __init__(self, capture: Capture, chosen: dict | None = None):
        self.capture = capture
        self.chosen = dict(chosen or {})

    def __call__(self, frame: Frame):
        return self.chosen.get(frame.camera_id) or self.capture.camera(frame)

    def at(self, camera_id: str, timestep: int):
        """Camera ``camera_id`` at ``timestep`` (also where no frame shows it there)."""
        return self.chosen.get(camera_id) or self.capture.camera_at(camera_id, timestep)


class ScoringCameras(FrameCameras):
    """The camera each scored frame is rendered from: the true one where the capture keeps it."""

    def __init__(self, capture: Capture):
        truth = {}
        name = capture_info(capture.root).get("ground_truth", {}).get("cameras")
        if name and (capture.root / name).exists():
            truth = read_cameras(capture.root / name, capture.declared_cy_origin)
        super().__init__(capture, truth)
        self.truth = self.chosen
        self.source = "true (cameras_gt.json)" if truth else "as calibrated"


class InputCameras(FrameCameras):
    """The camera an image-assisted source renders an input view from: the run's refined camera where
    training refined it."""

    def __init__(self, capture: Capture, refined: dict | None = None):
        super().__init__(capture, refined)
        self.refined = self.chosen

    @classmethod
    def of_run(cls, capture: Capture, run_root) -> "InputCameras":
        path = pathlib.Path(run_root) / REFINED_CAMERAS_FILE
        return cls(capture, read_cameras(path) if path.exists() else None)
