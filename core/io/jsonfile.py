"""Read JSON files (captures' split files, run.json, settings beside them), with errors that name
the file; the one JSON reader, so every one is checked for size before it is read."""

from __future__ import annotations

import json
import os

from ..errors import InputError
from ..limits import MAX_JSON_BYTES, MAX_JSON_VALUES
from .files import check_regular_file


def read_json(path: str | os.PathLike, error: type[InputError] = InputError):
    """The JSON value in ``path``: a regular file of at most :data:`MAX_JSON_BYTES`, read once."""
    try:
        check_regular_file(path, error)
        with open(path, "rb") as handle:
            size = os.fstat(handle.fileno()).st_size
            if size > MAX_JSON_BYTES:
                raise error(path, None, f"a JSON file of {size} bytes; the limit is {MAX_JSON_BYTES} (see docs/safety.md)")
            data = handle.read(MAX_JSON_BYTES + 1)
        if len(data) > MAX_JSON_BYTES:  # grew while it was opened
            raise error(path, None, f"a JSON file over the limit of {MAX_JSON_BYTES} bytes")
        # Python's objects take up to ~35 bytes a value ('[],' is 3 bytes of text and 69 of lists):
        # counted on the bytes before parsing (commas in strings count too: an upper bound).
        values = data.count(b",") + data.count(b"[") + data.count(b"{")
        if values > MAX_JSON_VALUES:
            raise error(path, None, f"holds up to {values} values (counting separators); the limit is "
                                    f"{MAX_JSON_VALUES} (see docs/safety.md)")
        return json.loads(data.decode("utf-8"))
    except InputError:  # already worded (InputError is a ValueError too)
        raise
    except RecursionError:
        raise error(path, None, "nested too deeply to be a capture or settings file") from None
    except FileNotFoundError:
        raise error(path, None, "file not found") from None
    except (OSError, ValueError) as problem:  # bad UTF-8, bad JSON, a number of 10 000 digits
        raise error(path, None, f"unreadable JSON ({problem})") from None


def read_json_object(path: str | os.PathLike, error: type[InputError] = InputError) -> dict:
    """The JSON object in ``path``; anything else raises ``error(path, None, problem)``."""
    doc = read_json(path, error)
    if not isinstance(doc, dict):
        raise error(path, None, f"expected a JSON object at the top level, got {type(doc).__name__}")
    return doc
