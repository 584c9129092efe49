"""Write the two renderers' images of docs/data-format.md: the same frames of two captures that differ
only in ``--renderer``, side by side, with the face enlarged.

    python -m mogaface make-capture out/cycles/mesh_s1 --subject 1 --views 8 --timesteps 48
    python -m mogaface make-capture out/cycles/cap_s1 --subject 1 --views 8 --timesteps 48 --renderer cycles
    .venv/bin/python scripts/docs_renderer_images.py out/cycles/mesh_s1 out/cycles/cap_s1 [--out docs/images]

``capture_renderers.png``: rows are timesteps (neutral, the strongest smile, the brows raised
highest), each the held-out frontal camera's whole image and its face twice enlarged, mesh
renderer left, Cycles right.
"""

from __future__ import annotations

import argparse
import pathlib

import numpy as np


def _strongest(capture, names) -> int:
    """The timestep whose true expression most activates ``names`` (substrings of component names)."""
    from mogaface.core.flame.model import FlameModel
    from mogaface.core.io.npz import load_npz

    model = FlameModel.load(capture / "head.pkl")
    picked = [k for k, n in enumerate(model.expression_names) if any(s in n for s in names)]
    files = sorted((capture / "flame_param_gt").glob("*.npz"))
    scores = [float(np.sum(load_npz(f)["expr"].reshape(-1)[picked])) for f in files]
    return int(files[int(np.argmax(scores))].stem)


def main(argv=None) -> int:
    from mogaface.core.data.capture import Capture
    from mogaface.core.io.image import write_png

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("mesh", type=pathlib.Path, help="the capture made by the mesh renderer")
    parser.add_argument("cycles", type=pathlib.Path, help="the same capture made by Cycles")
    parser.add_argument("--out", default="docs/images", help="folder for the image")
    args = parser.parse_args(argv)
    captures = [Capture.open(args.mesh), Capture.open(args.cycles)]
    frontal = [f for f in captures[0].frames("val")][0].camera_id
    timesteps = [0, _strongest(args.cycles, ("smile",)), _strongest(args.cycles, ("brow_raise",))]
    rows = []
    for timestep in timesteps:
        tiles = []
        for capture in captures:
            frame = next(f for f in capture.frames() if f.camera_id == frontal and f.timestep_index == timestep)
            rgb = capture.load_image(frame)[0]
            h, w = rgb.shape[:2]
            face = rgb[int(0.12 * h):int(0.62 * h), int(0.25 * w):int(0.75 * w)]
            face = face.repeat(2, 0).repeat(2, 1)[:h]
            tiles += [rgb, face, np.ones((h, 6, 3), np.float32)]
        rows.append(np.concatenate(tiles[:-1], 1))
    write_png(pathlib.Path(args.out) / "capture_renderers.png", np.concatenate(rows, 0))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
