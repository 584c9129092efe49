"""The held-out camera aligned to the avatar before it is scored: in pose (protocol
``novel_view_aligned``) or in colour (``novel_view_colour_aligned``).

With cameras whose calibration was off, a novel-view score mixes two things: how good the avatar
is, and how far its world sits from where the held-out camera's pose says. The second is not all
the avatar's fault: a real held-out camera comes from the same calibration, and a group of
training cameras can turn together without any image disagreeing. Methods that refine cameras are
therefore also scored after a test-time alignment of each held-out camera: a 6-DoF offset (a turn
about its centre and a shift of it) is fitted to the avatar on **half** of that camera's frames,
and the **other half** is scored. No scored image is an input to anything; the offset sees only
the other timesteps. ``novel_view`` stays the score at the scoring camera's own pose.

The colour is aligned the same way: a held-out camera has no colour learned in training (a run with
``[cameras] colour`` learns one per training camera, their mean held at the avatar's own colours),
so an affine colour of the rendered foreground (:mod:`..avatar.camera_colour`) is fitted in closed
form, by least squares on the foreground pixels of the renders of half its frames against their
images, and the other half is scored through it.
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
MIN_COLOUR_PIXELS = 64  # fewer foreground pixels than this pin no affine colour: the identity is kept
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


def fit_colour(renders: list[tuple[np.ndarray, np.ndarray]], targets: list[np.ndarray], background
               ) -> tuple[np.ndarray, dict]:
    """The affine colour (change ``[M − I | b]``, ``(3, 4)``) that best maps the foreground of
    ``renders`` (``(rgb, alpha)`` over ``background``, rgb as rendered, not clamped) to ``targets``,
    and what was fitted.

    Least squares over the pixels the avatar covers (alpha ≥ 0.5), in the premultiplied form of
    :func:`~..avatar.camera_colour.recolour`, ``target − (1 − α)·bg − F = (M − I)·F + α·b``
    (``F = rgb − (1 − α)·bg``), solved for the change: exact for targets that are such a map of the
    renders, and the identity in any direction the pixels do not pin (the least-norm solution). It
    is kept only if it lowers the mean L1 error of the clamped images over all fit views.
    """
    from ..avatar.camera_colour import matrix_and_offset, recolour

    if not renders or len(renders) != len(targets):
        raise ValueError("fitting a colour needs at least one render and its target")
    bg = np.asarray(background, np.float64).reshape(1, 3)
    inputs, outputs = [], []
    for (rgb, alpha), target in zip(renders, targets):
        keep = alpha >= 0.5
        a = alpha[keep].astype(np.float64)[:, None]
        foreground = rgb[keep].astype(np.float64) - (1.0 - a) * bg
        inputs.append(np.concatenate([foreground, a], axis=1))
        outputs.append(target[keep].astype(np.float64) - (1.0 - a) * bg - foreground)
    design, wanted = np.concatenate(inputs), np.concatenate(outputs)
    change = np.zeros((3, 4))
    if len(design) >= MIN_COLOUR_PIXELS:
        change = np.linalg.lstsq(design, wanted, rcond=None)[0].T

    def mean_error(candidate) -> float:
        with torch.no_grad():
            return float(np.mean([np.abs(np.clip(recolour(torch.from_numpy(rgb), torch.from_numpy(alpha), background,
                                                          candidate).numpy(), 0.0, 1.0) - target).mean()
                                  for (rgb, alpha), target in zip(renders, targets)]))

    before, after = mean_error(np.zeros((3, 4))), mean_error(change)
    kept = after < before
    matrix, offset = matrix_and_offset(change if kept else np.zeros((3, 4)))
    info = {"fit_frames": len(renders), "fit_pixels": len(design), "fit_l1_before": before, "fit_l1_after": after,
            "kept": kept, "matrix": matrix.tolist(), "offset": offset.tolist()}
    return (change if kept else np.zeros((3, 4))), info
