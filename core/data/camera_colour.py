"""Cameras that disagree in colour, as a real rig's do: white balance, exposure and vignetting.

A synthetic capture draws one :class:`CameraColour` per camera (``CaptureSettings.camera_colour``
scales the spread; 0 keeps every camera exact) and applies it to the foreground of each image the
camera takes, in linear light, before the image is composited over the capture's background: the
background stays the one colour the trainers composite over, as a matted capture's does. The drawn
values go to the ground-truth file beside ``cameras_gt.json``, never into the capture.

The default spread (1.0) is that of an uncalibrated machine-vision rig: exposure within about
±0.15 stops (std 0.08), red and blue gains within about ±6 % of green (std 3 %), and corners 15-35 %
darker than the centre.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..io.image import linear_to_srgb, srgb_to_linear

GT_COLOUR_FILE = "camera_colour_gt.json"
EXPOSURE_STOPS_STD = 0.08
GAIN_STD = 0.03
VIGNETTE_RANGE = (0.15, 0.35)


@dataclasses.dataclass(frozen=True)
class CameraColour:
    """One camera's colour: ``exposure`` in stops, per-channel ``gains`` (green 1), and ``vignette``,
    the fraction of light lost at the image's corners (falling off with the squared radius)."""

    exposure: float = 0.0
    gains: tuple[float, float, float] = (1.0, 1.0, 1.0)
    vignette: float = 0.0

    def factor(self, width: int, height: int) -> np.ndarray:
        """(H,W,3) linear multiplier of every pixel."""
        y, x = np.mgrid[0:height, 0:width].astype(np.float32)
        r2 = ((x + 0.5 - width / 2) ** 2 + (y + 0.5 - height / 2) ** 2) / ((width / 2) ** 2 + (height / 2) ** 2)
        falloff = 1.0 - self.vignette * r2
        scale = np.float32(2.0 ** self.exposure) * np.asarray(self.gains, np.float32)
        return falloff[..., None] * scale

    def seen(self, linear: np.ndarray) -> np.ndarray:
        """(H,W,3) linear light as this camera records it."""
        return linear * self.factor(linear.shape[1], linear.shape[0])


def foreground(rgb: np.ndarray, alpha: np.ndarray, background) -> np.ndarray:
    """The linear-light foreground of an image composited over ``background`` with coverage ``alpha``."""
    a = np.asarray(alpha, np.float32)[..., None]
    bg = np.asarray(background, np.float32).reshape(1, 1, 3)
    fg = np.where(a > 1e-4, (rgb - (1.0 - a) * bg) / np.maximum(a, 1e-4), 0.0)
    return srgb_to_linear(np.clip(fg, 0.0, 1.0))


def composite(linear: np.ndarray, alpha: np.ndarray, background) -> np.ndarray:
    """A linear-light foreground as sRGB values over ``background`` (coverage ``alpha``)."""
    a = np.asarray(alpha, np.float32)[..., None]
    bg = np.asarray(background, np.float32).reshape(1, 1, 3)
    return (a * linear_to_srgb(linear) + (1.0 - a) * bg).astype(np.float32)


def draw_camera_colours(count: int, spread: float, rng: np.random.Generator) -> list[CameraColour]:
    """``count`` cameras' colours with ``spread`` times the default spread (0: all exact)."""
    if spread == 0:
        return [CameraColour() for _ in range(count)]
    colours = []
    for _ in range(count):
        red, blue = np.exp(rng.normal(scale=GAIN_STD * spread, size=2))
        colours.append(CameraColour(
            exposure=float(rng.normal(scale=EXPOSURE_STOPS_STD * spread)),
            gains=(float(red), 1.0, float(blue)),
            vignette=float(spread * rng.uniform(*VIGNETTE_RANGE)),
        ))
    return colours
