"""``track INPUT --out CAPTURE``: a phone video (or several) or a folder of photos becomes a tracked
capture (images, masks, a camera per video, FLAME parameters per frame, 2D landmarks) on the CPU, offline
(:mod:`..track.pipeline`). Ctrl-C leaves a folder no reader takes; the same command resumes it."""

from __future__ import annotations

import pathlib


def add_arguments(parser) -> None:
    from ..track.decode import add_footage_arguments

    parser.add_argument("input", type=pathlib.Path, nargs="+",
                        help="a video file (mp4, mov, …), several videos of one subject (a camera each), a folder of "
                             "photos, or several photos")
    parser.add_argument("--out", type=pathlib.Path, required=True,
                        help="capture folder to write (new or empty; an interrupted track of the same input resumes)")
    add_footage_arguments(parser)
    parser.set_defaults(size=512)
    parser.add_argument("--focal", type=float, help="focal length in pixels of the input's frames (default: from "
                        "the file's metadata, else estimated from a phone's 26 mm; several videos: the first's "
                        "frames, one lens for all)")
    parser.add_argument("--focal-35mm", type=float, help="the same as a 35 mm equivalent focal length (mm)")
    parser.add_argument("--head", type=pathlib.Path, help="head model file (default: the procedural head)")
    add_fit_arguments(parser)
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--events", type=pathlib.Path, metavar="FILE",
                        help="also append progress as JSON lines here (how Blender follows the job)")


def add_fit_arguments(parser) -> None:
    """The fit's length, for ``track`` and ``drive``: ``--fit-steps``, ``--photometric-steps`` and
    ``--photometric-stride``."""
    parser.add_argument("--fit-steps", type=int, default=200, help="iterations of the fit (default %(default)s)")
    parser.add_argument("--photometric-steps", type=int, help="iterations of the photometric stage after the "
                        "landmark fit (0: off, minutes faster; default: those chosen on validation clips, 800 for a "
                        "video and 1920 for photos, docs/tracking.md)")
    parser.add_argument("--photometric-stride", type=int, help="the photometric stage fits a video's every N-th "
                        "frame and moves those between alike (1: every frame, slower; default: the one chosen on "
                        "validation clips, docs/tracking.md)")


def progress_reporter(args):
    """``progress(stage, done, total)`` for the tracker: a bar per stage (unless ``--quiet``) and
    ``iter`` events with an ETA in ``--events`` (the lines Blender's progress bar reads); and a
    closer that writes the ``done`` event (or nothing, when the work failed)."""
    import time

    from ..progress import ProgressBar
    from ..train.events import EventLog

    log = EventLog(args.events) if getattr(args, "events", None) else None
    bars: dict = {}
    started: dict = {}
    last = [time.monotonic()]  # a stage starts when the one before it ended (the first: now)

    def progress(stage, done, total):
        if not args.quiet:
            bar = bars.get(stage) or bars.setdefault(stage, ProgressBar(max(total, 1), stage))
            bar.total = max(total, done, 1)
            bar.update(done - bar.done)
        if log is not None:
            now = time.monotonic()
            first = started.setdefault(stage, (last[0], 0))
            last[0] = now
            rate = (done - first[1]) / (now - first[0]) if now > first[0] and done > first[1] else None
            log.emit("iter", stage=stage, step=int(done), steps=int(max(total, done, 1)),
                     eta_s=None if rate is None else (max(total, done) - done) / rate)

    def close(**done_fields):
        if log is not None:
            if done_fields:
                log.emit("done", **done_fields)
            log.close()

    return progress, close


def run(args) -> int:
    from ..errors import InputError
    from ..track.decode import open_footage, selection_from_arguments
    from ..track.fit import FitSettings
    from ..track.inputs import focal_in_pixels
    from ..track.photometric import PhotometricSettings
    from ..track.pipeline import TrackSettings, track_footage

    source = args.input[0] if len(args.input) == 1 else list(args.input)
    if any(path.resolve() in (args.out.resolve(), *args.out.resolve().parents) for path in args.input):
        raise InputError(args.out, None, "the capture folder must not hold the input")
    info = open_footage(source).info
    for line in info.lines():
        print(line)
    focal = args.focal if args.focal is not None else focal_in_pixels(args.focal_35mm, info.width, info.height)
    settings = TrackSettings(size=args.size, focal_px=focal, threads=args.threads or 2,
                             fit=FitSettings(steps=args.fit_steps, photometric=PhotometricSettings(
                                 steps=args.photometric_steps, stride=args.photometric_stride)),
                             head_file=args.head)
    progress, close = progress_reporter(args)
    try:
        report = track_footage(source, args.out, settings, selection_from_arguments(args), progress)
    except BaseException:
        close()
        raise
    close(path=str(args.out), frames=report["frames"], lost_frames=report["lost_frames"],
          reprojection_px=report["reprojection_px"]["mean"])
    lost = report["lost_frames"]
    print(f"tracked {report['frames']} frames ({report['seconds']['detect']:.1f} s finding the face, "
          f"{report['detect_ms_per_frame']:.0f} ms a frame; {report['seconds']['fit']:.1f} s fitting): "
          f"landmarks reproject to {report['reprojection_px']['mean']:.2f} px (worst frame "
          f"{report['reprojection_px']['max']:.2f} px), focal {report['focal_px']:.1f} px")
    for clip in report.get("clips", []):
        print(f"  {clip['camera']}: {clip['source']}, {clip['frames']} frames, focal {clip['focal_px']:.1f} px")
    if lost:
        print(f"warning: no face in {len(lost)} frames (first: {lost[:5]}): their parameters are interpolated and "
              "they are left out of the splits (tracking.json)")
    if report["two_faces_frames"]:
        print(f"warning: two or more faces in {len(report['two_faces_frames'])} frames: the largest was followed")
    print(f"wrote {args.out} (train {report['splits']['train']} frames, test {report['splits']['test']}); "
          f"next: python -m mogaface check-capture {args.out} --full, then train")
    return 0
