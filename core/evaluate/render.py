"""Render a run's avatar at chosen timesteps and cameras into image files.

PNG: sRGB on the training background, what the evaluation scores. EXR: RGBA, linear light,
premultiplied by alpha (the EXR convention compositors such as Blender's expect). A training
camera whose colour the run learned is rendered in that colour, as evaluation scores it.
"""

from __future__ import annotations

import os
import pathlib

import numpy as np

from ..avatar.avatar import render_frame
from ..data.capture_info import capture_info
from ..errors import InputError
from ..io.atomic import check_output_target
from ..io.image import srgb_to_linear, write_exr, write_png
from ..run.folder import RunFolder, load_flame_file
from .protocols import TrackedParams
from .sources.corrected import run_inference

RENDER_DIR = "renders"


def default_camera(capture) -> str:
    """The held-out (frontal) camera when the capture names one, else the first camera."""
    held_out = capture_info(capture.root).get("val_camera")
    if held_out in capture.cameras:
        return held_out
    val = capture.splits.get("val")
    return val[0].camera_id if val else next(iter(capture.cameras))


def exr_channels(rgb_black: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """A render on black (premultiplied sRGB) → premultiplied linear RGB."""
    safe = np.where(alpha > 1e-6, alpha, 1.0)[..., None]
    straight = np.clip(rgb_black / safe, 0.0, 1.0)
    return (srgb_to_linear(straight) * alpha[..., None]).astype(np.float32)


def render_run(
    run_dir: str | os.PathLike,
    timesteps: list[int],
    cameras: list[str] | None = None,
    *,
    out_dir: str | os.PathLike | None = None,
    exr: bool = False,
    params_dir: str | os.PathLike | None = None,
    capture: str | os.PathLike | None = None,
    avatar=None,
) -> list[pathlib.Path]:
    """Write ``{t:05d}_{camera}.png`` (and ``.exr``) per timestep and camera; returns the files."""
    run = RunFolder(run_dir, capture)
    out = pathlib.Path(out_dir) if out_dir is not None else run.root / RENDER_DIR
    check_output_target(out, folder=True)  # before any rendering: a FIFO or device there is refused now
    cap = run.open_capture()
    cameras = cameras or [default_camera(cap)]
    for camera_id in cameras:
        if camera_id not in cap.cameras:
            raise InputError(cap.root, "camera", f"no camera {camera_id!r} (have {', '.join(cap.cameras)})")
    modulated, modules_source = run_inference(run, cap, image_assisted=False)
    avatar = (modulated or run.load_avatar()) if avatar is None else avatar
    source = modules_source or TrackedParams(cap, run, avatar.flame)
    background = np.asarray(run.background, dtype=np.float32)
    colours = getattr(avatar, "camera_colours", None) or {}
    written = []
    for timestep in timesteps:
        if params_dir is not None:
            path = pathlib.Path(params_dir) / f"{timestep:05d}.npz"
            if not path.exists():
                raise InputError(path, None, f"file not found (no FLAME parameters for timestep {timestep})")
            params = load_flame_file(path)
            avatar.flame.check_counts(params, path)
        else:
            params = source.params_for(timestep)
        for camera_id in cameras:
            camera = cap.camera_at(camera_id, timestep)  # its pose at that timestep (per sequence in unions)
            rgb_black, alpha = render_frame(avatar, params, camera, (0.0, 0.0, 0.0), clamp=False,
                                            colour=colours.get(camera_id))
            stem = f"{timestep:05d}_{camera_id}"
            write_png(out / f"{stem}.png", np.clip(rgb_black + (1.0 - alpha[..., None]) * background, 0.0, 1.0))
            written.append(out / f"{stem}.png")
            if exr:
                write_exr(out / f"{stem}.exr", exr_channels(rgb_black, alpha), alpha)
                written.append(out / f"{stem}.exr")
    return written
