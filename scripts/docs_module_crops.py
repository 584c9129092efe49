"""Write where the MoGaFace modules help, for docs/results.md: the held-out camera's frames rendered by
a fine-tuning run and a full-method run of the same capture and seed, against the truth.

    python -m mogaface ablate CAPTURE --out ABL --variants finetune,full_prior ...
    .venv/bin/python scripts/docs_module_crops.py CAPTURE ABL/runs/finetune/seed0 ABL/runs/full_prior/seed0 \
        [--out docs/images/module_crops.png] [--frames 16]

Two rows: the frame where the full method gains most over fine-tuning, then the frame where it gains
least. Each row: the truth, fine-tuning, the full method (the whole image, then a crop twice
enlarged around where the error falls most), and the error change: red where the full method's
error is smaller, blue where it is larger. Every image comes from the runs' tracked source on the
held-out camera (no input reads the scored image). Prints each frame's PSNR of both runs.
"""

from __future__ import annotations

import argparse
import pathlib

import numpy as np

CROP = 0.3  # the crop's side, a fraction of the image's shorter side
GAIN = 8.0  # the error change's amplification in the picture


def _items(capture, run_dir: pathlib.Path, frames: int) -> list:
    from mogaface.core.evaluate.protocols import protocol_frames, run_protocol
    from mogaface.core.evaluate.sources.tracked import TrackedParams
    from mogaface.core.run.folder import RunFolder

    run = RunFolder(run_dir)
    avatar = run.load_avatar()
    chosen = protocol_frames(capture, "novel_view", frames)
    return list(run_protocol(avatar, capture, TrackedParams(capture, run), chosen, run.background))


def _row(truth: np.ndarray, finetune: np.ndarray, full: np.ndarray) -> np.ndarray:
    from scipy.ndimage import uniform_filter

    errors = [np.abs(image - truth).mean(-1) for image in (finetune, full)]
    error_change = errors[0] - errors[1]
    h, w = truth.shape[:2]
    side = int(CROP * min(h, w))
    weight = uniform_filter(errors[0] + errors[1], side, mode="nearest")
    y, x = np.unravel_index(np.argmax(weight), weight.shape)
    y0, x0 = int(np.clip(y - side // 2, 0, h - side)), int(np.clip(x - side // 2, 0, w - side))
    change = np.zeros((h, w, 3), np.float32)
    change[..., 0] = np.clip(error_change * GAIN, 0, 1)
    change[..., 2] = np.clip(-error_change * GAIN, 0, 1)
    tiles = []
    for image in (truth, finetune, full, change):
        whole = image.copy()
        whole[y0:y0 + side, [x0, x0 + side - 1]] = (1.0, 1.0, 0.0)
        whole[[y0, y0 + side - 1], x0:x0 + side] = (1.0, 1.0, 0.0)
        crop = image[y0:y0 + side, x0:x0 + side].repeat(2, 0).repeat(2, 1)
        crop = np.pad(crop, ((0, h - crop.shape[0]), (0, 0), (0, 0)), constant_values=1.0)[:h]
        tiles += [whole, crop, np.ones((h, 6, 3), np.float32)]
    return np.concatenate(tiles[:-1], 1)


def main(argv=None) -> int:
    from mogaface.core.data.capture import Capture
    from mogaface.core.io.image import write_png
    from mogaface.core.metrics.images import psnr

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("capture", type=pathlib.Path)
    parser.add_argument("finetune", type=pathlib.Path, help="a fine-tuning run of the capture")
    parser.add_argument("full", type=pathlib.Path, help="a full-method run of the capture")
    parser.add_argument("--out", type=pathlib.Path, default=pathlib.Path("docs/images/module_crops.png"))
    parser.add_argument("--frames", type=int, default=16, help="held-out-camera frames to look through")
    args = parser.parse_args(argv)
    capture = Capture.open(args.capture)
    pairs = list(zip(_items(capture, args.finetune, args.frames), _items(capture, args.full, args.frames)))
    gains = []
    for a, b in pairs:
        scores = float(psnr(a.prediction, a.target)), float(psnr(b.prediction, b.target))
        gains.append(scores[1] - scores[0])
        print(f"timestep {a.frame.timestep_index} camera {a.frame.camera_id}: fine-tuning {scores[0]:.2f} dB, "
              f"full method {scores[1]:.2f} dB")
    rows = [_row(pairs[k][0].target, pairs[k][0].prediction, pairs[k][1].prediction)
            for k in (int(np.argmax(gains)), int(np.argmin(gains)))]
    write_png(args.out, np.concatenate([rows[0], np.ones((6, rows[0].shape[1], 3), np.float32), rows[1]], 0))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
