"""``make-footage OUT``: synthetic phone footage of the procedural head, its truth written aside."""

from __future__ import annotations

import argparse
import pathlib


def _size(text: str) -> tuple[int, int]:
    try:
        width, height = (int(part) for part in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT in pixels (720x1280), got {text!r}") from None
    return width, height


def add_arguments(parser):
    from ..data.footage_settings import KINDS, FootageSettings

    d = FootageSettings()
    parser.add_argument("out", type=pathlib.Path,
                        help="output folder: OUT/footage holds the clip or photos, OUT/truth the truth")
    parser.add_argument("--kind", choices=KINDS, default=d.kind,
                        help="handheld: a camera orbiting a still head; fixed: a still camera, the head turning; "
                             "photos: JPEGs from views around the head (default %(default)s)")
    parser.add_argument("--truth", type=pathlib.Path,
                        help="folder for the truth (default OUT/truth); never inside OUT/footage")
    parser.add_argument("--size", type=_size, default=(d.width, d.height), metavar="WxH",
                        help=f"upright frame size, even numbers (default {d.width}x{d.height}: portrait 720p)")
    parser.add_argument("--seconds", type=float, default=d.seconds, help="clip length (default %(default)s)")
    parser.add_argument("--fps", type=float, default=d.fps, help="frame rate (default %(default)s)")
    parser.add_argument("--rotation-flag", action="store_true",
                        help="store the frames landscape with a 90° display matrix, as phones held upright do")
    parser.add_argument("--photos", type=int, default=d.photos, help="photos of --kind photos (default %(default)s)")
    parser.add_argument("--subject", type=int, default=d.subject, help="identity of the procedural head (default %(default)s)")
    parser.add_argument("--seed", type=int, default=d.seed, help="seed of everything (default %(default)s)")
    parser.add_argument("--focal", type=float, default=d.focal_35mm, metavar="MM",
                        help="35 mm equivalent focal length (default %(default)s: a phone's main camera)")
    parser.add_argument("--no-lens-metadata", action="store_true",
                        help="leave the focal length out of the clip's metadata and the photos' EXIF")
    parser.add_argument("--supersample", type=int, default=d.supersample,
                        help="renderer samples per pixel along each axis (default %(default)s)")
    parser.add_argument("--crf", type=int, default=d.crf, help="x264 constant quality (default %(default)s)")
    parser.add_argument("--novel-views", type=int, default=d.novel_views,
                        help="fixed cameras the footage never sees, rendered into the truth (default %(default)s)")
    parser.add_argument("--novel-every", type=int, default=d.novel_every,
                        help="render the novel views every N frames (default %(default)s; photos: every photo)")
    parser.add_argument("--novel-size", type=int, default=d.novel_size,
                        help="novel views' square size in pixels (default %(default)s)")
    parser.add_argument("--contact-sheet", type=pathlib.Path, metavar="PNG",
                        help="also write a sheet of frames read back from the footage, and the novel views of "
                             "its first frame")
    parser.add_argument("--model", type=pathlib.Path, help="use this FLAME-format model (with UVs and texture) instead")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args) -> int:
    import time

    from ..data.footage import make_footage
    from ..data.footage_settings import FootageSettings

    settings = FootageSettings(
        kind=args.kind, width=args.size[0], height=args.size[1], fps=args.fps, seconds=args.seconds,
        rotation_flag=args.rotation_flag, photos=args.photos, subject=args.subject, seed=args.seed,
        supersample=args.supersample, focal_35mm=args.focal, lens_metadata=not args.no_lens_metadata, crf=args.crf,
        novel_views=args.novel_views, novel_every=args.novel_every, novel_size=args.novel_size,
    )
    start = time.monotonic()
    folders = make_footage(args.out, settings, truth=args.truth, model_path=args.model, progress=not args.quiet)
    elapsed = time.monotonic() - start
    for path in folders.files[:3]:
        print(f"footage: {path}")
    if len(folders.files) > 3:
        print(f"footage: … {len(folders.files)} files in {folders.footage}")
    print(f"truth: {folders.truth} (never give it to the tracker)")
    if args.contact_sheet is not None:
        footage_sheet(folders, args.contact_sheet)
        print(f"contact sheet: {args.contact_sheet}")
    print(f"wrote {args.out} in {elapsed:.1f} s")
    return 0


def footage_sheet(folders, path, columns: int = 6, row_height: int = 240) -> None:
    """Frames spread over the footage as the reader decodes them (upright), then a row of the novel
    views of the first frame the truth renders them at."""
    import numpy as np

    from ..data.footage import INFO_FILE, NOVEL_DIR
    from ..io.image import read_image, write_png
    from ..io.jsonfile import read_json_object
    from ..track.decode import open_footage
    from ..track.inputs import FrameSelection

    source = folders.files[0] if len(folders.files) == 1 else folders.footage
    footage = open_footage(source)
    count = footage.info.frame_count
    wanted = set(np.linspace(0, count - 1, min(columns, count)).round().astype(int).tolist())
    frames = [f.rgb for f in footage.frames(FrameSelection(end=max(wanted) + 1), size=None) if f.index in wanted]
    info = read_json_object(folders.truth / INFO_FILE)
    novel = info["novel_views"]
    views = []
    if novel["frames"]:
        names = sorted((folders.truth / NOVEL_DIR / "images").glob(f"{novel['frames'][0]:05d}_*.png"))
        views = [(read_image(p)[..., :3] * 255 + 0.5).astype(np.uint8) for p in names]

    def row(images):
        from PIL import Image

        scaled = [np.asarray(Image.fromarray(image).resize(
            (max(1, round(image.shape[1] * row_height / image.shape[0])), row_height), Image.Resampling.LANCZOS))
            for image in images]
        return np.concatenate([np.pad(s, ((0, 0), (0, 4), (0, 0)), constant_values=255) for s in scaled], 1)

    rows = [row(frames)] + ([row(views)] if views else [])
    width = max(r.shape[1] for r in rows)
    sheet = np.concatenate([np.pad(r, ((0, 4), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows])
    write_png(path, sheet)
