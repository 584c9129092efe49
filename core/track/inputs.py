"""What footage is, whatever reads it: a frame, an input's summary (:class:`FootageInfo`), the
frames chosen (:class:`FrameSelection`), orientation codes, sizes. The readers are
:mod:`.videos` and :mod:`.photos`; :mod:`.decode` opens an input with the right one."""

from __future__ import annotations

import collections
import dataclasses
import math
import pathlib
from typing import NamedTuple

import numpy as np

from ..camera import focal_from_35mm
from ..errors import InputError
from ..limits import MAX_VIDEO_SIDE

PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png")
# Photo formats phones write that pillow cannot decode here: refused by name rather than ignored.
UNSUPPORTED_PHOTO_SUFFIXES = {".heic": "HEIC", ".heif": "HEIF", ".dng": "DNG (raw)", ".avif": "AVIF"}


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
    kind: str  # "video", "videos" (several clips, :class:`Clips`) or "photos"
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
    clips: tuple["FootageInfo", ...] = ()  # several videos: each one's (this one's fields: the first's)

    @property
    def focal_px(self) -> float | None:
        return focal_in_pixels(self.focal_35mm, self.width, self.height)

    @property
    def sizes(self) -> collections.Counter:
        """Upright sizes ``(width, height)`` and how many frames have each."""
        if self.kind == "photos":
            return collections.Counter((p.width, p.height) for p in self.photos)
        if self.kind == "videos":
            return sum((clip.sizes for clip in self.clips), collections.Counter())
        return collections.Counter({(self.width, self.height): self.frame_count})

    def lines(self) -> list[str]:
        """A human summary, a few lines."""
        if self.kind == "videos":
            return [f"clip {number} (camera cam{number:02d}): {line}"
                    for number, clip in enumerate(self.clips) for line in clip.lines()]
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


def check_size_option(size, source) -> None:
    if size is not None and not (isinstance(size, int | np.integer) and 16 <= size <= MAX_VIDEO_SIDE):
        raise InputError(source, "size", f"expected the output's longer side in pixels, 16 to {MAX_VIDEO_SIDE}, "
                                         f"got {size!r}")


def check_threads(threads, source) -> None:
    if threads is not None and not (isinstance(threads, int | np.integer) and 0 <= threads <= 256):
        raise InputError(source, "threads", f"expected 0 (automatic) to 256, got {threads!r}")
