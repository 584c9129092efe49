"""Reading footage: a phone's video file, several of them, or a folder of photos, as upright RGB frames.

:func:`open_footage` opens an input with its reader (:mod:`.videos`, :mod:`.photos`; what they
share is :mod:`.inputs`) and says what it holds before a frame is converted (:class:`FootageInfo`:
frame count, rate, upright size, codec, duration, focal length), and ``frames()`` yields
:class:`Frame` ``(index, time, rgb)``: ``index`` counts the input's frames from 0 (a video's
in presentation order, a folder's photos in name order), ``time`` is seconds from the video's
first frame (``None`` for photos), ``rgb`` is ``uint8 (H, W, 3)``, upright.

Upright: a video's display matrix (or the older ``rotate`` tag) and a photo's EXIF orientation are
applied, as a phone's gallery shows them. Both are turned into one of the eight EXIF orientations
and applied by :func:`upright`.

Bad input raises :class:`~mogaface.core.errors.InputError` naming the file, the field and what
was expected. A video damaged part-way (a truncated file, corrupt packets) yields the frames
before the damage and then warns (:class:`FootageWarning`); one with no decodable frame is an
error when opened. Declared frame sizes are checked against the limits (8K) before any frame is
decoded. See docs/tracking.md, "Reading footage".
"""

from __future__ import annotations

import dataclasses
import math
import os
import pathlib

from ..errors import InputError
from ..io.files import check_regular_file
from .inputs import PHOTO_SUFFIXES, UNSUPPORTED_PHOTO_SUFFIXES, FrameSelection
from .photos import Photos
from .videos import Video


class Clips:
    """Several videos of one subject (several phones, or one phone's clips filmed one after
    another): each its own camera and lens, not synchronised. ``videos`` are read one by one;
    ``info`` sums them up (its own fields are the first clip's, ``info.clips`` each one's)."""

    kind = "videos"

    def __init__(self, paths: list):
        self.videos = [Video(path) for path in paths]  # each checked as a regular file when it opens
        self.path = self.videos[0].path
        infos = tuple(video.info for video in self.videos)
        focals = {info.focal_35mm for info in infos}
        self.info = dataclasses.replace(
            infos[0], kind="videos", frame_count=sum(info.frame_count for info in infos),
            frame_count_exact=all(info.frame_count_exact for info in infos),
            duration=sum(info.duration or 0.0 for info in infos), focal_35mm=focals.pop() if len(focals) == 1 else None,
            clips=infos)


def _input_kind(path: pathlib.Path) -> str:
    """What one of several inputs is, by its name: a ``folder``, a ``photo`` or (anything else) a ``video``."""
    if path.is_dir():
        return "folder"
    suffix = path.suffix.lower()
    return "photo" if suffix in PHOTO_SUFFIXES or suffix in UNSUPPORTED_PHOTO_SUFFIXES else "video"


def open_footage(source: str | os.PathLike | list) -> Video | Photos | Clips:
    """A video file, a folder of photos, a list of photo files (one photo file alone is a list of
    one) or a list of video files (:class:`Clips`); its ``info`` says what it holds, ``frames()``
    reads it (each of ``videos``, for clips). The readers are :mod:`.videos` and :mod:`.photos`."""
    if isinstance(source, list | tuple):
        if len(source) == 1:
            return open_footage(source[0])
        paths = [pathlib.Path(p) for p in source]
        kinds = [_input_kind(p) for p in paths]
        if set(kinds) == {"video"}:
            return Clips(paths)
        if set(kinds) == {"photo"}:
            return Photos(paths)
        rule = "several inputs must all be videos (a camera each) or all photos"
        if "folder" in kinds:
            raise InputError(paths[kinds.index("folder")], None, f"is a folder: a folder of photos is given alone; {rule}")
        odd = next(p for p, kind in zip(paths, kinds) if kind != kinds[0])
        raise InputError(odd, None, f"is a {_input_kind(odd)} among {kinds[0]}s; {rule}")
    path = pathlib.Path(source)
    if path.is_dir():
        return Photos(path)
    check_regular_file(path)
    if path.suffix.lower() in PHOTO_SUFFIXES:
        return Photos([path])
    if path.suffix.lower() in UNSUPPORTED_PHOTO_SUFFIXES:
        raise InputError(path, None, f"{UNSUPPORTED_PHOTO_SUFFIXES[path.suffix.lower()]} photos cannot be read; "
                                     f"expected JPEG or PNG")
    return Video(path)


# -- the command line --------------------------------------------------------------------------


def frame_position(text: str) -> tuple[str, float]:
    """An argparse type: ``"90"`` is frame 90, ``"3s"`` or ``"2.5s"`` is that many seconds."""
    import argparse

    value = text.strip().lower()
    try:
        if value.endswith("s"):
            seconds = float(value[:-1])
            if math.isfinite(seconds) and seconds >= 0:
                return "seconds", seconds
        else:
            frame = int(value)
            if frame >= 0:
                return "frame", frame
    except ValueError:
        pass
    raise argparse.ArgumentTypeError(f"expected a frame number (90) or seconds (3s, 2.5s), got {text!r}")


def add_footage_arguments(parser) -> None:
    """The reading options of a command that reads footage (``track``)."""
    parser.add_argument("--start", type=frame_position, metavar="N|Ts",
                        help="first frame to read: a frame number, or seconds with an s (2.5s)")
    parser.add_argument("--end", type=frame_position, metavar="N|Ts",
                        help="read up to (not including) this frame number or time")
    parser.add_argument("--stride", type=int, default=1, help="read every N-th frame of the range (default 1)")
    parser.add_argument("--fps", type=float, help="drop frames evenly down to this rate (videos)")
    parser.add_argument("--size", type=int, help="longer side of the frames in pixels, aspect kept (default: as stored)")
    parser.add_argument("--threads", type=int, help="decoder threads (default: FFmpeg's choice)")


def selection_from_arguments(args) -> FrameSelection:
    """The :class:`FrameSelection` that :func:`add_footage_arguments`' options describe."""
    fields = {}
    for name in ("start", "end"):
        value = getattr(args, name)
        if value is not None:
            kind, amount = value
            fields[name if kind == "frame" else f"{name}_time"] = amount
    return FrameSelection(stride=args.stride, fps=args.fps, **fields)
