"""Read a capture dataset in the GaussianAvatars/VHAP layout (see :mod:`.layout`).

:meth:`Capture.open` parses the split files and checks their structure (keys, types, paths
that stay inside the folder, one set of intrinsics and one pose per camera id); it does not
touch images or FLAME files. :func:`~mogaface.core.data.validate.validate_capture` checks
those. Images load lazily through a least-recently-used cache with a byte bound, so a capture
of any length never has to fit in memory.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
import zipfile

import numpy as np

from ..camera import Camera
from ..errors import CaptureError, InputError
from ..io.files import check_plain_name
from ..io.image import read_image
from ..io.jsonfile import read_json_object
from ..io.npz import load_npz
from ..limits import MAX_PARAM_FILE_BYTES
from . import layout
from .byte_cache import ByteLRU
from .capture_entries import camera_of, check_frame_paths, empty_split_reason, int_field, union_path
from .paths import check_stays_inside

DEFAULT_CACHE_BYTES = 512 * 1024 * 1024


@dataclasses.dataclass(frozen=True, slots=True)
class Frame:
    """One image of the capture: one camera at one timestep, as listed in a split file."""

    split: str
    position: int  # index in the split file's "frames" list (for error messages)
    timestep_index: int
    timestep_id: str
    camera_index: int
    camera_id: str
    file_path: str
    fg_mask_path: str | None
    flame_param_path: str
    sequence: str | None
    # This frame's own camera: one id may have a different pose per sequence (union datasets).
    camera: Camera | None = dataclasses.field(default=None, compare=False, repr=False)

    @property
    def source(self) -> str:
        """The split file that lists this frame."""
        return layout.split_file(self.split)

    def field(self, name: str) -> str:
        return f"frames[{self.position}].{name}"


def _load_json(path: pathlib.Path) -> dict:
    return read_json_object(path, CaptureError)


class Capture:
    """An opened capture folder: splits, frames, cameras, timesteps, sequences, lazy images.

    Attributes:
        root: the dataset folder.
        splits: split name -> list of :class:`Frame` (only split files that exist).
        cameras: camera id -> :class:`~mogaface.core.camera.Camera` (its first pose), by camera index;
            :meth:`camera` gives a frame's own pose.
        timesteps: sorted timestep indices over all splits.
        timestep_ids: timestep index -> id string.
        sequences: sequence name -> sorted timestep indices (empty when frames name none).
        empty_splits: split name -> why its file lists no frames (e.g. VHAP's monocular val).
        memory_bound_bytes: the most bytes the image cache ever holds.
    """

    def __init__(self, root, splits: dict[str, list[Frame]], cameras: dict[str, Camera], cache_bytes: int):
        self.root = pathlib.Path(root)
        self.splits = splits
        self.cameras = cameras
        frames = self.frames()
        self.timestep_ids = dict(sorted({f.timestep_index: f.timestep_id for f in frames}.items()))
        self.timesteps = list(self.timestep_ids)
        seq: dict[str, set[int]] = {}
        for f in frames:
            if f.sequence is not None:
                seq.setdefault(f.sequence, set()).add(f.timestep_index)
        self.sequences = {name: sorted(ts) for name, ts in sorted(seq.items())}
        self._timestep_frame: dict[int, Frame] = {}
        for f in frames:
            self._timestep_frame.setdefault(f.timestep_index, f)
        self._images = ByteLRU(cache_bytes)
        self.empty_splits: dict[str, str] = {}
        self._at: dict[tuple[str, int], Frame] | None = None
        self.declared_cy_origin = "bottom"  # how the train split's cy is read (see layout.cy_origin)

    # -- opening -------------------------------------------------------------------------------
    @classmethod
    def open(cls, root: str | os.PathLike, *, cache_bytes: int = DEFAULT_CACHE_BYTES) -> "Capture":
        """Parse the split files of ``root`` (``transforms_train.json`` required; val/test optional).

        Raises :class:`~mogaface.core.errors.CaptureError` naming the file and field of the
        first problem found.
        """
        root = pathlib.Path(root)
        if not root.is_dir():
            raise CaptureError(root, None, "not a folder")
        if not (root / layout.split_file("train")).exists():
            train = root / layout.split_file("train")
            raise CaptureError(train, None, "file not found (every capture needs a train split)")
        splits: dict[str, list[Frame]] = {}
        cameras: dict[str, tuple[int, Camera]] = {}
        per_timestep: dict[int, tuple] = {}
        empty: dict[str, str] = {}
        origins: dict[str, str] = {}
        for split in layout.SPLITS:
            source = root / layout.split_file(split)
            if split != "train" and not source.exists():
                continue
            frames = cls._parse_split(root, split, source, cameras, per_timestep, empty, origins)
            if frames is not None:
                splits[split] = frames
        ordered = dict(sorted(((cid, cam) for cid, (_, cam) in cameras.items()), key=lambda kv: cameras[kv[0]][0]))
        capture = cls(root, splits, ordered, cache_bytes)
        capture.empty_splits = empty
        capture.declared_cy_origin = origins["train"]
        return capture

    @staticmethod
    def _parse_split(root, split, source, cameras, per_timestep, empty, origins) -> list[Frame] | None:
        doc = _load_json(source)
        origins[split] = layout.cy_origin(doc, source)
        entries = doc.get("frames")
        if entries is None:
            raise CaptureError(source, "frames", "missing key")
        if not isinstance(entries, list):
            raise CaptureError(source, "frames", f"expected a list, got {type(entries).__name__}")
        if not entries:
            if split == "train":
                raise CaptureError(source, "frames", "the train split is empty")
            empty[split] = empty_split_reason(split, doc)
            return None
        frames = []
        seen: set[tuple[int, int]] = set()
        parsed: dict[tuple, Camera] = {}
        for pos, entry in enumerate(entries):
            where = f"frames[{pos}]"
            if not isinstance(entry, dict):
                raise CaptureError(source, where, "expected a JSON object")
            t = int_field(entry, "timestep_index", source, where)
            c = int_field(entry, "camera_index", source, where)
            camera_id = check_plain_name(str(entry.get("camera_id", c)), source, f"{where}.camera_id", CaptureError)
            timestep_id = str(entry.get("timestep_id", f"{t:05d}"))
            union = union_path(entry.get("file_path"))  # a union's frame: its sequence folder by default
            sequence = entry.get("sequence", union[0] if union else None)
            if sequence is not None and not isinstance(sequence, str):
                raise CaptureError(source, f"{where}.sequence", f"expected a string, got {sequence!r}")
            check_frame_paths(root, entry, source, where)
            mask = entry.get("fg_mask_path")
            if (t, c) in seen:
                raise CaptureError(source, where, f"timestep {t} camera {c} is listed twice")
            seen.add((t, c))
            camera = camera_of(entry, doc, camera_id, c, source, where, cameras, parsed)
            record = (timestep_id, entry["flame_param_path"], sequence)
            if per_timestep.setdefault(t, record) != record:
                raise CaptureError(
                    source, f"{where}.timestep_id/flame_param_path/sequence",
                    f"timestep {t} is described differently by another frame: {per_timestep[t]} vs {record}",
                )
            frames.append(
                Frame(
                    split, pos, t, timestep_id, c, camera_id,
                    entry["file_path"], mask, entry["flame_param_path"], sequence, camera,
                )
            )
        for name, values in (
            ("camera_indices", {f.camera_index for f in frames}),
            ("timestep_indices", {f.timestep_index for f in frames}),
        ):
            listed = doc.get(name)
            if listed is not None and (not isinstance(listed, list) or set(listed) != values):
                raise CaptureError(source, name, "does not match the indices of the frames")
        return frames

    # -- queries -------------------------------------------------------------------------------
    def frames(self, split: str | None = None) -> list[Frame]:
        """The frames of one split, or of every split in train, val, test order."""
        if split is not None:
            if split not in self.splits:
                raise CaptureError(self.root, "split", f"no {split!r} split (have {list(self.splits)})")
            return list(self.splits[split])
        return [f for frames in self.splits.values() for f in frames]

    def camera(self, frame: Frame) -> Camera:
        """The camera of one frame (its own pose: in union datasets it differs per sequence)."""
        return frame.camera if frame.camera is not None else self.cameras[frame.camera_id]

    def camera_at(self, camera_id: str, timestep: int) -> Camera:
        """Camera ``camera_id`` as placed at ``timestep`` (its first pose when no frame shows it there)."""
        if self._at is None:
            self._at = {(f.camera_id, f.timestep_index): f for f in reversed(self.frames())}
        frame = self._at.get((camera_id, timestep))
        return self.camera(frame) if frame is not None else self.cameras[camera_id]

    def path(self, frame: Frame, name: str) -> pathlib.Path:
        """Absolute path of one of ``frame``'s files: ``"file_path"``, ``"fg_mask_path"``, ``"flame_param_path"``.

        Refuses a path that leaves its allowed tree, symlinks followed (:mod:`.paths`).
        """
        relative, source, field = getattr(frame, name), self.root / frame.source, frame.field(name)
        path = layout.resolve_inside(self.root, relative, source, field)
        return check_stays_inside(self.root, relative, path, source, field)

    @property
    def memory_bound_bytes(self) -> int:
        return self._images.max_bytes

    @property
    def cached_bytes(self) -> int:
        return self._images.nbytes

    # -- pixels --------------------------------------------------------------------------------
    def load_image(self, frame: Frame) -> tuple[np.ndarray, np.ndarray]:
        """``(rgb (H,W,3), mask (H,W))`` float32 in [0,1], read-only, cached (LRU, byte-bounded).

        The mask comes from ``fg_mask_path``; without one, from the image's alpha channel;
        without that, it is all ones.
        """
        key = (frame.file_path, frame.fg_mask_path)
        hit = self._images.get(key)
        if hit is not None:
            return hit
        rgb, alpha = self._decode_rgb(frame)
        if frame.fg_mask_path is not None:
            mask = self._read(frame, "fg_mask_path")[..., 0]
            self._check_size(frame, "fg_mask_path", mask)
        elif alpha is not None:
            mask = alpha
        else:
            mask = np.ones(rgb.shape[:2], np.float32)
        mask = np.ascontiguousarray(mask, dtype=np.float32)
        mask.setflags(write=False)
        self._images.put(key, (rgb, mask), rgb.nbytes + mask.nbytes)
        return rgb, mask

    def load_rgb(self, frame: Frame) -> np.ndarray:
        """The image alone, as :meth:`load_image` gives it: from its cache when it holds the frame,
        else decoded without the mask and not cached (the encoder's small copies need no more, and
        must not push out the frames the loss reads)."""
        hit = self._images.get((frame.file_path, frame.fg_mask_path))
        return hit[0] if hit is not None else self._decode_rgb(frame)[0]

    def _decode_rgb(self, frame: Frame) -> tuple[np.ndarray, np.ndarray | None]:
        """``(rgb (H,W,3) read-only, the file's alpha channel or None)``, checked against the camera."""
        rgb = self._read(frame, "file_path")
        self._check_size(frame, "file_path", rgb)
        channels = rgb.shape[2]
        alpha = rgb[..., channels - 1] if channels in (2, 4) else None
        rgb = np.repeat(rgb[..., :1], 3, axis=2) if channels <= 2 else rgb[..., :3]
        rgb = np.ascontiguousarray(rgb, dtype=np.float32)
        rgb.setflags(write=False)
        return rgb, alpha

    def _check_size(self, frame: Frame, name: str, array: np.ndarray) -> None:
        camera = self.camera(frame)
        if array.shape[:2] != (camera.height, camera.width):
            raise CaptureError(
                self.path(frame, name), f"{frame.source} {frame.field('w/h')}",
                f"image is {array.shape[1]}x{array.shape[0]}, the frame says {camera.width}x{camera.height}",
            )

    def _read(self, frame: Frame, name: str) -> np.ndarray:
        path = self.path(frame, name)
        try:
            return read_image(path)
        except InputError as error:
            raise CaptureError(path, f"{frame.source} {frame.field(name)}", error.problem) from None

    # -- FLAME parameters ----------------------------------------------------------------------
    def timestep_frame(self, timestep: int) -> Frame:
        """The first frame listed for a timestep (the one its FLAME parameters are read through)."""
        frame = self._timestep_frame.get(timestep)
        if frame is None:
            raise CaptureError(self.root, "timestep_index", f"no frame has timestep {timestep}")
        return frame

    def flame_params(self, timestep: int) -> dict[str, np.ndarray]:
        """The tracked FLAME parameters of one timestep: float32 ``(n,)`` vectors (``static_offset (V,3)``)."""
        frame = self.timestep_frame(timestep)
        field = f"{frame.source} {frame.field('flame_param_path')}"
        return self._load_flame(self.flame_param_file(timestep), field)

    def flame_param_file(self, timestep: int) -> pathlib.Path:
        """The file :meth:`flame_params` reads for one timestep."""
        return self.path(self.timestep_frame(timestep), "flame_param_path")

    def flame_params_stacked(self, timesteps: list[int] | None = None) -> dict[str, np.ndarray]:
        """Parameters of many timesteps stacked to ``(T, n)`` (``static_offset`` from the first;
        ``dynamic_offset`` stacked to ``(T, V, 3)``)."""
        timesteps = self.timesteps if timesteps is None else list(timesteps)
        rows = [self.flame_params(t) for t in timesteps]
        out = {}
        for key in rows[0]:
            if key == "static_offset":
                out[key] = rows[0][key]
                continue
            sizes = {r[key].shape for r in rows}
            if len(sizes) != 1:
                raise CaptureError(self.root, key, f"sizes differ between timesteps: {sorted(sizes)}")
            out[key] = np.stack([r[key] for r in rows])
        return out

    def canonical_flame_params(self) -> dict[str, np.ndarray] | None:
        """``canonical_flame_param.npz`` normalised like :meth:`flame_params`, or None if absent."""
        path = self.root / layout.CANONICAL_FILE
        if not path.exists():
            return None
        check_stays_inside(self.root, layout.CANONICAL_FILE, path, path, None)
        return self._load_flame(path, None)

    @staticmethod
    def _load_flame(path: pathlib.Path, field: str | None) -> dict[str, np.ndarray]:
        """Load and check one FLAME file; ``field`` names the reference to it for errors."""
        if path.is_file() and not zipfile.is_zipfile(path):
            raise CaptureError(path, field, "not an .npz (zip) archive")
        try:
            arrays = load_npz(path, MAX_PARAM_FILE_BYTES)
        except InputError as error:
            raise CaptureError(path, error.field or field, error.problem) from None
        return layout.normalize_flame_params(arrays, path)
