"""Caches keyed by a file's version: an edited file reloads, an unchanged one is loaded once."""

from __future__ import annotations

import os
import pathlib
import threading

from ..errors import InputError

#: Held while a cached model (head model or avatar) is looked up or loaded.
CACHE_LOCK = threading.Lock()


def file_version(path, what: str) -> tuple[pathlib.Path, tuple]:
    """The resolved path and a cache key that changes whenever the file is rewritten."""
    path = pathlib.Path(path).expanduser().resolve()
    try:
        stat = path.stat()
    except OSError:
        raise InputError(path, None, f"{what} file not found") from None
    return path, (os.fspath(path), stat.st_size, stat.st_mtime_ns)
