"""``eval RUN``: score a trained run on the evaluation protocols; write metrics.json and metrics.md."""

from __future__ import annotations

import pathlib

from . import add_split_argument


def add_arguments(parser) -> None:
    from ..evaluate.protocol_names import ALL_PROTOCOLS, PROTOCOLS

    parser.add_argument("run", type=pathlib.Path, metavar="RUN", help="run folder written by 'train'")
    parser.add_argument(
        "--protocols", nargs="+", choices=ALL_PROTOCOLS, default=list(PROTOCOLS),
        help=f"protocols to score (default: {' '.join(PROTOCOLS)}); novel_view_aligned scores half the novel "
             "view's frames after aligning the held-out camera to the avatar on the other half, "
             "novel_view_colour_aligned after fitting the held-out camera's affine colour there",
    )
    parser.add_argument("--max-frames", type=int, help="score at most this many frames per protocol, evenly spread")
    parser.add_argument("--no-lpips", action="store_true", help="skip LPIPS (PSNR and SSIM only)")
    add_split_argument(parser)
    parser.add_argument(
        "--driver", type=pathlib.Path, metavar="CAPTURE_B",
        help="also render cross-identity reenactment driven by this capture's tracked motion",
    )
    parser.add_argument(
        "--driver-cameras", metavar="IDS",
        help="comma-separated cameras of the run's capture for --driver (default: all)",
    )
    parser.add_argument("--capture", type=pathlib.Path, help="the run's capture folder, when it has moved")
    parser.add_argument("--out", type=pathlib.Path, metavar="DIR", help="where outputs go (default: the run folder)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args) -> int:
    from ..errors import InputError
    from ..evaluate.evaluation import evaluate_run
    from ..evaluate.report import markdown_table

    if args.max_frames is not None and args.max_frames < 1:
        raise InputError(None, "--max-frames", f"must be at least 1, got {args.max_frames}")
    result = evaluate_run(
        args.run, args.protocols, args.max_frames, lpips=not args.no_lpips, driver=args.driver,
        out_dir=args.out, capture=args.capture, progress=not args.quiet,
        driver_cameras=args.driver_cameras.split(",") if args.driver_cameras else None, split=args.split,
    )
    print(markdown_table(result), end="")
    out = args.out or args.run
    print(f"wrote {out / 'metrics.json'} and {out / 'metrics.md'}")
    return 0
