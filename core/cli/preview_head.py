"""``preview-head MODEL --out DIR``: a contact sheet of a head model in several poses and views."""

from __future__ import annotations

import pathlib


def add_arguments(parser):
    parser.add_argument("model", type=pathlib.Path, help="FLAME-format model (.pkl or .npz) with UVs and texture")
    parser.add_argument("--out", type=pathlib.Path, required=True, help="output folder for the PNG files")
    parser.add_argument("--size", type=int, default=256, help="pixels per view (default 256)")


def run(args) -> int:
    from ..data.head_preview import render_preview_sheet
    from ..io.image import write_png

    sheet, tiles = render_preview_sheet(args.model, size=args.size)
    args.out.mkdir(parents=True, exist_ok=True)
    write_png(args.out / "contact_sheet.png", sheet)
    for name, image in tiles.items():
        write_png(args.out / f"{name}.png", image)
    print(f"wrote {args.out / 'contact_sheet.png'} and {len(tiles)} views")
    return 0
