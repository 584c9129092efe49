"""A quick novel-view check at the end of training: the val split (held-out camera, training
timesteps), never trained on. The full protocols live in :mod:`mogaface.core.evaluate`."""

from __future__ import annotations

import numpy as np
import torch

from ..avatar.avatar import Avatar
from ..metrics import images as image_metrics
from .config import EvalSection
from .data import FlameTable, TrainingData


def evenly_spaced(items: list, count: int) -> list:
    """``count`` items spread over ``items`` (all of them when ``count`` is 0 or too large)."""
    if count <= 0 or count >= len(items):
        return list(items)
    return [items[i] for i in np.linspace(0, len(items) - 1, count).round().astype(int)]


def evaluate_val(avatar: Avatar, data: TrainingData, table: FlameTable, settings: EvalSection) -> dict:
    """Mean PSNR/SSIM(/LPIPS) over val frames, on the whole image and on the foreground mask."""
    frames = [f for f in data.capture.frames("val") if f.timestep_index in table.row]
    frames = evenly_spaced(frames, settings.max_frames)
    background = torch.tensor(data.background, dtype=torch.float32)
    rows: dict[str, list[float]] = {}
    for frame in frames:
        with torch.no_grad():
            params = table.params(frame.timestep_index)
            out = avatar.render(params, data.capture.camera(frame), background)
        pred = out.rgb.clamp(0, 1).numpy()
        target, mask = data.capture.load_image(frame)
        values = {
            "psnr": image_metrics.psnr(pred, target),
            "ssim": image_metrics.ssim(pred, target),
            "psnr_masked": image_metrics.psnr(pred, target, mask),
            "ssim_masked": image_metrics.ssim(pred, target, mask),
        }
        if settings.lpips:
            values["lpips"] = image_metrics.lpips(pred, target)
        for key, value in values.items():
            rows.setdefault(key, []).append(value)
    cameras = sorted({f.camera_id for f in frames})
    return {"split": "val", "frames": len(frames), "cameras": cameras,
            **{key: float(np.mean(values)) for key, values in rows.items()}}
