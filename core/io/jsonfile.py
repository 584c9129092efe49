"""Read a JSON file that must hold an object, with errors that name the file."""

from __future__ import annotations

import json
import os

from ..errors import InputError


def read_json_object(path: str | os.PathLike, error: type[InputError] = InputError) -> dict:
    """The JSON object in ``path``; anything else raises ``error(path, None, problem)``."""
    try:
        with open(path, encoding="utf-8") as handle:
            doc = json.load(handle)
    except FileNotFoundError:
        raise error(path, None, "file not found") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as problem:
        raise error(path, None, f"unreadable JSON ({problem})") from None
    if not isinstance(doc, dict):
        raise error(path, None, f"expected a JSON object at the top level, got {type(doc).__name__}")
    return doc
