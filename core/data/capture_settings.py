"""What decides a synthetic capture (:func:`.generator.make_capture`): plain values, no torch, so the
command line can show the defaults in ``make-capture --help`` without loading the renderer."""

from __future__ import annotations

import dataclasses

from ..errors import InputError
from .sequences import NOISE_GROUPS, GroupNoise, TrackingNoise

RENDERERS = ("mesh", "cycles")


@dataclasses.dataclass(frozen=True)
class CaptureSettings:
    """Everything that decides a synthetic capture; the same settings give the same capture."""

    subject: int = 0
    views: int = 16
    timesteps: int = 150
    size: int = 256  # image width, and height unless ``height`` is given
    # Image height of a non-square capture (NeRSemble's 802×550: size 802, height 550); None: square.
    height: int | None = None
    # The tracker's error per group: std of the drifting part, its correlation length in
    # timesteps, std of the constant per-coefficient bias (docs/data-format.md says why these).
    expr_noise: float = 0.4
    expr_correlation: float = 5.0
    expr_bias: float = 0.3
    pose_noise: float = 0.008  # radians: global, neck, jaw and eye rotations
    pose_correlation: float = 10.0
    pose_bias: float = 0.006
    translation_noise: float = 0.0008  # metres
    translation_correlation: float = 10.0
    translation_bias: float = 0.0006
    camera_noise: float = 0.0  # degrees of rotation error
    # Millimetres of centre error (std per axis); None: 5 mm per degree of camera_noise. A rig's
    # centres are often measured better than its angles.
    camera_centre_noise: float | None = None
    # Unsynchronised cameras: the std, in timesteps, of the moment each camera takes its images,
    # against the moment the tracking (and the held-out frontal camera, the rig's clock) describes.
    camera_delay: float = 0.0
    # The landmark detector's error, pixels at the capture's size: new at every image, and a
    # constant per camera and landmark (a detector errs alike on alike views).
    landmark_noise: float = 0.5
    landmark_bias: float = 0.5
    # Cameras that disagree in colour (white balance, exposure, vignetting): the spread, 1.0 a
    # real uncalibrated rig's (:mod:`.camera_colour`); 0 every camera exact.
    camera_colour: float = 0.0
    seed: int = 0
    # Who renders the images: "mesh", the fast reference rasteriser (diffuse shading of the painted
    # texture), or "cycles", Blender's path tracer with skin, wrinkles, wet eyes and hair
    # (:mod:`.cycles_job`; needs the bpy module).
    renderer: str = "mesh"
    supersample: int = 3  # the mesh renderer's samples per pixel along each axis
    samples: int = 32  # Cycles' samples per pixel (adaptive, denoised)

    def check(self) -> None:
        limits = {"views": (2, 64), "timesteps": (16, 100000), "size": (32, 4096), "supersample": (1, 8),
                  "samples": (1, 4096)}
        for name, (low, high) in limits.items():
            value = getattr(self, name)
            if not low <= value <= high:
                raise InputError(None, name, f"must lie in [{low}, {high}], got {value}")
        if self.height is not None and not 32 <= self.height <= 4096:
            raise InputError(None, "height", f"must lie in [32, 4096], got {self.height}")
        if self.renderer not in RENDERERS:
            raise InputError(None, "renderer", f"must be one of {', '.join(RENDERERS)}, got {self.renderer!r}")
        if not 0 <= self.camera_colour <= 2:
            raise InputError(None, "camera_colour", f"must lie in [0, 2], got {self.camera_colour}")
        for name in ("camera_noise", "camera_centre_noise", "camera_delay", "landmark_noise", "landmark_bias"):
            if getattr(self, name) is not None and not getattr(self, name) >= 0:
                raise InputError(None, name, f"must be >= 0, got {getattr(self, name)}")
        self.tracking_noise().check()

    @property
    def image_height(self) -> int:
        return self.size if self.height is None else self.height

    def tracking_noise(self) -> TrackingNoise:
        """The tracker's error model these settings describe."""
        return TrackingNoise(**{
            group: GroupNoise(getattr(self, f"{group}_noise"), getattr(self, f"{group}_correlation"),
                              getattr(self, f"{group}_bias"))
            for group in NOISE_GROUPS
        })

    @staticmethod
    def iid_noise(**overrides) -> dict:
        """Settings for the older error model: independent per timestep, no bias (the totals kept)."""
        values = {"expr_noise": 0.5, "pose_noise": 0.01, "translation_noise": 0.001}
        values.update({f"{g}_{k}": 0.0 for g in NOISE_GROUPS for k in ("correlation", "bias")})
        values.update(overrides)
        return values
