"""Reading footage: a phone's video file or a folder of photos, as upright RGB frames.

:func:`open_footage` says what an input is before a frame is converted (:class:`FootageInfo`:
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

import collections
import dataclasses
import math
import os
import pathlib
import re
import struct
import warnings
from collections.abc import Iterator
from typing import NamedTuple

import numpy as np

from ..camera import focal_from_35mm
from ..errors import InputError
from ..io.files import check_regular_file
from ..io.video import APPLE_FOCAL_35MM
from ..limits import MAX_IMAGE_PIXELS, MAX_IMAGE_SIDE, MAX_VIDEO_PIXELS, MAX_VIDEO_SIDE

PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png")
# Photo formats phones write that pillow cannot decode here: refused by name rather than ignored.
UNSUPPORTED_PHOTO_SUFFIXES = {".heic": "HEIC", ".heif": "HEIF", ".dng": "DNG (raw)", ".avif": "AVIF"}
EXIF_IFD = 0x8769
EXIF_ORIENTATION = 0x0112
EXIF_FOCAL_35MM = 0xA405  # FocalLengthIn35mmFilm
HDR_TRANSFERS = {16: "PQ (SMPTE ST 2084)", 18: "HLG (ARIB STD-B67)"}


class FootageWarning(UserWarning):
    """Footage that is read, but not all of it or not as recorded (damage, HDR colours)."""


class Frame(NamedTuple):
    index: int  # the input's frame number, from 0
    time: float | None  # seconds from the video's first frame; None for photos
    rgb: np.ndarray  # uint8 (H, W, 3), upright


@dataclasses.dataclass(frozen=True)
class PhotoInfo:
    """One photo of a folder: its upright size, EXIF orientation (1–8) and lens."""

    name: str
    width: int
    height: int
    orientation: int
    focal_35mm: float | None
    format: str


@dataclasses.dataclass(frozen=True)
class FootageInfo:
    """What an input holds, read from its headers (and, for a video, its first frame).

    ``frame_count`` is exact for photos and for videos whose container counts its frames (MP4,
    MOV); otherwise it is ``duration × fps`` rounded and ``frame_count_exact`` is False.
    ``width``/``height`` are the upright size (a video stored landscape with a 90° flag is
    portrait here; photos of mixed sizes give the first photo's, and ``photos`` holds each).
    ``focal_35mm`` is the 35 mm equivalent focal length from EXIF ``FocalLengthIn35mmFilm`` or the
    video's metadata, ``focal_px`` the same in pixels of the upright size (by the diagonal).
    """

    path: pathlib.Path
    kind: str  # "video" or "photos"
    frame_count: int
    frame_count_exact: bool
    fps: float | None
    width: int
    height: int
    codec: str
    duration: float | None
    orientation: int = 1  # the EXIF orientation code the video's display matrix amounts to (photos: each its own)
    stored_width: int = 0  # a video's frame size as stored, before the orientation
    stored_height: int = 0
    focal_35mm: float | None = None
    transfer: str | None = None  # a video's HDR transfer function, when it has one
    photos: tuple[PhotoInfo, ...] = ()
    ignored: tuple[str, ...] = ()  # files of a photo folder that are not photos

    @property
    def focal_px(self) -> float | None:
        return focal_in_pixels(self.focal_35mm, self.width, self.height)

    @property
    def sizes(self) -> collections.Counter:
        """Upright sizes ``(width, height)`` and how many frames have each."""
        if self.kind == "photos":
            return collections.Counter((p.width, p.height) for p in self.photos)
        return collections.Counter({(self.width, self.height): self.frame_count})

    def lines(self) -> list[str]:
        """A human summary, a few lines."""
        if self.kind == "video":
            about = "" if self.frame_count_exact else " (estimated from the duration)"
            turn = ""
            if self.orientation != 1:
                turn = f", stored {self.stored_width}x{self.stored_height} ({ORIENTATION_NAMES[self.orientation]})"
            lines = [f"{self.path}: {self.codec} video, {self.width}x{self.height} upright{turn}, "
                     f"{self.fps:.3f} fps, {self.frame_count} frames{about}, {self.duration:.2f} s"]
        else:
            sizes = ", ".join(f"{w}x{h} ×{n}" for (w, h), n in self.sizes.most_common())
            turned = sum(p.orientation != 1 for p in self.photos)
            count = f"{self.frame_count} photo{'s' if self.frame_count != 1 else ''}"
            lines = [f"{self.path}: {count} ({self.codec}), {sizes}"
                     + (f", {turned} turned upright by EXIF orientation" if turned else "")]
            if self.ignored:
                more = f" and {len(self.ignored) - 5} more" if len(self.ignored) > 5 else ""
                lines.append(f"ignored (not photos): {', '.join(self.ignored[:5])}{more}")
        if self.focal_35mm:
            lines.append(f"focal length {self.focal_35mm:g} mm (35 mm equivalent) = {self.focal_px:.1f} px")
        else:
            lines.append("focal length: not recorded")
        if self.transfer:
            lines.append(f"HDR ({self.transfer}): decoded without tone mapping, colours look flat")
        return lines


@dataclasses.dataclass(frozen=True)
class FrameSelection:
    """Which frames to read: a range (frames ``start ≤ index < end`` and/or seconds
    ``start_time ≤ time < end_time``), then a target rate (``fps``: frames dropped evenly, by their
    times; never duplicated), then every ``stride``-th of what remains."""

    start: int | None = None
    end: int | None = None
    start_time: float | None = None
    end_time: float | None = None
    stride: int = 1
    fps: float | None = None

    def check(self, source=None) -> None:
        for name in ("start", "end"):
            value = getattr(self, name)
            if value is not None and (not isinstance(value, int | np.integer) or value < 0):
                raise InputError(source, name, f"expected a frame number >= 0, got {value!r}")
        for name in ("start_time", "end_time"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value >= 0):
                raise InputError(source, name, f"expected seconds >= 0, got {value!r}")
        if not isinstance(self.stride, int | np.integer) or self.stride < 1:
            raise InputError(source, "stride", f"expected an integer >= 1, got {self.stride!r}")
        if self.fps is not None and not (math.isfinite(self.fps) and self.fps > 0):
            raise InputError(source, "fps", f"expected a rate > 0, got {self.fps!r}")

    @property
    def uses_time(self) -> bool:
        return self.start_time is not None or self.end_time is not None or self.fps is not None

    def _before(self, index: int, time: float | None) -> bool:
        return (self.start is not None and index < self.start) or (
            self.start_time is not None and time is not None and time < self.start_time - 1e-9)

    def _after(self, index: int, time: float | None) -> bool:
        return (self.end is not None and index >= self.end) or (
            self.end_time is not None and time is not None and time >= self.end_time - 1e-9)

    def picker(self):
        """A function ``(index, time) -> "take" | "skip" | "stop"`` for frames in order."""
        state = {"first": None, "slot": -1, "kept": 0}

        def pick(index: int, time: float | None) -> str:
            if self._after(index, time):
                return "stop"
            if self._before(index, time):
                return "skip"
            if self.fps is not None and time is not None:
                if state["first"] is None:
                    state["first"] = time
                slot = math.floor((time - state["first"]) * self.fps + 1e-6)
                if slot <= state["slot"]:
                    return "skip"
                state["slot"] = slot
            state["kept"] += 1
            return "take" if (state["kept"] - 1) % self.stride == 0 else "skip"

        return pick


# -- orientation -------------------------------------------------------------------------------

ORIENTATION_NAMES = {1: "upright", 2: "mirrored", 3: "turned 180°", 4: "flipped vertically",
                     5: "transposed", 6: "turned 90° clockwise to display", 7: "transversed",
                     8: "turned 90° counter-clockwise to display"}


def upright(image: np.ndarray, orientation: int) -> np.ndarray:
    """Apply an EXIF orientation code (1–8) to a stored image ``(H, W, …)``: what a viewer shows."""
    ops = {
        1: lambda a: a,
        2: lambda a: a[:, ::-1],
        3: lambda a: a[::-1, ::-1],
        4: lambda a: a[::-1],
        5: lambda a: a.swapaxes(0, 1),
        6: lambda a: np.rot90(a, -1),
        7: lambda a: np.rot90(a, -1)[::-1],
        8: lambda a: np.rot90(a, 1),
    }
    return np.ascontiguousarray(ops[orientation](image))


def swaps_sides(orientation: int) -> bool:
    return orientation in (5, 6, 7, 8)


def orientation_from_display_matrix(matrix, source=None) -> int:
    """FFmpeg's display matrix (9 int32, 16.16 fixed point) → the EXIF orientation that shows the
    frame as FFmpeg's own player rotates it (``fftools``' autorotate: the same tests, the same
    filters)."""
    m = [float(v) for v in matrix]
    scale = [math.hypot(m[0], m[3]), math.hypot(m[1], m[4])]
    if scale[0] == 0 or scale[1] == 0:
        return 1
    # fftools' theta: the clockwise turn that displays the frame (minus av_display_rotation_get)
    theta = math.degrees(math.atan2(m[1] / scale[1], m[0] / scale[0]))
    theta -= 360.0 * math.floor(theta / 360.0 + 0.9 / 360.0)
    if abs(theta - 90) < 1.0:
        return 5 if m[3] > 0 else 6  # transpose=cclock_flip : clock
    if abs(theta - 180) < 1.0:
        return {(True, True): 3, (True, False): 2, (False, True): 4, (False, False): 1}[(m[0] < 0, m[4] < 0)]
    if abs(theta - 270) < 1.0:
        return 7 if m[3] < 0 else 8  # transpose=clock_flip : cclock
    if abs(theta) < 1.0 or abs(theta - 360) < 1.0:
        return 4 if m[4] < 0 else 1
    raise InputError(source, "display matrix", f"turns the picture by {theta:.1f}°; expected a multiple of 90°")


def orientation_from_rotate_tag(value, source=None) -> int:
    """The older ``rotate`` stream tag (degrees clockwise to display) → an EXIF orientation."""
    try:
        degrees = int(round(float(value))) % 360
    except (TypeError, ValueError):
        raise InputError(source, "rotate", f"expected degrees, got {value!r}") from None
    codes = {0: 1, 90: 6, 180: 3, 270: 8}
    if degrees not in codes:
        raise InputError(source, "rotate", f"turns the picture by {degrees}°; expected a multiple of 90°")
    return codes[degrees]


def focal_in_pixels(focal_35mm: float | None, width: int, height: int) -> float | None:
    """A 35 mm equivalent focal length in pixels of a ``width`` × ``height`` image, by the diagonal
    (:func:`~mogaface.core.camera.focal_from_35mm`); None when there is none."""
    return focal_from_35mm(focal_35mm, width, height) if focal_35mm else None


def output_size(width: int, height: int, longer: int | None) -> tuple[int, int]:
    """``(width, height)`` with the longer side ``longer`` and the aspect kept (None: as it is)."""
    if longer is None:
        return width, height
    scale = longer / max(width, height)
    return (longer, max(1, round(height * scale))) if width >= height else (max(1, round(width * scale)), longer)


def _check_size_option(size, source) -> None:
    if size is not None and not (isinstance(size, int | np.integer) and 16 <= size <= MAX_VIDEO_SIDE):
        raise InputError(source, "size", f"expected the output's longer side in pixels, 16 to {MAX_VIDEO_SIDE}, "
                                         f"got {size!r}")


def _check_threads(threads, source) -> None:
    if threads is not None and not (isinstance(threads, int | np.integer) and 0 <= threads <= 256):
        raise InputError(source, "threads", f"expected 0 (automatic) to 256, got {threads!r}")


# -- videos ------------------------------------------------------------------------------------


_ISO_FIRST_BOXES = (b"ftyp", b"wide", b"free", b"mdat", b"moov", b"skip")


def _iso_boxes(handle, start: int, end: int, limit: int = 4096) -> list[tuple[bytes, int, int]]:
    """``(type, payload start, payload end)`` of the ISO media boxes (MP4, MOV) in ``[start, end)``,
    read from their headers only."""
    boxes, offset = [], start
    while offset + 8 <= end and len(boxes) < limit:
        handle.seek(offset)
        header = handle.read(16)
        if len(header) < 8:
            break
        length, kind = struct.unpack(">I4s", header[:8])
        head = 8
        if length == 1:
            if len(header) < 16:
                break
            length, head = struct.unpack(">Q", header[8:16])[0], 16
        elif length == 0:
            length = end - offset
        if length < head:
            break
        boxes.append((kind, offset + head, min(offset + length, end)))
        offset += length
    return boxes


def _children(handle, box, kind: bytes) -> list[tuple[bytes, int, int]]:
    return [b for b in _iso_boxes(handle, box[1], box[2], limit=1024) if b[0] == kind]


def _top_boxes(path) -> list[tuple[bytes, int, int]] | None:
    """The top-level boxes of an ISO media file, or None if it does not start like one."""
    with open(path, "rb") as handle:
        boxes = _iso_boxes(handle, 0, os.path.getsize(path))
    return boxes if boxes and boxes[0][0] in _ISO_FIRST_BOXES else None


def declared_sizes(path) -> list[tuple[int, int]]:
    """The frame sizes the video tracks of an MP4/MOV declare in their sample descriptions (``stsd``),
    read from the file's boxes before FFmpeg opens it (its probe decodes a few H.264 frames); empty
    for other containers."""
    try:
        top = _top_boxes(path)
        if not top:
            return []
        sizes = []
        with open(path, "rb") as handle:
            for moov in (b for b in top if b[0] == b"moov"):
                for trak in _children(handle, moov, b"trak"):
                    for mdia in _children(handle, trak, b"mdia"):
                        handlers = _children(handle, mdia, b"hdlr")
                        if not handlers:
                            continue
                        handle.seek(handlers[0][1] + 8)  # version and flags, pre_defined, then the handler type
                        if handle.read(4) != b"vide":
                            continue
                        for minf in _children(handle, mdia, b"minf"):
                            for stbl in _children(handle, minf, b"stbl"):
                                for stsd in _children(handle, stbl, b"stsd"):
                                    # a full box (4 bytes) and an entry count (4), then the entries:
                                    # each a visual sample entry with width and height at byte 24
                                    for entry in _iso_boxes(handle, stsd[1] + 8, stsd[2], limit=64):
                                        handle.seek(entry[1] + 24)
                                        data = handle.read(4)
                                        if len(data) == 4:
                                            sizes.append(struct.unpack(">HH", data))
        return sizes
    except (OSError, struct.error):
        return []


def _not_a_video(path, error) -> InputError:
    try:
        top = _top_boxes(path)
    except (OSError, struct.error):
        top = None
    if top and b"moov" not in {b[0] for b in top}:
        return InputError(path, "moov", "an MP4/QuickTime file without its index (the 'moov' box): the recording "
                                        "was cut off before it was finished, and no frame can be located without "
                                        "the index")
    detail = f" ({error})" if error is not None else ""
    return InputError(path, None, f"not a video FFmpeg can read{detail}; expected a video file (MP4, MOV, …) "
                                  f"or a folder of photos")


class Video:
    """A video file. ``info`` is read when it is opened; ``frames()`` decodes."""

    kind = "video"

    def __init__(self, path: str | os.PathLike):
        self.path = pathlib.Path(path)
        self.damage: str | None = None  # what stopped the last ``frames()`` early, if anything
        self.info = self._probe()

    def _open(self):
        import av

        check_regular_file(self.path)
        for width, height in declared_sizes(self.path):  # before FFmpeg's probe decodes anything
            check_video_size(self.path, width, height)
        try:
            container = av.open(os.fspath(self.path), "r")
        except av.error.EOFError:
            raise InputError(self.path, None, "ends before its first frame (an empty or cut-off recording); expected "
                                              "a video file with frames") from None
        except av.error.FFmpegError as error:
            raise _not_a_video(self.path, getattr(error, "strerror", None) or error) from None
        except (OSError, ValueError) as error:
            raise InputError(self.path, None, f"cannot be read ({error})") from None
        try:
            if container.format.name.endswith("_pipe") or container.format.name in ("image2", "gif"):
                raise InputError(self.path, None, f"is an image ({container.format.name.removesuffix('_pipe')}), not "
                                                  f"a video: give photos as a folder (or as files) of photos")
            if not container.streams.video:
                raise InputError(self.path, "streams", "holds no video stream (a recording with zero frames, or "
                                                       "audio only)")
            stream = container.streams.best("video")
            width, height = int(stream.codec_context.width), int(stream.codec_context.height)
            check_video_size(self.path, width, height)
            # frame (or frame and slice) threading: H.264 marks concealed frames corrupt there, and not
            # under slice threading alone, PyAV's default
            stream.codec_context.thread_type = "AUTO"
        except BaseException:
            container.close()
            raise
        return container, stream

    def _probe(self) -> FootageInfo:
        container, stream = self._open()
        try:
            ctx = stream.codec_context
            width, height = int(ctx.width), int(ctx.height)
            first = next(self._decoded(container, stream, probing=True), None)
            if first is None:
                raise InputError(self.path, None, f"no frame could be decoded ({self.damage or 'the video is empty'})")
            orientation = self._orientation(first, stream)
            rate = stream.average_rate or stream.guessed_rate or stream.base_rate
            fps = float(rate) if rate else None
            if not fps or not math.isfinite(fps) or fps <= 0:
                raise InputError(self.path, "frame rate", f"expected a frame rate > 0, got {rate!r}")
            duration = None
            if stream.duration is not None and stream.time_base:
                duration = float(stream.duration * stream.time_base)
            elif container.duration is not None:
                duration = container.duration / 1_000_000
            declared = int(stream.frames or 0)
            exact = declared > 0
            if duration is None:
                duration = declared / fps if exact else 0.0
            count = declared if exact else max(1, round(duration * fps))
            up_w, up_h = (height, width) if swaps_sides(orientation) else (width, height)
            transfer = HDR_TRANSFERS.get(int(first.color_trc or 0)) if hasattr(first, "color_trc") else None
            return FootageInfo(
                path=self.path, kind="video", frame_count=count, frame_count_exact=exact, fps=fps, width=up_w,
                height=up_h, codec=ctx.name, duration=duration, orientation=orientation, stored_width=width,
                stored_height=height, focal_35mm=_video_focal(container, stream, self.path), transfer=transfer,
            )
        finally:
            container.close()
            self.damage = None

    def _orientation(self, frame, stream) -> int:
        from av.sidedata.sidedata import Type

        try:
            side = frame.side_data.get(Type.DISPLAYMATRIX)
        except Exception:  # older side-data containers; the rotation alone is still read below
            side = None
        if side is not None:
            matrix = struct.unpack("<9i", bytes(side)[:36])
            return orientation_from_display_matrix(matrix, self.path)
        if frame.rotation:
            return orientation_from_display_matrix(_rotation_matrix(frame.rotation), self.path)
        tag = stream.metadata.get("rotate")
        return orientation_from_rotate_tag(tag, self.path) if tag is not None else 1

    def _decoded(self, container, stream, probing: bool = False):
        """Decoded frames in presentation order, stopping at the first damage (said in ``damage``)."""
        import av

        self.damage = None
        try:
            for packet in container.demux(stream):
                if packet.is_corrupt:
                    self.damage = f"the packet at {_seconds(packet, stream)} is incomplete or corrupt"
                    break
                try:
                    frames = stream.decode(packet)
                except av.error.FFmpegError as error:
                    self.damage = f"the packet at {_seconds(packet, stream)} does not decode ({error})"
                    break
                for frame in frames:
                    if frame.is_corrupt:
                        self.damage = f"the frame at {_seconds(frame, stream)} decodes with errors"
                        return
                    yield frame
                    if probing:
                        return
        except av.error.FFmpegError as error:
            self.damage = f"the file cannot be read on ({error})"
        if self.damage is None:
            return
        try:  # frames the decoder holds back (reordering, threads) came from intact packets
            for frame in stream.decode(None):
                if frame.is_corrupt:
                    return
                yield frame
                if probing:
                    return
        except av.error.FFmpegError:
            return

    def frames(self, selection: FrameSelection = FrameSelection(), size: int | None = None,
               threads: int | None = None) -> Iterator[Frame]:
        """Decode the selected frames, upright, as RGB ``uint8``; the longer side ``size`` if given.

        ``threads``: the decoder's threads (None or 0: FFmpeg's choice). A damaged file stops at the
        damage with a :class:`FootageWarning` (also in ``self.damage``).
        """
        selection.check(self.path)
        _check_size_option(size, self.path)
        _check_threads(threads, self.path)
        info = self.info
        out_w, out_h = output_size(info.width, info.height, size)
        stored_w, stored_h = (out_h, out_w) if swaps_sides(info.orientation) else (out_w, out_h)
        container, stream = self._open()
        try:
            stream.codec_context.thread_count = int(threads or 0)
            pick = selection.picker()
            origin = None
            index = -1
            for frame in self._decoded(container, stream):
                index += 1  # frames decoded so far, less one
                if frame.pts is not None and frame.time is not None:
                    if origin is None:
                        origin = frame.time
                    time = float(frame.time - origin)
                else:
                    time = index / info.fps
                choice = pick(index, time)
                if choice == "stop":
                    break
                if choice == "skip":
                    continue
                shrink = stored_w * stored_h < frame.width * frame.height
                rgb = frame.reformat(width=stored_w, height=stored_h, format="rgb24",
                                     interpolation="AREA" if shrink else None).to_ndarray()
                yield Frame(index, time, upright(rgb, info.orientation))
            if self.damage is not None:
                self.damage = f"damaged ({self.damage}): read the first {index + 1} frames"
                warnings.warn(FootageWarning(f"{self.path}: {self.damage}"), stacklevel=2)
        finally:
            container.close()


def _seconds(item, stream) -> str:
    """When a packet or frame is shown, for messages."""
    if item.pts is None or stream.time_base is None:
        return "an unknown time"
    return f"{float((item.pts - (stream.start_time or 0)) * stream.time_base):.3f} s"


def _rotation_matrix(ccw_degrees: float) -> list[int]:
    """The display matrix of a pure rotation (FFmpeg's av_display_rotation_set of -ccw)."""
    radians = math.radians(ccw_degrees)
    c, s = math.cos(radians), math.sin(radians)
    one = 1 << 16
    return [round(c * one), round(-s * one), 0, round(s * one), round(c * one), 0, 0, 0, 1 << 30]


def check_video_size(path, width: int, height: int) -> None:
    """Refuse a video whose stream declares frames above the limits (8K), before decoding."""
    if not (0 < width <= MAX_VIDEO_SIDE and 0 < height <= MAX_VIDEO_SIDE and width * height <= MAX_VIDEO_PIXELS):
        raise InputError(path, "frame size", f"declares {width}x{height} frames; the limit is {MAX_VIDEO_SIDE} a "
                                             f"side and {MAX_VIDEO_PIXELS} pixels (8K)")


def _video_focal(container, stream, path) -> float | None:
    tags = {**dict(container.metadata), **dict(stream.metadata)}
    for key, value in tags.items():
        lowered = key.lower()
        if key == APPLE_FOCAL_35MM or ("focal" in lowered and "35" in lowered):
            try:
                focal = float(str(value).strip())
            except ValueError:
                continue
            if 1.0 <= focal <= 2000.0:
                return focal
    return None


# -- photos ------------------------------------------------------------------------------------


def _natural_key(name: str):
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", name)]


def check_photo_size(path, width: int, height: int) -> None:
    if not (0 < width <= MAX_IMAGE_SIDE and 0 < height <= MAX_IMAGE_SIDE and width * height <= MAX_IMAGE_PIXELS):
        raise InputError(path, "size", f"declares {width}x{height} pixels; the limit is {MAX_IMAGE_SIDE} a side and "
                                       f"{MAX_IMAGE_PIXELS} in all")


def _photo_header(path: pathlib.Path) -> PhotoInfo:
    from PIL import Image

    check_regular_file(path)
    try:
        with Image.open(path) as image:
            width, height = image.size
            check_photo_size(path, width, height)
            exif = image.getexif()
            orientation = int(exif.get(EXIF_ORIENTATION, 1) or 1)
            focal = exif.get_ifd(EXIF_IFD).get(EXIF_FOCAL_35MM)
            kind = image.format or "?"
    except InputError:
        raise
    except Exception as error:  # pillow raises many types for what is not an image
        raise InputError(path, None, f"not a photo that can be read ({error}); expected a JPEG or PNG") from None
    if kind not in ("JPEG", "PNG", "MPO"):
        raise InputError(path, None, f"is a {kind} image; expected a JPEG or PNG photo")
    if orientation not in ORIENTATION_NAMES:
        raise InputError(path, "Orientation", f"expected an EXIF orientation 1 to 8, got {orientation}")
    try:
        focal = float(focal) if focal else None
    except (TypeError, ValueError):
        focal = None
    if swaps_sides(orientation):
        width, height = height, width
    return PhotoInfo(path.name, width, height, orientation, focal, "JPEG" if kind == "MPO" else kind)


class Photos:
    """Photos (JPEG, PNG): a folder's, in natural name order, or a list of files."""

    kind = "photos"

    def __init__(self, source: str | os.PathLike | list):
        if isinstance(source, list | tuple):
            paths = [pathlib.Path(p) for p in source]
            if not paths:
                raise InputError(None, None, "no photos given")
            self.path = paths[0] if len(paths) == 1 else paths[0].parent
            ignored = []
        else:
            self.path = pathlib.Path(source)
            paths, ignored = self._listing(self.path)
        self.paths = paths
        headers = tuple(_photo_header(p) for p in paths)
        formats = sorted({h.format.lower() for h in headers})
        focals = {h.focal_35mm for h in headers}
        first = headers[0]
        self.info = FootageInfo(
            path=self.path, kind="photos", frame_count=len(headers), frame_count_exact=True, fps=None,
            width=first.width, height=first.height, codec="+".join(formats), duration=None,
            focal_35mm=focals.pop() if len(focals) == 1 else None, photos=headers, ignored=tuple(ignored),
        )

    @staticmethod
    def _listing(folder: pathlib.Path) -> tuple[list[pathlib.Path], list[str]]:
        if not folder.is_dir():
            raise InputError(folder, None, "expected a video file or a folder of photos")
        photos, ignored = [], []
        try:
            entries = sorted(os.scandir(folder), key=lambda e: _natural_key(e.name))
        except OSError as error:
            raise InputError(folder, None, f"cannot be listed ({error.strerror})") from None
        for entry in entries:
            if entry.name.startswith("."):  # hidden files, and macOS's ._NAME companions
                continue
            suffix = pathlib.Path(entry.name).suffix.lower()
            if suffix in UNSUPPORTED_PHOTO_SUFFIXES:
                raise InputError(entry.path, None, f"{UNSUPPORTED_PHOTO_SUFFIXES[suffix]} photos cannot be read; "
                                                   f"expected JPEG or PNG (export them as JPEG; on an iPhone, "
                                                   f"Settings > Camera > Formats > Most Compatible)")
            if suffix in PHOTO_SUFFIXES and not entry.is_dir():
                photos.append(pathlib.Path(entry.path))
            else:
                ignored.append(entry.name)
        if not photos:
            raise InputError(folder, None, f"holds no photos; expected JPEG or PNG files "
                                           f"({', '.join(PHOTO_SUFFIXES)})")
        return photos, ignored

    def frames(self, selection: FrameSelection = FrameSelection(), size: int | None = None,
               threads: int | None = None) -> Iterator[Frame]:
        """Decode the selected photos, upright, as RGB ``uint8``; the longer side ``size`` if given.
        Photos have no time: a selection in seconds or by rate is refused. ``threads`` is unused."""
        selection.check(self.path)
        _check_size_option(size, self.path)
        _check_threads(threads, self.path)
        if selection.uses_time:
            raise InputError(self.path, "fps" if selection.fps is not None else "start_time",
                             "photos have no time: select them by frame number (start, end, stride)")
        pick = selection.picker()
        for index, (path, header) in enumerate(zip(self.paths, self.info.photos)):
            choice = pick(index, None)
            if choice == "stop":
                break
            if choice == "take":
                yield Frame(index, None, read_photo(path, header, size))


def read_photo(path, header: PhotoInfo, size: int | None = None) -> np.ndarray:
    """One photo as upright RGB ``uint8``, the longer side ``size`` if given (JPEGs are decoded at a
    reduced scale first where that is enough: pillow's draft mode)."""
    from PIL import Image

    out_w, out_h = output_size(header.width, header.height, size)
    stored = (out_h, out_w) if swaps_sides(header.orientation) else (out_w, out_h)
    try:
        with Image.open(path) as image:
            if size is not None and image.format == "JPEG":
                image.draft("RGB", stored)
            image.load()
            if image.mode in ("I;16", "I;16B", "I;16L", "I"):
                array = np.asarray(image).astype(np.float64)
                scale = 65535.0 if array.max(initial=0) > 255 else 255.0
                image = Image.fromarray((np.clip(array / scale, 0, 1) * 255 + 0.5).astype(np.uint8), "L")
            image = image.convert("RGB")
            if image.size != stored:
                image = image.resize(stored, Image.Resampling.LANCZOS if size is not None else Image.Resampling.BILINEAR,
                                     reducing_gap=3.0)
            array = np.asarray(image)
    except Exception as error:
        raise InputError(path, None, f"the photo cannot be decoded ({error})") from None
    return upright(array, header.orientation)


# -- opening -----------------------------------------------------------------------------------


def open_footage(source: str | os.PathLike | list) -> Video | Photos:
    """A video file, a folder of photos, or a list of photo files (one photo file alone is a list
    of one); its ``info`` says what it holds, ``frames()`` reads it."""
    if isinstance(source, list | tuple):
        if len(source) == 1:
            return open_footage(source[0])
        return Photos(list(source))
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
