"""The trained avatar for Blender: found from a run folder, loaded once per file version."""

from __future__ import annotations

import pathlib

from .file_cache import CACHE_LOCK, file_version


def avatar_location(path) -> tuple[pathlib.Path, tuple[float, float, float]]:
    """A run folder or an avatar file → the avatar file and the background it was trained on.

    Read by :class:`~..run.folder.RunFolder` (``run.json`` checked: a bad background is an error;
    white without one).
    """
    from ..run.folder import RunFolder

    run = RunFolder.of_avatar(path)
    return run.avatar_path.resolve(), run.background


_avatar_cache: dict = {}


def load_avatar(path):
    """The avatar of a run folder or avatar file, as :meth:`RunFolder.load_avatar
    <..run.folder.RunFolder.load_avatar>` loads it (with the run's MoGaFace modules when it has
    them), cached while neither the avatar nor the modules file changes."""
    from ..run.folder import RunFolder

    run = RunFolder.of_avatar(path)
    path, key = file_version(run.avatar_path, "avatar")
    if run.has_modules():
        key = key + file_version(run.modules_path, "MoGaFace modules")[1]
    with CACHE_LOCK:
        avatar = _avatar_cache.get(key)
        if avatar is None:
            avatar = run.load_avatar()
            _avatar_cache.clear()
            _avatar_cache[key] = avatar
    return avatar

