"""``make-capture OUT``: render a synthetic multi-view capture of the procedural head."""

from __future__ import annotations

import pathlib


def add_arguments(parser):
    from ..data.capture_settings import CaptureSettings

    d = CaptureSettings()
    parser.add_argument("out", type=pathlib.Path, help="output capture folder")
    parser.add_argument("--subject", type=int, default=d.subject, help="identity of the procedural head (default %(default)s)")
    parser.add_argument("--views", type=int, default=d.views, help="cameras in the dome (default %(default)s)")
    parser.add_argument("--timesteps", type=int, default=d.timesteps, help="timesteps over all sequences (default %(default)s)")
    parser.add_argument("--size", type=int, default=d.size,
                        help="image width in pixels, and height unless --height (default %(default)s)")
    parser.add_argument("--height", type=int, help="image height in pixels (default: --size, square; NeRSemble's "
                                                   "802×550 is --size 802 --height 550)")
    groups = (("expr", "expression coefficients"), ("pose", "global, neck, jaw and eye rotations (radians)"),
              ("translation", "translation (metres)"))
    for group, what in groups:
        parser.add_argument(
            f"--{group}-noise", type=float,
            help=f"std of the tracked {what}' drifting error (default {getattr(d, f'{group}_noise')}; 0 = none)",
        )
        parser.add_argument(
            f"--{group}-correlation", type=float, default=getattr(d, f"{group}_correlation"),
            help="correlation length in timesteps of that error (default %(default)s; 0 = independent per timestep)",
        )
        parser.add_argument(
            f"--{group}-bias", type=float, default=getattr(d, f"{group}_bias"),
            help=f"std of the tracked {what}' constant bias per coefficient (default %(default)s)",
        )
    parser.add_argument(
        "--iid-noise", action="store_true",
        help="the older error model: independent per timestep, no bias (expr 0.5, pose 0.01, translation 0.001 "
        "unless given)",
    )
    parser.add_argument(
        "--camera-noise", type=float, default=d.camera_noise,
        help="degrees of rotation error (plus 5 mm per degree unless --camera-centre-noise) in the cameras "
        "written to the json; the true ones go to cameras_gt.json (default %(default)s)",
    )
    parser.add_argument(
        "--camera-centre-noise", type=float, metavar="MM",
        help="millimetres of error (std per axis) in those cameras' centres (default: 5 per degree of "
        "--camera-noise)",
    )
    parser.add_argument(
        "--camera-delay", type=float, default=d.camera_delay,
        help="unsynchronised cameras: std, in timesteps, of the moment each camera takes its images "
        "(the held-out frontal camera keeps the tracking's; the true delays go to capture_info.json; "
        "default %(default)s)",
    )
    parser.add_argument(
        "--landmark-noise", type=float, default=d.landmark_noise,
        help="pixels of the simulated landmark detector's error, new in every image (default %(default)s)",
    )
    parser.add_argument(
        "--landmark-bias", type=float, default=d.landmark_bias,
        help="pixels of its constant error per camera and landmark (default %(default)s)",
    )
    parser.add_argument(
        "--camera-colour", type=float, metavar="SPREAD",
        help="cameras that disagree in white balance, exposure and vignetting: 1 is an uncalibrated rig's "
        "spread, 0 none; the truth goes to camera_colour_gt.json (default: 1 with --renderer cycles, else 0)",
    )
    parser.add_argument(
        "--renderer", choices=("mesh", "cycles"), default=d.renderer,
        help="mesh: the fast reference rasteriser (diffuse shading of the painted texture); cycles: Blender's "
        "path tracer with skin, expression wrinkles, wet eyes and hair, in a child process that resumes where "
        "it stopped (needs the bpy module; default %(default)s)",
    )
    parser.add_argument("--samples", type=int, default=d.samples,
                        help="Cycles' samples per pixel, denoised (default %(default)s)")
    parser.add_argument("--threads", type=int, help="Cycles' render threads (default: all cores)")
    parser.add_argument("--render-part", metavar="K/N",
                        help="with --renderer cycles: render only the K-th of N shares of the images (one machine "
                             "of N), into OUT/.cycles/renders; gather every share's images there and run the same "
                             "command without it to write the capture")
    parser.add_argument("--seed", type=int, default=d.seed, help="seed (default %(default)s)")
    parser.add_argument("--model", type=pathlib.Path, help="use this FLAME-format model (with UVs and texture) instead")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args) -> int:
    import time

    from ..data.capture_settings import CaptureSettings
    from ..data.generator import make_capture
    from ..data.sequences import NOISE_GROUPS
    from ..data.validate import validate_capture

    given = {f"{g}_noise": getattr(args, f"{g}_noise") for g in NOISE_GROUPS if getattr(args, f"{g}_noise") is not None}
    if args.iid_noise:
        noise = CaptureSettings.iid_noise(**given)
    else:
        noise = {f"{g}_{k}": getattr(args, f"{g}_{k}") for g in NOISE_GROUPS for k in ("correlation", "bias")}
        noise.update(given)
    settings = CaptureSettings(
        subject=args.subject, views=args.views, timesteps=args.timesteps, size=args.size, height=args.height,
        camera_noise=args.camera_noise, camera_centre_noise=args.camera_centre_noise,
        camera_delay=args.camera_delay, landmark_noise=args.landmark_noise, landmark_bias=args.landmark_bias,
        camera_colour=(1.0 if args.renderer == "cycles" else 0.0) if args.camera_colour is None else args.camera_colour,
        renderer=args.renderer, samples=args.samples, seed=args.seed, **noise,
    )
    part = (1, 1)
    if args.render_part is not None:
        from ..data.cycles_job import JOB_DIR, parse_part
        from ..errors import InputError

        if args.renderer != "cycles":
            raise InputError(None, "render part", "splits Cycles' images between machines: give --renderer cycles")
        part = parse_part(args.render_part)
    start = time.monotonic()
    make_capture(args.out, settings, model_path=args.model, progress=not args.quiet, threads=args.threads,
                 render_part=part)
    elapsed = time.monotonic() - start
    if part != (1, 1):
        print(f"rendered share {part[0]} of {part[1]} into {args.out / JOB_DIR / 'renders'} in {elapsed:.1f} s; "
              "gather every share's images there and run the same command without --render-part to write the capture")
        return 0
    for line in validate_capture(args.out).lines():
        print(line)
    print(f"wrote {args.out} in {elapsed:.1f} s")
    return 0
