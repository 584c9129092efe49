"""Writing a video as a phone does: H.264 in an MP4, BT.709 colours, atomically.

A phone stores BT.709 YUV 4:2:0 at limited range, one key frame a second or so, and, when held
upright, often stores the frames landscape with a display matrix that turns them 90° clockwise
(the ``rotate=90`` tag of older tools); ``rotation_flag=True`` writes that form. The file appears
at its path complete or not at all (``core/io/atomic.py``). Frames are read back by
``core/track/decode.py``.
"""

from __future__ import annotations

import fractions
import os
import pathlib

import numpy as np

from ..errors import InputError
from .atomic import atomic_path

# Apple's key for a video's lens (an mdta tag; FFmpeg reads it into the container's tags).
APPLE_FOCAL_35MM = "com.apple.quicktime.camera.focal_length.35mm_equivalent"
# The display matrix of a phone held upright with a landscape sensor: turn 90° clockwise to show
# (PyAV's rotation is counter-clockwise).
PHONE_PORTRAIT_ROTATION = -90


class VideoWriter:
    """``with VideoWriter(path, width, height, fps) as video: video.write(rgb)`` for every frame.

    ``width``/``height`` are the upright size; ``rgb`` is ``uint8 (height, width, 3)``. ``crf``:
    x264's constant quality (18: visually lossless, what phones' bit rates give). ``metadata``:
    container tags (written as QuickTime ``mdta`` keys, as iPhones write their lens).
    ``index_first``: the index (``moov``) before the frames, as streaming files have it; by default
    it follows them, as a recording writes it when it stops.
    """

    def __init__(self, path: str | os.PathLike, width: int, height: int, fps: float, *, crf: int = 18,
                 rotation_flag: bool = False, metadata: dict[str, str] | None = None, codec: str = "libx264",
                 key_frame_seconds: float = 1.0, index_first: bool = False):
        self.path = pathlib.Path(path)
        if self.path.suffix.lower() not in (".mp4", ".mov"):
            raise InputError(self.path, None, "expected a .mp4 or .mov file name for the video")
        for name, value in (("width", width), ("height", height)):
            if not (isinstance(value, int | np.integer) and 16 <= value <= 8192 and value % 2 == 0):
                raise InputError(self.path, name, f"expected an even number of pixels, 16 to 8192, got {value!r}")
        if not (0 < fps <= 240):
            raise InputError(self.path, "fps", f"expected a frame rate in (0, 240], got {fps!r}")
        self.width, self.height = int(width), int(height)
        self.rate = fractions.Fraction(fps).limit_denominator(1001)
        self.crf, self.rotation_flag, self.codec = int(crf), bool(rotation_flag), codec
        self.metadata = dict(metadata or {})
        self.index_first = bool(index_first)
        self.gop = max(1, round(float(self.rate) * key_frame_seconds))
        self.frames = 0
        self._atomic = None
        self._container = None
        self._stream = None

    def __enter__(self) -> "VideoWriter":
        import av

        self._atomic = atomic_path(self.path)
        tmp = self._atomic.__enter__()
        try:
            flags = [name for name, wanted in (("use_metadata_tags", self.metadata), ("faststart", self.index_first))
                     if wanted]
            options = {"movflags": "+".join(flags)} if flags else {}
            self._container = av.open(os.fspath(tmp), "w", format="mp4" if self.path.suffix.lower() == ".mp4" else "mov",
                                      options=options)
            self._container.metadata.update(self.metadata)
            codec_options = {"crf": str(self.crf)}
            if self.codec == "libx264":
                codec_options["preset"] = "veryfast"  # 3x medium's speed; at crf 18 ~10 Mbit/s at 720p, a phone's rate
                # x264's macroblock-tree rate control gives different bytes from run to run on the same
                # frames here (1 to 5 variants in 10 runs); without it the same frames give the same file
                codec_options["x264-params"] = "mbtree=0"
            stream = self._container.add_stream(self.codec, rate=self.rate, options=codec_options)
            stored = (self.height, self.width) if self.rotation_flag else (self.width, self.height)
            stream.width, stream.height = stored
            stream.pix_fmt = "yuv420p"
            stream.gop_size = self.gop
            ctx = stream.codec_context
            ctx.colorspace = ctx.color_primaries = ctx.color_trc = 1  # BT.709
            ctx.color_range = 1  # limited ("MPEG") range
            if self.rotation_flag:
                stream.set_display_rotation(PHONE_PORTRAIT_ROTATION)
            self._stream = stream
        except BaseException as error:
            self._abort(error)
            raise
        return self

    def write(self, rgb: np.ndarray) -> None:
        """Encode one upright frame, ``uint8 (height, width, 3)``."""
        import av

        rgb = np.asarray(rgb)
        if rgb.shape != (self.height, self.width, 3) or rgb.dtype != np.uint8:
            raise InputError(self.path, "frame", f"expected uint8 ({self.height}, {self.width}, 3), got "
                                                 f"{rgb.dtype} {rgb.shape}")
        stored = np.ascontiguousarray(np.rot90(rgb, 1) if self.rotation_flag else rgb)
        frame = av.VideoFrame.from_ndarray(stored, format="rgb24")
        frame = frame.reformat(format="yuv420p", dst_colorspace="ITU709", dst_color_range=1)
        frame.pts = self.frames
        frame.time_base = 1 / self.rate
        for packet in self._stream.encode(frame):
            self._container.mux(packet)
        self.frames += 1

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self._abort(exc)
            return
        try:
            if self.frames == 0:
                raise InputError(self.path, "frames", "no frames were written")
            for packet in self._stream.encode(None):
                self._container.mux(packet)
            self._container.close()
            self._container = None
        except BaseException as error:
            self._abort(error)
            raise
        self._atomic.__exit__(None, None, None)

    def _abort(self, error) -> None:
        if self._container is not None:
            try:
                self._container.close()
            except Exception:  # the temporary file is removed below either way
                pass
            self._container = None
        self._atomic.__exit__(type(error), error, error.__traceback__)
