"""Where numba caches the compiled kernels: one private folder per import name.

numba writes a kernel's cache beside its source unless told otherwise, and the extension folder
may be read-only, so kernels are cached per user. The cache files are pickles that name the
module they were compiled in, so two processes that import this code under different names
(Blender's ``bl_ext.<repo>.mogaface`` and a worker's ``mogaface``) must never share a folder:
each would load the other's files and fail to find its module. Because numba loads those files
with pickle, the folder is created owner-only and a folder that someone else can write is refused
(a fresh private temporary folder is used instead, so nothing is loaded from it).

Light on purpose: imported by ``core/__init__`` before numba, never imports numba itself.
"""

from __future__ import annotations

import os
import pathlib
import stat
import sys
import tempfile
import warnings

#: The base folder of the user's MoGaFace caches; overrides ``$XDG_CACHE_HOME/mogaface``.
CACHE_ENV = "MOGAFACE_CACHE_DIR"


def user_cache_dir() -> pathlib.Path:
    """``$MOGAFACE_CACHE_DIR``, else ``$XDG_CACHE_HOME/mogaface``, else ``~/.cache/mogaface``."""
    if os.environ.get(CACHE_ENV):
        return pathlib.Path(os.environ[CACHE_ENV])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return pathlib.Path(base) / "mogaface"


def folder_for(import_name: str, base: pathlib.Path | None = None) -> pathlib.Path:
    """The cache folder of code imported as ``import_name`` (``mogaface``, ``bl_ext.user_default.mogaface``)."""
    safe = "".join(c if c.isalnum() or c in "._-" else "_" for c in import_name) or "_"
    return (base or user_cache_dir()) / "numba" / safe


def unsafe_reason(folder: pathlib.Path) -> str | None:
    """Why ``folder`` must not hold pickles loaded by this user (None when it is safe).

    Safe: a real folder (not a link) owned by this user that nobody else can write. Checked on
    POSIX only; on Windows the user's profile folder is private by default.
    """
    if not hasattr(os, "getuid"):
        return None
    try:
        info = os.lstat(folder)
    except OSError as error:
        return f"cannot inspect it ({error.strerror or error})"
    if stat.S_ISLNK(info.st_mode) or not stat.S_ISDIR(info.st_mode):
        return "it is not a plain folder"
    if info.st_uid != os.getuid():
        return f"it belongs to user id {info.st_uid}, not {os.getuid()}"
    if info.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        return f"other users can write it (mode {stat.S_IMODE(info.st_mode):o})"
    return None


def private_folder(folder: pathlib.Path) -> pathlib.Path:
    """Create ``folder`` (and its missing parents) owner-only (0700); return it if it is safe.

    A folder that exists but is not safe (:func:`unsafe_reason`) is left untouched and a fresh
    private temporary folder is returned instead, with a warning naming the reason.
    """
    try:
        old_umask = os.umask(0o077)
        try:
            folder.mkdir(parents=True, exist_ok=True, mode=0o700)
        finally:
            os.umask(old_umask)
        reason = unsafe_reason(folder)
    except OSError as error:
        reason = f"cannot create it ({error.strerror or error})"
    if reason is None:
        return folder
    fallback = pathlib.Path(tempfile.mkdtemp(prefix="mogaface-numba-"))  # 0700 by construction
    warnings.warn(f"numba cache {folder} not used: {reason}; caching in {fallback} for this process only",
                  RuntimeWarning, stacklevel=2)
    return fallback


def configure(import_name: str) -> pathlib.Path:
    """Point numba's cache at this import name's private folder; returns the folder.

    Sets ``NUMBA_CACHE_DIR`` (read when numba is imported) and, when numba's configuration is
    already loaded (another add-on imported numba first), its ``CACHE_DIR`` too.
    """
    folder = private_folder(folder_for(import_name))
    os.environ["NUMBA_CACHE_DIR"] = str(folder)
    config = sys.modules.get("numba.core.config")
    if config is not None:
        config.CACHE_DIR = str(folder)
    return folder
