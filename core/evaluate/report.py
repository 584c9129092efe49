"""What an evaluation leaves behind: the markdown table, comparison images, cross-identity strips."""

from __future__ import annotations

import math
import os
import pathlib

import numpy as np

from ..io.image import write_png

EVAL_DIR = "eval"
ERROR_GAIN = 4.0  # |prediction - truth| is faint; amplified so that errors show
STRIP_COLUMNS = 8


def json_safe(value):
    """``value`` with non-finite floats (an identical image's infinite PSNR) as ``None``."""
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _cell(value, digits: int) -> str:
    if value is None:
        return "–"
    if isinstance(value, float) and math.isinf(value):
        return "∞"
    return f"{value:.{digits}f}"


def markdown_table(result: dict) -> str:
    """The metrics as a markdown table: protocol, frames, PSNR, SSIM, LPIPS."""
    lines = [
        "# Evaluation",
        "",
        f"Run: `{result['run']}`  ",
        f"Capture: `{result['capture']}`  ",
        f"Background: {tuple(result['background'])}; {result['inference']}.",
        "",
        "| protocol | frames | PSNR (dB) ↑ | SSIM ↑ | LPIPS ↓ |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, summary in result["protocols"].items():
        lines.append(
            f"| {name.replace('_', ' ')} | {summary['frames']} | {_cell(summary.get('psnr'), 2)} "
            f"| {_cell(summary.get('ssim'), 4)} | {_cell(summary.get('lpips'), 4)} |"
        )
    for name, reason in result.get("skipped", {}).items():
        lines.append(f"| {name.replace('_', ' ')} | not run: {reason} | | | |")
    cross = result.get("cross_identity")
    if cross:
        lines += ["", f"Cross-identity reenactment (driver `{cross['driver']}`): {cross['frames']} images, "
                  f"no ground truth; strip `{cross['strip']}`."]
    return "\n".join(lines) + "\n"


def comparison_image(prediction: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Prediction | ground truth | amplified absolute error, side by side."""
    error = np.clip(np.abs(prediction - target).mean(-1, keepdims=True) * ERROR_GAIN, 0.0, 1.0)
    return np.concatenate([prediction, target, np.repeat(error, 3, axis=2)], axis=1)


def write_comparison(path: str | os.PathLike, item) -> None:
    write_png(path, comparison_image(item.prediction, item.target))


def strip_image(rows: list[list[np.ndarray]]) -> np.ndarray:
    """Images in a grid: one row per camera, one column per timestep."""
    return np.concatenate([np.concatenate(row, axis=1) for row in rows], axis=0)


def write_cross_identity(avatar, capture, run, driver, out: pathlib.Path, max_frames, progress, cameras=None) -> dict:
    """Render subject A (the run) driven by ``driver``'s tracked motion: PNGs and a strip, no metrics."""
    from ..data.capture import Capture
    from ..progress import ProgressBar
    from .protocols import DrivenParams, cross_identity

    driving = Capture.open(driver)
    identity = run.identity_params() or {
        k: v for k, v in capture.flame_params(capture.timesteps[0]).items() if k in ("shape", "static_offset")
    }
    source = DrivenParams(identity, driving, n_expr=avatar.flame.n_expr)
    cameras = list(capture.cameras) if cameras is None else list(cameras)
    count = len(cameras) * min(len(driving.timesteps), max_frames or len(driving.timesteps))
    bar = ProgressBar(count, "cross-identity") if progress else None
    images: dict[str, list[tuple[int, np.ndarray]]] = {c: [] for c in cameras}  # cross_identity checks the ids
    written = []
    for timestep, camera_id, rgb, _ in cross_identity(avatar, capture, source, run.background, cameras, max_frames):
        path = out / f"{timestep:05d}_{camera_id}.png"
        write_png(path, rgb)
        written.append(str(path))
        images[camera_id].append((timestep, rgb))
        if bar:
            bar.update()
    columns = max(len(v) for v in images.values())
    picks = np.unique(np.round(np.linspace(0, columns - 1, min(columns, STRIP_COLUMNS))).astype(int))
    strip = out / "strip.png"
    write_png(strip, strip_image([[row[i][1] for i in picks] for row in images.values()]))
    driver = str(pathlib.Path(driver).resolve())
    return {"driver": driver, "frames": len(written), "strip": str(strip), "images": written}
