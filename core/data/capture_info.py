"""``capture_info.json``: what a synthetic capture records about itself (its settings, background,
head model file, sequences); real captures have none."""

from __future__ import annotations

import os
import pathlib

from ..errors import CaptureError
from ..io.jsonfile import read_json_object

INFO_FILE = "capture_info.json"


def capture_info(root: str | os.PathLike) -> dict:
    """``capture_info.json`` of the capture in ``root``, or ``{}`` when it has none."""
    path = pathlib.Path(root) / INFO_FILE
    return read_json_object(path, CaptureError) if path.exists() else {}
