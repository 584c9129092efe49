"""A run folder, opened: its paths, its ``run.json`` (read and checked once) and the one avatar loader.

Training writes the folder through :meth:`RunFolder.at` (paths only); evaluation, rendering,
exports, refine-tracking, ablation, the demo and Blender open a finished run with
:class:`RunFolder` (or :meth:`RunFolder.of_avatar`) and load its avatar with
:meth:`RunFolder.load_avatar`, which adds the MoGaFace modules whenever the run has them, so every
consumer draws the avatar that ``render`` draws.
"""

from __future__ import annotations

import functools
import os
import pathlib

import numpy as np

from ..data import layout
from ..data.capture_info import DEFAULT_BACKGROUND, capture_background
from ..errors import InputError
from . import names

IDENTITY_KEYS = ("shape", "static_offset")
MOTION_KEYS = tuple(k for k in layout.FLAME_KEYS if k not in IDENTITY_KEYS)


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
    from ..io.npz import load_npz
    from ..limits import MAX_PARAM_FILE_BYTES

    return layout.normalize_flame_params(load_npz(path, MAX_PARAM_FILE_BYTES), path)


def is_complete(root: str | os.PathLike) -> bool:
    """Whether the run at ``root`` trained to its end (``run.json``'s ``complete``): a finished run a
    workflow reuses instead of training again. No or an unreadable ``run.json``: not complete."""
    import json

    try:
        return bool(json.loads((pathlib.Path(root) / names.RUN_FILE).read_text(encoding="utf-8")).get("complete"))
    except (OSError, ValueError, AttributeError):
        return False


