"""Read a JSON file that must hold an object, with errors that name the file."""

from __future__ import annotations

import json
import os

from ..errors import InputError
from .files import check_regular_file


def read_json_object(path: str | os.PathLike, error: type[InputError] = InputError) -> dict:
    """The JSON object in ``path``; anything else raises ``error(path, None, problem)``."""
    try:
        check_regular_file(path, error)
        with open(path, encoding="utf-8") as handle:
            doc = json.load(handle)
    except RecursionError:
        raise error(path, None, "nested too deeply to be a capture or settings file") from None
    except FileNotFoundError:
        raise error(path, None, "file not found") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as problem:
        raise error(path, None, f"unreadable JSON ({problem})") from None
    if not isinstance(doc, dict):
        raise error(path, None, f"expected a JSON object at the top level, got {type(doc).__name__}")
    return doc
