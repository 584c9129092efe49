"""Write a capture dataset in the GaussianAvatars/VHAP layout (see :mod:`.layout`).

Every file is written atomically. The ``transforms_*.json`` files are written last, by
:meth:`CaptureWriter.finish`, so a folder whose writing was interrupted has no split files and
is refused by the reader instead of being read half-complete.
"""

from __future__ import annotations

import os
import pathlib

import numpy as np

from ..camera import Camera
from ..errors import CaptureError
from ..io.atomic import write_json
from ..io.files import check_plain_name
from ..io.image import write_png
from ..io.npz import save_npz
from . import layout
from .camera_file import camera_fields

# Per-frame camera fields that are also written at the top level when all frames agree.
_UNIFORM_FIELDS = ("fl_x", "fl_y", "cx", "cy", "w", "h", "camera_angle_x", "camera_angle_y")


class CaptureWriter:
    """Builds a capture folder frame by frame.

    Usage::

        with CaptureWriter(root) as w:
            w.write_flame_params(t, params)            # once per timestep
            w.add_frame(t, camera, rgb, mask, split="train", sequence="EXP-1")
            w.write_canonical_flame_params(canonical)
        # leaving the block without an error writes the transforms_*.json files

    Camera indices follow the order in which camera ids first appear, unless given.
    """

    def __init__(self, root: str | os.PathLike, *, png_compress_level: int = 4, n_vertices: int | None = None):
        """``n_vertices``: the head model's vertex count; FLAME files then always carry a
        ``static_offset`` (zeros when none is given), which GaussianAvatars' loader requires."""
        self.root = pathlib.Path(root)
        self.n_vertices = n_vertices
        self.root.mkdir(parents=True, exist_ok=True)
        self.png_compress_level = png_compress_level
        self._frames: dict[str, list[dict]] = {split: [] for split in layout.SPLITS}
        self._camera_index: dict[str, int] = {}
        self._flame_written: set[int] = set()
        self._seen: set[tuple[int, str]] = set()

    def camera_index(self, camera_id: str, index: int | None = None) -> int:
        """The index of ``camera_id``, assigned on first use (``index`` pins it)."""
        known = self._camera_index.get(camera_id)
        if known is None:
            check_plain_name(camera_id, self.root, "camera_id", CaptureError)  # the reader refuses others
            known = len(self._camera_index) if index is None else int(index)
            if known in self._camera_index.values():
                raise CaptureError(self.root, "camera_index", f"index {known} already belongs to another camera")
            self._camera_index[camera_id] = known
        elif index is not None and index != known:
            problem = f"camera {camera_id!r} already has index {known}, not {index}"
            raise CaptureError(self.root, "camera_index", problem)
        return known

    def write_flame_params(self, timestep: int, params: dict[str, np.ndarray]) -> str:
        """Write ``flame_param/{t:05d}.npz`` (VHAP form); returns its relative path."""
        rel = layout.flame_param_path(timestep)
        checked = layout.normalize_flame_params(self._with_static_offset(params), self.root / rel)
        save_npz(self.root / rel, layout.batched_flame_params(checked))
        self._flame_written.add(int(timestep))
        return rel

    def write_canonical_flame_params(self, params: dict[str, np.ndarray]) -> None:
        """Write ``canonical_flame_param.npz``."""
        path = self.root / layout.CANONICAL_FILE
        checked = layout.normalize_flame_params(self._with_static_offset(params), path)
        save_npz(path, layout.batched_flame_params(checked))

    def _with_static_offset(self, params: dict) -> dict:
        if self.n_vertices is None or "static_offset" in params:
            return params
        return {**params, "static_offset": np.zeros((self.n_vertices, 3), np.float32)}

    def add_frame(
        self,
        timestep: int,
        camera: Camera,
        rgb: np.ndarray,
        mask: np.ndarray,
        *,
        split: str,
        timestep_id: str | None = None,
        sequence: str | None = None,
        camera_index: int | None = None,
    ) -> dict:
        """Write one view of one timestep (image and mask PNGs) and record its frame entry.

        ``rgb`` (H,W,3) float sRGB in [0,1] or uint8; ``mask`` (H,W) float in [0,1] or uint8;
        both must match ``camera.width/height``. The timestep's FLAME file must be written
        (before or after) with :meth:`write_flame_params`.
        """
        size = (camera.height, camera.width)
        if np.shape(rgb)[:2] != size or np.shape(mask)[:2] != size:
            problem = f"image {np.shape(rgb)} / mask {np.shape(mask)} do not match the camera {size}"
            raise CaptureError(self.root, "rgb/mask", problem)
        frame = self._entry(timestep, camera, split, timestep_id, sequence, camera_index)
        write_png(self.root / frame["file_path"], rgb, compress_level=self.png_compress_level)
        write_png(self.root / frame["fg_mask_path"], mask, compress_level=self.png_compress_level)
        return self._record(frame, split)

    def record_frame(
        self,
        timestep: int,
        camera: Camera,
        *,
        split: str,
        timestep_id: str | None = None,
        sequence: str | None = None,
        camera_index: int | None = None,
    ) -> dict:
        """Record a frame whose PNGs were already written, e.g. by worker processes.

        The files must exist at ``layout.image_path(t, c)`` and ``layout.mask_path(t, c)``,
        with ``c`` the index :meth:`camera_index` gives (pin it with ``camera_index``).
        """
        frame = self._entry(timestep, camera, split, timestep_id, sequence, camera_index)
        for name in ("file_path", "fg_mask_path"):
            if not (self.root / frame[name]).is_file():
                raise CaptureError(self.root / frame[name], name, "file not found; write it before recording the frame")
        return self._record(frame, split)

    def _entry(self, timestep, camera, split, timestep_id, sequence, camera_index) -> dict:
        if split not in self._frames:
            raise CaptureError(self.root, "split", f"unknown split {split!r}; expected one of {layout.SPLITS}")
        timestep = int(timestep)
        if (timestep, camera.camera_id) in self._seen:
            raise CaptureError(self.root, "frames", f"timestep {timestep}, camera {camera.camera_id!r} added twice")
        c = self.camera_index(camera.camera_id, camera_index)
        frame = {
            "timestep_index": timestep,
            "timestep_id": timestep_id if timestep_id is not None else f"{timestep:05d}",
            "camera_index": c,
            "camera_id": camera.camera_id,
            "file_path": layout.image_path(timestep, c),
            "fg_mask_path": layout.mask_path(timestep, c),
            "flame_param_path": layout.flame_param_path(timestep),
        }
        if sequence is not None:
            frame["sequence"] = str(sequence)
        frame.update(camera_fields(camera))
        return frame

    def _record(self, frame: dict, split: str) -> dict:
        self._frames[split].append(frame)
        self._seen.add((frame["timestep_index"], frame["camera_id"]))
        return frame

    def finish(self) -> None:
        """Write ``transforms_{split}.json`` for every split and ``transforms.json``.

        An empty val or test split is written with no frames (as VHAP does): GaussianAvatars
        opens all three files."""
        missing = {f["timestep_index"] for frames in self._frames.values() for f in frames} - self._flame_written
        if missing:
            problem = f"no FLAME parameters written for timesteps {sorted(missing)[:10]}"
            raise CaptureError(self.root, "flame_param", problem)
        if not self._frames["train"]:
            raise CaptureError(self.root, "frames", "no training frames were added")
        everything = []
        for split, frames in self._frames.items():
            write_json(self.root / layout.split_file(split), transforms_document(frames))
            everything.extend(frames)
        everything.sort(key=lambda f: (f["timestep_index"], f["camera_index"]))
        write_json(self.root / layout.ALL_FRAMES_FILE, transforms_document(everything))

    def __enter__(self) -> "CaptureWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.finish()


def transforms_document(frames: list[dict]) -> dict:
    """A ``transforms_*.json`` document: index lists, uniform camera fields, frames."""
    doc: dict = {
        layout.CY_ORIGIN_KEY: "bottom",
        "camera_indices": sorted({f["camera_index"] for f in frames}),
        "timestep_indices": sorted({f["timestep_index"] for f in frames}),
    }
    for field in _UNIFORM_FIELDS:
        values = {f[field] for f in frames}
        if len(values) == 1:
            doc[field] = values.pop()
    sequences = sorted({f["sequence"] for f in frames if "sequence" in f})
    if sequences:
        doc["sequences"] = sequences
    doc["frames"] = frames
    return doc
