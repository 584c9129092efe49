"""What an evaluation leaves behind: the markdown table, comparison images, image strips."""

from __future__ import annotations

import math
import os

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
    """Images in a grid: one row per camera, one column per timestep. Cameras of several sizes
    (photos) are padded with black to the largest (each image at its top left), never resized."""
    height = max(image.shape[0] for row in rows for image in row)
    width = max(image.shape[1] for row in rows for image in row)

    def padded(image):
        out = np.zeros((height, width, *image.shape[2:]), image.dtype)
        out[:image.shape[0], :image.shape[1]] = image
        return out

    return np.concatenate([np.concatenate([padded(image) for image in row], axis=1) for row in rows], axis=0)
