"""``make-capture OUT``: render a synthetic multi-view capture of the procedural head."""

from __future__ import annotations

import pathlib


def add_arguments(parser):
    from ..data.generator import CaptureSettings

    d = CaptureSettings()
    parser.add_argument("out", type=pathlib.Path, help="output capture folder")
    parser.add_argument("--subject", type=int, default=d.subject, help="identity of the procedural head (default %(default)s)")
    parser.add_argument("--views", type=int, default=d.views, help="cameras in the dome (default %(default)s)")
    parser.add_argument("--timesteps", type=int, default=d.timesteps, help="timesteps over all sequences (default %(default)s)")
    parser.add_argument("--size", type=int, default=d.size, help="image width and height in pixels (default %(default)s)")
    parser.add_argument(
        "--expr-noise", type=float, default=d.expr_noise,
        help="std of the tracked expression coefficients' error (default %(default)s; 0 = perfect tracking)",
    )
    parser.add_argument(
        "--pose-noise", type=float, default=d.pose_noise,
        help="std in radians of the tracked head, neck, jaw and eye rotations' error (default %(default)s)",
    )
    parser.add_argument(
        "--camera-noise", type=float, default=d.camera_noise,
        help="degrees of rotation error (plus 5 mm per degree) in the cameras written to the json; "
        "the true ones go to cameras_gt.json (default %(default)s)",
    )
    parser.add_argument("--seed", type=int, default=d.seed, help="seed (default %(default)s)")
    parser.add_argument("--model", type=pathlib.Path, help="use this FLAME-format model (with UVs and texture) instead")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args) -> int:
    import time

    from ..data.generator import CaptureSettings, make_capture
    from ..data.validate import validate_capture

    settings = CaptureSettings(
        subject=args.subject, views=args.views, timesteps=args.timesteps, size=args.size,
        expr_noise=args.expr_noise, pose_noise=args.pose_noise, camera_noise=args.camera_noise, seed=args.seed,
    )
    start = time.monotonic()
    make_capture(args.out, settings, model_path=args.model, progress=not args.quiet)
    elapsed = time.monotonic() - start
    for line in validate_capture(args.out).lines():
        print(line)
    print(f"wrote {args.out} in {elapsed:.1f} s")
    return 0
