"""What decides synthetic phone footage (:func:`.footage.make_footage`): plain values, no torch, so
``make-footage --help`` shows the defaults without loading the renderer."""

from __future__ import annotations

import dataclasses
import math

from ..errors import InputError

KINDS = ("handheld", "fixed", "photos")


@dataclasses.dataclass(frozen=True)
class FootageSettings:
    """Everything that decides a footage folder and its truth; the same settings give the same files.

    ``kind``: ``handheld`` (a camera orbiting a still head, ±``orbit`` degrees, hand shake, auto
    exposure drifting), ``fixed`` (a still camera, the head turning ±``head_yaw`` degrees and
    nodding), or ``photos`` (``photos`` JPEGs from views around a still head, mixed sizes). The
    subject talks in all three (the photos catch moments of the same script).
    """

    kind: str = "handheld"
    width: int = 720  # upright size: portrait 720x1280, a phone's 720p held upright
    height: int = 1280
    fps: float = 30.0
    seconds: float = 10.0
    rotation_flag: bool = False  # store the frames landscape with a 90° display matrix, as phones do
    photos: int = 8
    subject: int = 0
    seed: int = 0
    supersample: int = 2
    focal_35mm: float = 26.0  # mm, 35 mm equivalent (a phone's main camera)
    lens_metadata: bool = True  # write the focal length into the clip (as iPhones do) and the photos' EXIF
    orbit: float = 40.0  # degrees either side of frontal (handheld, photos)
    head_yaw: float = 35.0  # degrees either side (fixed)
    head_pitch: float = 12.0  # degrees either side (fixed)
    shake: float = 1.0  # scale of the hand shake (handheld; 0: a camera on rails)
    exposure_drift: float = 0.06  # std of the auto exposure's log gain
    sensor_noise: float = 1.5  # std of the sensor noise in 8-bit levels
    crf: int = 18  # x264's constant quality
    novel_views: int = 4  # fixed cameras the footage never saw, for scoring novel views
    novel_every: int = 30  # a novel-view render every this many frames (photos: every photo)
    novel_size: int = 512

    def check(self) -> None:
        if self.kind not in KINDS:
            raise InputError(None, "kind", f"expected one of {', '.join(KINDS)}, got {self.kind!r}")
        integers = {"width": (16, 4096), "height": (16, 4096), "photos": (1, 500), "supersample": (1, 8),
                    "crf": (0, 51), "novel_views": (0, 16), "novel_every": (1, 100000), "novel_size": (16, 4096),
                    "subject": (0, 1_000_000), "seed": (0, 2**63 - 1)}
        for name, (low, high) in integers.items():
            value = getattr(self, name)
            if not (isinstance(value, int) and low <= value <= high):
                raise InputError(None, name, f"expected an integer in [{low}, {high}], got {value!r}")
        for name in ("width", "height"):
            if getattr(self, name) % 2:
                raise InputError(None, name, f"expected an even number of pixels (H.264 4:2:0), got {getattr(self, name)}")
        reals = {"fps": (1.0, 240.0), "seconds": (0.05, 3600.0), "focal_35mm": (8.0, 300.0), "orbit": (0.0, 90.0),
                 "head_yaw": (0.0, 80.0), "head_pitch": (0.0, 45.0), "shake": (0.0, 10.0),
                 "exposure_drift": (0.0, 1.0), "sensor_noise": (0.0, 32.0)}
        for name, (low, high) in reals.items():
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and low <= value <= high):
                raise InputError(None, name, f"expected a number in [{low}, {high}], got {value!r}")
        if self.kind != "photos" and self.frame_count < 1:
            raise InputError(None, "seconds", f"{self.seconds} s at {self.fps} fps is less than one frame")

    @property
    def frame_count(self) -> int:
        """Frames of the clip (photos: the photo count)."""
        if self.kind == "photos":
            return self.photos
        return int(math.floor(self.seconds * self.fps + 1e-6))
