"""What a scored frame is rendered by and from: the avatar's render and the camera a frame is scored
from. The ground truth it is compared with is :func:`..data.target.target_image`."""

from __future__ import annotations

import numpy as np
import torch

from ..data.camera_file import read_cameras
from ..data.capture import Capture, Frame
from ..data.capture_info import capture_info


def render_frame(
    avatar, params: dict[str, np.ndarray], camera, background, clamp: bool = True, vertex_shift=None
) -> tuple[np.ndarray, np.ndarray]:
    """``(rgb (H,W,3), alpha (H,W))`` of the avatar posed by ``params``, as numpy float32.

    ``clamp=False`` keeps colours outside [0, 1] (SH can overshoot) for compositing later.
    ``vertex_shift``: a move of the posed mesh (a camera's delay along the motion), or None.
    """
    from ..avatar.avatar import flame_params_to_torch

    with torch.no_grad():
        out = avatar.render(flame_params_to_torch(params), camera, background, vertex_shift=vertex_shift)
    rgb = out.rgb.clamp(0.0, 1.0) if clamp else out.rgb
    return rgb.numpy().astype(np.float32), out.alpha.clamp(0.0, 1.0).numpy().astype(np.float32)


class ScoringCameras:
    """The camera each scored frame is rendered from: the true one where the capture keeps the
    truth (``cameras_gt.json``, synthetic captures with camera noise), else the capture's own.

    A calibration error of the training cameras then costs what it costs, and a method that
    refines cameras can show it; the held-out camera is never scored at a perturbed pose.
    """

    def __init__(self, capture: Capture):
        self.capture = capture
        self.truth: dict = {}
        name = capture_info(capture.root).get("ground_truth", {}).get("cameras")
        if name and (capture.root / name).exists():
            self.truth = read_cameras(capture.root / name, capture.declared_cy_origin)
        self.source = "true (cameras_gt.json)" if self.truth else "as calibrated"

    def __call__(self, frame: Frame):
        return self.truth.get(frame.camera_id) or self.capture.camera(frame)
