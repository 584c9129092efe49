"""``capture_info.json``: what a synthetic capture records about itself (its settings, background,
head model file, sequences); real captures have none."""

from __future__ import annotations

import os
import pathlib

from ..errors import CaptureError
from ..io.files import file_inside
from ..io.jsonfile import read_json_object

INFO_FILE = "capture_info.json"
DEFAULT_BACKGROUND = (1.0, 1.0, 1.0)  # white
DEFAULT_HEAD_FILE = "head.pkl"


def capture_info(root: str | os.PathLike) -> dict:
    """``capture_info.json`` of the capture in ``root``, or ``{}`` when it has none."""
    path = pathlib.Path(root) / INFO_FILE
    return read_json_object(path, CaptureError) if path.exists() else {}


def capture_background(root: str | os.PathLike) -> tuple[float, float, float]:
    """The colour the capture's images are composited on (``capture_info.json`` "background"; white)."""
    root = pathlib.Path(root)
    value = capture_info(root).get("background", DEFAULT_BACKGROUND)
    if not (isinstance(value, list | tuple) and len(value) == 3
            and all(isinstance(v, int | float) and 0 <= v <= 1 for v in value)):
        raise CaptureError(root / INFO_FILE, "background", f"expected three numbers in [0, 1], got {value!r}")
    return tuple(float(v) for v in value)


def capture_head_file(root: str | os.PathLike) -> pathlib.Path:
    """The head model file a capture names (``capture_info.json`` "model_file"), or ``head.pkl``: what
    train, check-capture and solve-cameras use when no ``--head`` is given."""
    root = pathlib.Path(root)
    name = capture_info(root).get("model_file", DEFAULT_HEAD_FILE)
    path = file_inside(root, name, root / INFO_FILE, "model_file", CaptureError)
    if not path.is_file():
        raise CaptureError(root / INFO_FILE, "model_file",
                           f"head model file {path} not found (pass --head FILE)")
    return path
