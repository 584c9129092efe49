"""numba's cache filed by the code, not by where it is installed.

numba files a kernel's cache under a hash of its source folder's absolute path, so the same code
installed in two places (the repository and Blender's extension folder, or a fresh install after
an update) compiles everything again, about a minute of work. This locator files it under the
folder's path inside the package (``core/splat``), within the import name's private folder
(:mod:`.numba_cache`), so every copy of the same code shares it.

Its freshness stamp is a hash of every module of the kernel's folder, not of its file alone: a
kernel inlines its neighbours' functions and constants (``splat/raster.py`` those of
``splat/tiles.py``), which numba's own stamp would miss, and two copies that differ anywhere in
that folder must never load each other's kernels.

Kernel modules import this module before defining their kernels. It builds on numba's locator
interface (``numba.core.caching``, its version pinned in requirements.txt and in the extension's
installer); tests/test_worker_start.py checks that two copies share the cache and that a change
in a kernel's folder compiles it again.
"""

from __future__ import annotations

import functools
import hashlib
import os
import pathlib

from numba.core import caching, config

PACKAGE_ROOT = pathlib.Path(__file__).resolve().parents[1]


@functools.lru_cache(maxsize=None)
def _folder_hash(folder: str, stamps: tuple) -> str:
    """sha256 of the folder's modules, names and contents (``stamps`` keys the memo on their mtimes)."""
    digest = hashlib.sha256()
    for name, _, _ in stamps:
        digest.update(name.encode() + b"\0" + pathlib.Path(folder, name).read_bytes() + b"\0")
    return digest.hexdigest()


def folder_stamp(folder: pathlib.Path) -> str:
    """A hash of every ``.py`` file in ``folder``: changes when any of them does."""
    files = sorted((p.name, p.stat()) for p in folder.iterdir() if p.suffix == ".py" and p.is_file())
    return _folder_hash(str(folder), tuple((name, info.st_mtime_ns, info.st_size) for name, info in files))


class PackageCacheLocator(caching._SourceFileBackedLocatorMixin, caching._CacheLocator):
    """Kernels of this package: ``$NUMBA_CACHE_DIR/<folder in the package>``, stamped by that folder."""

    def __init__(self, py_func, py_file):
        self._py_file = py_file
        self._lineno = py_func.__code__.co_firstlineno
        self._folder = pathlib.Path(py_file).resolve().parent
        inside = self._folder.relative_to(PACKAGE_ROOT)
        self._cache_path = os.path.join(config.CACHE_DIR, "package", *inside.parts)

    def get_cache_path(self):
        return self._cache_path

    def get_source_stamp(self):
        return folder_stamp(self._folder)

    @classmethod
    def from_function(cls, py_func, py_file):
        if not config.CACHE_DIR or not pathlib.Path(py_file).resolve().is_relative_to(PACKAGE_ROOT):
            return None
        return super().from_function(py_func, py_file)


def install() -> None:
    """Put the locator first in numba's list of locators (once)."""
    if PackageCacheLocator not in caching.CacheImpl._locator_classes:
        caching.CacheImpl._locator_classes.insert(0, PackageCacheLocator)


install()
