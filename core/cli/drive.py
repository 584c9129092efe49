"""``drive CLIP --avatar RUN_OR_CAPTURE --out FOLDER``: a performance clip drives an avatar. The
clip is tracked with the avatar's head shape held fixed; its expression, jaw, eyes and head motion
are written as ``flame_param`` files (``render --params`` and Blender's Import Tracking read them),
retimed to ``--to-fps``, thinned within ``--tolerance`` (:mod:`..workflows.drive`)."""

from __future__ import annotations

import pathlib


def add_arguments(parser) -> None:
    from ..track.decode import add_footage_arguments
    from .track import add_fit_arguments

    parser.add_argument("input", type=pathlib.Path, metavar="CLIP", help="the performance: a video file")
    parser.add_argument("--avatar", type=pathlib.Path, required=True,
                        help="a run folder, a capture folder, or an .npz with the head's 'shape' (then --head)")
    parser.add_argument("--head", type=pathlib.Path, help="head model file (default: the run's or capture's)")
    parser.add_argument("--out", type=pathlib.Path, required=True,
                        help="flame_param folder to write (new or empty), with drive.json")
    add_footage_arguments(parser)
    parser.set_defaults(size=512)
    parser.add_argument("--to-fps", type=float, help="frame rate of the written frames (default: the clip's)")
    parser.add_argument("--keep-head-still", action="store_true",
                        help="the avatar keeps its rest pose: only the face (expression, jaw, eyes) moves")
    parser.add_argument("--tolerance", type=float, default=0.0,
                        help="drop keys that linear interpolation gives within this (default 0: every frame)")
    parser.add_argument("--capture", type=pathlib.Path, help="also keep the tracked capture of the clip here")
    add_fit_arguments(parser)
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--events", type=pathlib.Path, metavar="FILE",
                        help="also append progress as JSON lines here (how Blender follows the job)")


def run(args) -> int:
    from ..errors import InputError
    from ..track.decode import selection_from_arguments
    from ..workflows.drive import DriveSettings, Identity, drive_clip
    from .track import progress_reporter

    if args.tolerance < 0 or (args.to_fps is not None and args.to_fps <= 0):
        raise InputError(None, "--tolerance/--to-fps", "expected a tolerance ≥ 0 and a positive frame rate")
    identity = Identity.of(args.avatar, args.head)
    settings = DriveSettings(fps=args.to_fps, keep_head_still=args.keep_head_still, tolerance=args.tolerance,
                             fit_steps=args.fit_steps, photometric_steps=args.photometric_steps,
                             photometric_stride=args.photometric_stride, size=args.size, threads=args.threads or 2)
    progress, close = progress_reporter(args)
    try:
        result = drive_clip(args.input, identity, args.out, settings, selection_from_arguments(args),
                            capture=args.capture, progress=progress)
    except BaseException:
        close()
        raise
    close(path=str(args.out), frames=result["frames"], lost_frames=result["lost_frames"], fps=result["fps"])
    print(f"drove {result['frames']} frames at {result['fps']:g} fps (clip {result['clip_fps']:g} fps, "
          f"{result['tracked_frames']} tracked, landmarks reproject to {result['reprojection_px']:.2f} px); "
          f"{result['keys']} keys of {result['keys_dense']} within {result['tolerance']:g}")
    if result["lost_frames"]:
        print(f"warning: no face in {len(result['lost_frames'])} frames (first: {result['lost_frames'][:5]}): "
              "interpolated")
    print(f"wrote {args.out}; next: python -m mogaface render RUN --params {args.out} --timesteps "
          f"0-{result['frames'] - 1}")
    return 0
