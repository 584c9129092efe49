"""A training run's folder, read for evaluation, rendering and export.

::

    RUN/run.json             "capture" (absolute path), "background", ...
    RUN/avatar.pt            the trained avatar (Avatar.save), beside its head model file
    RUN/flame_param/*.npz    FLAME parameters of the training timesteps, as training left them

Only what evaluation needs is read; the trainer owns the rest of the folder.
"""

from __future__ import annotations

import os
import pathlib

import numpy as np

from ..data import layout
from ..data.generator import INFO_FILE
from ..errors import InputError
from ..io.jsonfile import read_json_object
from ..io.npz import load_npz
from ..limits import MAX_PARAM_FILE_BYTES

RUN_FILE = "run.json"
AVATAR_FILE = "avatar.pt"
FLAME_PARAM_DIR = "flame_param"
DEFAULT_BACKGROUND = (1.0, 1.0, 1.0)


def _read_json(path: pathlib.Path) -> dict:
    return read_json_object(path)


def capture_info(capture_root: str | os.PathLike) -> dict:
    """The capture's ``capture_info.json`` (synthetic captures write it), or ``{}``."""
    path = pathlib.Path(capture_root) / INFO_FILE
    return _read_json(path) if path.exists() else {}


def parse_background(value, source, field: str = "background") -> tuple[float, float, float]:
    """An RGB triple in [0, 1] from JSON or the command line."""
    try:
        rgb = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise InputError(source, field, f"expected three numbers, got {value!r}") from None
    if len(rgb) != 3 or not all(0.0 <= v <= 1.0 for v in rgb):
        raise InputError(source, field, f"expected three numbers in [0, 1], got {value!r}")
    return rgb


def load_flame_file(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """One timestep's FLAME ``.npz`` (VHAP form or plain), checked: ``(n,)`` vectors, ``static_offset (V,3)``."""
    return layout.normalize_flame_params(load_npz(path, MAX_PARAM_FILE_BYTES), path)


class RunFolder:
    """An opened run folder: its avatar, capture, background and trained FLAME parameters."""

    def __init__(self, root: str | os.PathLike, capture: str | os.PathLike | None = None):
        self.root = pathlib.Path(root)
        if not self.root.is_dir():
            raise InputError(self.root, None, "not a run folder")
        self.avatar_path = self.root / AVATAR_FILE
        if not self.avatar_path.exists():
            raise InputError(self.avatar_path, None, "file not found (is training finished?)")
        run_file = self.root / RUN_FILE
        self.info = _read_json(run_file) if run_file.exists() else {}
        if capture is None:
            capture = self.info.get("capture")
            if not isinstance(capture, str) or not capture:
                raise InputError(run_file, "capture", "missing: pass the capture folder explicitly")
            capture = self.root / capture  # absolute as written; a relative one is read from the run folder
        self.capture_root = pathlib.Path(capture)
        if "background" in self.info:
            self.background = parse_background(self.info["background"], run_file)
        else:
            recorded = capture_info(self.capture_root).get("background", DEFAULT_BACKGROUND)
            self.background = parse_background(recorded, self.capture_root)
        self.flame_param_dir = self.root / FLAME_PARAM_DIR
        self.trained_timesteps = sorted(
            int(p.stem) for p in self.flame_param_dir.glob("*.npz") if p.stem.isdigit()
        ) if self.flame_param_dir.is_dir() else []

    def load_avatar(self):
        from ..avatar.avatar import Avatar

        return Avatar.load(self.avatar_path)

    def open_capture(self):
        from ..data.capture import Capture

        return Capture.open(self.capture_root)

    def flame_params(self, timestep: int) -> dict[str, np.ndarray] | None:
        """This run's FLAME parameters of a training timestep, or None for a timestep it never saw."""
        if timestep not in self.trained_timesteps:
            return None
        return load_flame_file(self.flame_param_dir / f"{timestep:05d}.npz")

    def identity_params(self) -> dict[str, np.ndarray] | None:
        """``shape`` (and ``static_offset``) as training left them, or None without trained files."""
        if not self.trained_timesteps:
            return None
        params = self.flame_params(self.trained_timesteps[0])
        return {k: v for k, v in params.items() if k in IDENTITY_KEYS}


IDENTITY_KEYS = ("shape", "static_offset")
MOTION_KEYS = tuple(k for k in layout.FLAME_KEYS if k not in IDENTITY_KEYS)
