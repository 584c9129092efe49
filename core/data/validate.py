"""Check a whole capture before training: every referenced file, FLAME array and image size.

Image files are checked by their headers only (no pixel decoding), so a long capture is
checked in seconds. The first problem raises :class:`~mogaface.core.errors.CaptureError`
naming the file and the field.
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np

from ..errors import CaptureError, InputError
from ..io.files import check_regular_file
from ..io.image import image_size, read_image
from . import layout
from .capture import DEFAULT_CACHE_BYTES, Capture
from .landmarks import capture_landmarks


@dataclasses.dataclass
class CaptureSummary:
    """What a checked capture holds."""

    root: str
    views: int
    camera_ids: list[str]
    timesteps: int
    sequences: dict[str, int]  # name -> number of timesteps
    resolutions: list[tuple[int, int]]  # distinct (width, height)
    splits: dict[str, dict[str, int]]  # split -> frames, views, timesteps
    flame_sizes: dict[str, tuple[int, ...]]  # parameter -> per-timestep shape
    has_canonical: bool
    memory_bound_bytes: int
    empty_splits: dict[str, str] = dataclasses.field(default_factory=dict)  # split -> why it has no frames
    landmark_cameras: list[str] = dataclasses.field(default_factory=list)  # cameras with a landmark file

    def lines(self) -> list[str]:
        res = ", ".join(f"{w}x{h}" for w, h in self.resolutions)
        seqs = ", ".join(f"{name} ({n} timesteps)" for name, n in self.sequences.items()) or "none named"
        out = [
            f"capture: {self.root}",
            f"views: {self.views} ({', '.join(self.camera_ids)})",
            f"timesteps: {self.timesteps}",
            f"sequences: {seqs}",
            f"resolution: {res}",
        ]
        for split, counts in self.splits.items():
            out.append(
                f"split {split}: {counts['frames']} frames, {counts['views']} views, {counts['timesteps']} timesteps"
            )
        for split, reason in self.empty_splits.items():
            out.append(f"split {split}: empty ({reason})")
        sizes = ", ".join(f"{k} {v}" for k, v in self.flame_sizes.items())
        out.append(f"flame params: {sizes}; canonical: {'yes' if self.has_canonical else 'no'}")
        out.append(f"landmarks: {len(self.landmark_cameras)} of {self.views} cameras" if self.landmark_cameras
                   else "landmarks: none (solve-cameras needs landmark2d/, docs/data-format.md)")
        out.append(f"image cache bound: {self.memory_bound_bytes / 2**20:.0f} MiB")
        return out


def validate_capture(
    capture: Capture | str | os.PathLike, *, cache_bytes: int = DEFAULT_CACHE_BYTES, full: bool = False
) -> CaptureSummary:
    """Run every check on a capture (a path or an opened :class:`Capture`) and summarise it.

    ``full`` also decodes every image and mask (truncated or corrupt files, non-finite EXR
    values), which takes about as long as reading the capture once.
    """
    if not isinstance(capture, Capture):
        capture = Capture.open(capture, cache_bytes=cache_bytes)
    _check_images(capture)
    if full:
        _decode_images(capture)
    sizes = _check_flame_files(capture)
    canonical = capture.canonical_flame_params()
    if canonical is not None:
        _check_same_sizes(capture.root / layout.CANONICAL_FILE, canonical, sizes, canonical_file=True)
    splits = {
        name: {
            "frames": len(frames),
            "views": len({f.camera_id for f in frames}),
            "timesteps": len({f.timestep_index for f in frames}),
        }
        for name, frames in capture.splits.items()
    }
    return CaptureSummary(
        root=str(capture.root),
        views=len(capture.cameras),
        camera_ids=list(capture.cameras),
        timesteps=len(capture.timesteps),
        sequences={name: len(ts) for name, ts in capture.sequences.items()},
        resolutions=sorted({(c.width, c.height) for c in capture.cameras.values()}),
        splits=splits,
        flame_sizes=sizes,
        has_canonical=canonical is not None,
        memory_bound_bytes=capture.memory_bound_bytes,
        empty_splits=dict(capture.empty_splits),
        landmark_cameras=sorted(capture_landmarks(capture, capture.cameras)),
    )


def _named_images(capture: Capture):
    """``(frame, path, where)`` of every image and mask the capture names, each file once."""
    checked: set[str] = set()
    for frame in capture.frames():
        for name in ("file_path", "fg_mask_path"):
            rel = getattr(frame, name)
            if rel is None or rel in checked:
                continue
            checked.add(rel)
            yield frame, capture.path(frame, name), f"{frame.source} {frame.field(name)}"


def _check_images(capture: Capture) -> None:
    for frame, path, where in _named_images(capture):
        camera = capture.camera(frame)
        try:
            size = image_size(path)
        except InputError as error:
            raise CaptureError(path, where, error.problem) from None
        if size != (camera.width, camera.height):
            raise CaptureError(
                path, f"{frame.source} {frame.field('w/h')}",
                f"image is {size[0]}x{size[1]}, the frame says {camera.width}x{camera.height}",
            )


def _decode_images(capture: Capture) -> None:
    """Decode every image and mask once (nothing kept): the errors training would meet later."""
    for _frame, path, where in _named_images(capture):
        try:
            pixels = read_image(path)
        except InputError as error:
            raise CaptureError(path, where, error.problem) from None
        if not np.isfinite(pixels).all():
            raise CaptureError(path, where, "holds NaN or infinite pixel values")


def _check_flame_files(capture: Capture) -> dict[str, tuple[int, ...]]:
    first_frame = {}
    for frame in capture.frames():
        first_frame.setdefault(frame.timestep_index, frame)
    sizes: dict[str, tuple[int, ...]] = {}
    first = None
    for t in capture.timesteps:
        frame = first_frame[t]
        path = capture.path(frame, "flame_param_path")
        try:
            check_regular_file(path)
        except InputError as error:
            raise CaptureError(path, f"{frame.source} {frame.field('flame_param_path')}", error.problem) from None
        params = capture.flame_params(t)
        if first is None:
            first = path
            sizes = {k: v.shape for k, v in params.items()}
        else:
            _check_same_sizes(path, params, sizes, first=first)
    return sizes


def _check_same_sizes(path, params, sizes, *, first=None, canonical_file=False) -> None:
    for key, shape in sizes.items():
        if key not in params:
            if key == "static_offset":
                continue
            raise CaptureError(path, key, "missing FLAME parameter")
        if params[key].shape != shape:
            other = "the timesteps" if canonical_file else str(first)
            raise CaptureError(path, key, f"shape {params[key].shape} differs from {shape} in {other}")