class RunFolder:
    """A finished run, opened: checks that it holds an avatar and that its ``run.json`` is sound.

    ``capture``: the capture folder when it has moved (else ``run.json``'s, read lazily, so an
    avatar whose capture is gone still loads). ``avatar_file``: another avatar file inside the
    folder (an imported ``.pt``); the MoGaFace modules belong to ``avatar.pt`` alone.
    """

    def __init__(self, root: str | os.PathLike, capture: str | os.PathLike | None = None,
                 avatar_file: str | os.PathLike | None = None):
        self._place(root, capture, avatar_file)
        if not self.root.is_dir():
            raise InputError(self.root, None, "not a run folder")
        if not self.avatar_path.is_file():
            if self.avatar_path.exists():  # a FIFO, device or folder where the avatar should be
                from ..io.files import check_regular_file

                check_regular_file(self.avatar_path)
            raise InputError(self.avatar_path, None, "avatar file not found (is training finished?)")
        self.background  # noqa: B018 -- run.json is read and checked now, not at first use

    def _place(self, root, capture, avatar_file) -> None:
        self.root = pathlib.Path(root)
        self._capture = capture
        self.avatar_path = self.root / names.AVATAR_FILE if avatar_file is None else pathlib.Path(avatar_file)

    @classmethod
    def at(cls, path: str | os.PathLike) -> "RunFolder":
        """The folder a run is being written to: its paths only, nothing read or checked."""
        folder = cls.__new__(cls)
        folder._place(pathlib.Path(path).resolve(), None, None)
        return folder

    @classmethod
    def of_avatar(cls, path: str | os.PathLike) -> "RunFolder":
        """The run of a run folder or of an avatar file inside one (what Blender's file field holds)."""
        path = pathlib.Path(path).expanduser()
        if path.is_dir():
            return cls(path)
        if not path.is_file():
            raise InputError(path, None, "avatar file not found (is training finished?)")
        return cls(path.parent, avatar_file=path)

    # -- paths -------------------------------------------------------------------------------
    @property
    def config_path(self) -> pathlib.Path:
        return self.root / names.CONFIG_FILE

    @property
    def run_json_path(self) -> pathlib.Path:
        return self.root / names.RUN_FILE

    @property
    def events_path(self) -> pathlib.Path:
        return self.root / names.EVENTS_FILE

    @property
    def checkpoint_dir(self) -> pathlib.Path:
        return self.root / names.CHECKPOINT_DIR

    @property
    def modules_path(self) -> pathlib.Path:
        return self.root / names.MODULES_FILE

    @property
    def flame_param_dir(self) -> pathlib.Path:
        return self.root / names.FLAME_PARAM_DIR

    @property
    def metrics_path(self) -> pathlib.Path:
        return self.root / names.METRICS_TRAIN_END_FILE

    @property
    def refined_cameras_path(self) -> pathlib.Path:
        return self.root / names.REFINED_CAMERAS_FILE

    @property
    def delays_path(self) -> pathlib.Path:
        return self.root / names.DELAYS_FILE

    @property
    def colours_path(self) -> pathlib.Path:
        return self.root / names.COLOURS_FILE

    def head_path(self, suffix: str = ".pkl") -> pathlib.Path:
        return self.root / f"{names.HEAD_STEM}{suffix}"

    # -- run.json ----------------------------------------------------------------------------
    @functools.cached_property
    def info(self) -> dict:
        """``run.json`` as written by training (``{}`` for a folder without one)."""
        from ..io.jsonfile import read_json_object

        return read_json_object(self.run_json_path) if self.run_json_path.exists() else {}

    @functools.cached_property
    def capture_root(self) -> pathlib.Path:
        """The capture the run was trained on (``run.json``'s ``capture``, relative to the run)."""
        capture = self._capture
        if capture is None:
            capture = self.info.get("capture")
            if not isinstance(capture, str) or not capture:
                raise InputError(self.run_json_path, "capture", "missing: pass the capture folder explicitly")
            from ..io.files import check_path_text

            capture = self.root / check_path_text(capture, self.run_json_path, "capture")  # absolute as written; a relative one is read from the run folder
        return pathlib.Path(capture)

    @functools.cached_property
    def background(self) -> tuple[float, float, float]:
        """``run.json``'s background, else the capture's, else white."""
        if "background" in self.info:
            return parse_background(self.info["background"], self.run_json_path)
        if self._capture is None and not self.info.get("capture"):
            return DEFAULT_BACKGROUND
        return capture_background(self.capture_root)

    @functools.cached_property
    def trained_timesteps(self) -> list[int]:
        """Timesteps with trained FLAME parameters (``flame_param/TTTTT.npz``)."""
        if not self.flame_param_dir.is_dir():
            return []
        return sorted(int(p.stem) for p in self.flame_param_dir.glob("*.npz") if p.stem.isdigit())

    # -- contents ----------------------------------------------------------------------------
    def open_capture(self):
        from ..data.capture import Capture

        return Capture.open(self.capture_root)

    def flame_params(self, timestep: int) -> dict[str, np.ndarray] | None:
        """This run's FLAME parameters of a training timestep, or None for a timestep it never saw."""
        if timestep not in self.trained_timesteps:
            return None
        return load_flame_file(self.flame_param_file(timestep))

    def flame_param_file(self, timestep: int) -> pathlib.Path:
        """The file of this run's FLAME parameters of a training timestep."""
        return self.flame_param_dir / f"{timestep:05d}.npz"

    def identity_params(self) -> dict[str, np.ndarray] | None:
        """``shape`` (and ``static_offset``) as training left them, or None without trained files."""
        if not self.trained_timesteps:
            return None
        params = self.flame_params(self.trained_timesteps[0])
        return {k: v for k, v in params.items() if k in IDENTITY_KEYS}

    def _own_avatar(self) -> bool:
        """Whether the avatar is the run's own ``avatar.pt`` (what the run's other files belong to)."""
        return self.avatar_path.name == names.AVATAR_FILE and self.avatar_path.parent == self.root

    def has_modules(self) -> bool:
        """Whether the avatar renders with MoGaFace modules (``mogaface.pt`` beside ``avatar.pt``)."""
        return self._own_avatar() and self.modules_path.is_file()

    def camera_colours(self) -> dict[str, np.ndarray] | None:
        """The training cameras' learned colours (``camera_colours.json``), camera id → change
        ``[M − I | b]`` (:mod:`..avatar.camera_colour`); None for a run without them."""
        if not (self._own_avatar() and self.colours_path.is_file()):
            return None
        from ..avatar.camera_colour import read_camera_colours

        return read_camera_colours(self.colours_path)

    def load_avatar(self):
        """The run's avatar as ``render`` draws it: :class:`~..avatar.avatar.Avatar`, wrapped in
        :class:`~..correction.avatar.ModulatedAvatar` when the run has MoGaFace modules. Its
        ``camera_colours`` are the run's learned camera colours (or None), for renders that show a
        training camera's view in that camera's colours (:func:`~..avatar.avatar.render_frame`'s
        ``colour``)."""
        from ..avatar.avatar import Avatar

        avatar = Avatar.load(self.avatar_path)
        avatar.camera_colours = self.camera_colours()
        if not self.has_modules():
            return avatar
        from ..correction.avatar import ModulatedAvatar
        from ..correction.model import MoGaFace

        try:
            model = MoGaFace.load(self.modules_path)
        except (RuntimeError, KeyError, ValueError, TypeError) as error:  # modules of another version
            raise InputError(self.modules_path, None, f"cannot load the modules ({error})") from None
        return ModulatedAvatar(avatar, model)
