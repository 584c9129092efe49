"""``demo --out DIR``: the main job on the embedded default (the procedural head)."""

from __future__ import annotations

import pathlib
import time


def add_arguments(parser):
    parser.add_argument("--out", type=pathlib.Path, default=pathlib.Path("out/demo"), help="output folder")
    parser.add_argument("--seed", type=int, default=0, help="seed of everything random (default 0)")


def run(args) -> int:
    from ..flame.model_file import write_model_file
    from ..flame.preview import render_preview_sheet
    from ..flame.procedural import build_head
    from ..io.image import write_png

    start = time.monotonic()
    args.out.mkdir(parents=True, exist_ok=True)
    head_path = args.out / "head.pkl"
    write_model_file(head_path, build_head(subject=0, seed=args.seed))
    print(f"[demo] procedural head → {head_path}")
    sheet, tiles = render_preview_sheet(head_path)
    preview = args.out / "preview"
    write_png(preview / "contact_sheet.png", sheet)
    for name, image in tiles.items():
        write_png(preview / f"{name}.png", image)
    print(f"[demo] preview renders → {preview}/ ({len(tiles)} views)")
    print(f"[demo] done in {time.monotonic() - start:.1f} s")
    return 0
