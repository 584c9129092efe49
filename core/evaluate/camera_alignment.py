"""The held-out camera aligned to the avatar before it is scored (protocol ``novel_view_aligned``).

With cameras whose calibration was off, a novel-view score mixes two things: how good the avatar
is, and how far its world sits from where the held-out camera's pose says. The second is not all
the avatar's fault: a real held-out camera comes from the same calibration, and a group of
training cameras can turn together without any image disagreeing. Methods that refine cameras are
therefore also scored after a test-time alignment of each held-out camera: a 6-DoF offset (a turn
about its centre and a shift of it) is fitted to the avatar on **half** of that camera's frames,
and the **other half** is scored. No scored image is an input to anything; the offset sees only
the other timesteps. ``novel_view`` stays the score at the scoring camera's own pose.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..avatar.avatar import flame_params_to_torch
from ..camera import Camera
from ..data.capture import Frame

ALIGNMENT_STEPS = 150
MAX_FIT_FRAMES = 8  # the fit's views are posed once and kept; enough to pin six numbers
ROTATION_RATE = 2e-3  # radians per Adam step at the start (decays tenfold over the fit)
SHIFT_RATE = 2e-4  # metres per Adam step at the start


def split_frames(frames: list[Frame]) -> tuple[list[Frame], list[Frame]]:
    """``(fit, scored)``: each camera's frames in timestep order, alternately (the first to fit),
    so both halves span the whole sequence and no timestep is in both."""
    fit, scored = [], []
    for camera_id in sorted({f.camera_id for f in frames}):
        own = sorted((f for f in frames if f.camera_id == camera_id), key=lambda f: f.timestep_index)
        fit += own[0::2]
        scored += own[1::2]
    return fit, scored


def align_camera(avatar, camera: Camera, views: list[tuple[dict, np.ndarray]], background,
                 steps: int = ALIGNMENT_STEPS) -> tuple[Camera, dict]:
    """The camera moved to where ``avatar`` best shows ``views`` (``(FLAME parameters, target
    image)`` pairs seen by ``camera``), and what was moved.

    Adam on the L1 image error, one view a step, rates decaying tenfold. The offset is kept only
    if it lowers the mean error over all fit views; otherwise the camera is returned unmoved.
    """
    from ..correction.avatar import render_world
    from ..train.camera_refine import CameraOffsets
    from ..train.schedule import decayed

    if not views:
        raise ValueError("aligning a camera needs at least one view")
    offsets = CameraOffsets({camera.camera_id: camera}, gauge="none")
    background_tensor = torch.as_tensor(background, dtype=torch.float32)
    with torch.no_grad():
        worlds = [{k: v.detach() for k, v in avatar.world_gaussians(flame_params_to_torch(p)).items()}
                  for p, _ in views]
    targets = [torch.from_numpy(np.array(t, dtype=np.float32)) for _, t in views]

    def error(index: int) -> torch.Tensor:  # of the image as scored: colours clamped to [0, 1]
        moved = offsets.move_scene(worlds[index], camera.camera_id)
        return (render_world(moved, camera, background_tensor).rgb.clamp(0.0, 1.0) - targets[index]).abs().mean()

    def mean_error() -> float:
        with torch.no_grad():
            return float(np.mean([float(error(i)) for i in range(len(views))]))

    before = mean_error()
    optimiser = torch.optim.Adam([{"params": list(offsets.rotation), "lr": ROTATION_RATE},
                                  {"params": list(offsets.translation), "lr": SHIFT_RATE}])
    for step in range(steps):
        for group, rate in zip(optimiser.param_groups, (ROTATION_RATE, SHIFT_RATE)):
            group["lr"] = decayed(rate, 0.1, step, steps - 1)
        optimiser.zero_grad()
        error(step % len(views)).backward()
        optimiser.step()
    after = mean_error()
    kept = after < before
    aligned = offsets.refined_camera(camera.camera_id) if kept else camera
    rotation, shift = offsets.values()
    info = {
        "fit_frames": len(views),
        "fit_l1_before": before,
        "fit_l1_after": after,
        "kept": kept,
        "rotation_deg": math.degrees(float(rotation[0].norm())) if kept else 0.0,
        "shift_mm": 1000.0 * float(shift[0].norm()) if kept else 0.0,
    }
    return aligned, info
