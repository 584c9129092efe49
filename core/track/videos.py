"""Video files (a phone's MP4 or MOV, or anything FFmpeg reads): their declared frame sizes read
from the container's boxes before FFmpeg opens them, then the frames decoded upright, with the
lens and the display matrix from the metadata (:mod:`.decode` says what a frame and an input are)."""

from __future__ import annotations

import math
import os
import pathlib
import struct
import warnings
from collections.abc import Iterator

from ..errors import InputError
from ..io.files import check_regular_file
from ..io.video import APPLE_FOCAL_35MM
from ..limits import MAX_VIDEO_PIXELS, MAX_VIDEO_SIDE
from .inputs import (
    FootageInfo,
    FootageWarning,
    Frame,
    FrameSelection,
    check_size_option,
    check_threads,
    orientation_from_display_matrix,
    orientation_from_rotate_tag,
    output_size,
    swaps_sides,
    upright,
)

HDR_TRANSFERS = {16: "PQ (SMPTE ST 2084)", 18: "HLG (ARIB STD-B67)"}


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
            return orientation_from_display_matrix(rotation_matrix(frame.rotation), self.path)
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
        check_size_option(size, self.path)
        check_threads(threads, self.path)
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


def rotation_matrix(ccw_degrees: float) -> list[int]:
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
