"""Which Python packages the core needs, whether they import here, and how to install them.

Packages installed by ``mogaface.install_dependencies`` live in the extension's user folder
(:func:`site_packages`), on ``sys.path`` while the extension is enabled.

Checked with ``importlib.util.find_spec`` (nothing is imported), so the panel can draw the
answer on every redraw, and the operators can refuse cleanly instead of failing in an import.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import sys

REQUIRED_MODULES = ("numpy", "torch", "numba")

#: What reading captures and heads needs (no torch: importing cameras and meshes stays light).
FILE_MODULES = ("numpy",)


class LazyModule:
    """A module imported on first attribute use, so registering the add-on imports nothing heavy.

    ``np = LazyModule("numpy")`` at the top of an operator module; a Blender without numpy can
    still enable the extension, draw the panel and offer *Install Dependencies*.
    """

    def __init__(self, name: str):
        self._name = name

    def __getattr__(self, attribute):
        return getattr(importlib.import_module(self._name), attribute)


def missing_modules(names=REQUIRED_MODULES) -> list[str]:
    """The names among ``names`` that this Python cannot import."""
    missing = []
    for name in names:
        try:
            found = importlib.util.find_spec(name) is not None
        except (ImportError, ValueError):  # a broken entry in sys.modules counts as missing
            found = False
        if not found:
            missing.append(name)
    return missing


def report(missing) -> str:
    """One sentence for an operator's error report: what is missing and how to get it."""
    return (f"Missing Python packages: {', '.join(missing)}. Click Install Dependencies in the MoGaFace panel "
            "(or the add-on preferences), or name a Python that has them in the preferences")


def top_package() -> str:
    """The extension's own module name (``mogaface`` or ``bl_ext.<repo>.mogaface``)."""
    return __package__.rpartition(".")[0]


def preference(context, name: str, default):
    """One of the add-on's preferences (``default`` when the add-on is not registered as one)."""
    addon = context.preferences.addons.get(top_package())
    value = getattr(getattr(addon, "preferences", None), name, None) if addon else None
    return default if value is None else value


def interpreter(context) -> str:
    """The Python interpreter named in the add-on preferences (Blender's own if unset)."""
    return preference(context, "python_path", "") or sys.executable


def worker_paths(python: str) -> list[str]:
    """The folders a worker run by ``python`` needs in front of its own ``sys.path``.

    Blender's Python gets the extension's installed packages, exactly as Blender itself sees
    them; another interpreter has its own packages (ours may be built for another Python).
    """
    folder = site_packages()
    if folder is None or not os.path.isdir(folder):
        return []
    try:
        same = os.path.samefile(python, sys.executable)
    except OSError:
        same = False
    return [folder] if same else []


def site_packages(create: bool = False) -> str | None:
    """The extension's user folder for installed packages; None outside an installed extension."""
    import bpy

    try:
        return bpy.utils.extension_path_user(top_package(), path="site-packages", create=create)
    except ValueError:  # registered as a plain module, not an extension
        return None


def online_access() -> bool:
    """Whether the user allows Blender to go online (Preferences › System)."""
    import bpy

    return bool(bpy.app.online_access)


_added: list[str] = []


def add_site_packages(create: bool = False) -> str | None:
    """Put the user site-packages folder on ``sys.path`` (once); returns it, or None if absent."""
    folder = site_packages(create=create)
    if folder is None or not os.path.isdir(folder):
        return None
    if folder not in sys.path:
        sys.path.append(folder)
        _added.append(folder)
    importlib.invalidate_caches()
    return folder


def remove_site_packages() -> None:
    """Take back what :func:`add_site_packages` put on ``sys.path``."""
    folders = set(_added)
    _added.clear()
    own = site_packages()
    if own:
        folders.add(own)
    sys.path[:] = [path for path in sys.path if path not in folders]
    importlib.invalidate_caches()


#: The big native libraries behind torch and numba: (package, folder in it, library names).
_NATIVE_LIBRARIES = (("torch", "lib", ("c10", "torch_cpu", "torch_cuda", "torch")),
                     ("llvmlite", "binding", ("llvmlite",)))


def preload_native_libraries() -> None:
    """Load torch's and llvmlite's shared libraries through ``dlopen`` called via ctypes, from a
    worker thread, before those packages are imported.

    Python's own import of an extension module holds the interpreter lock while the dynamic loader
    maps and initialises its libraries (libtorch_cpu: 0.4-0.7 s), freezing Blender's interface;
    a ctypes call releases the lock. The later import finds them loaded. Only plain C++ libraries
    are preloaded (never a Python extension), each at most once; a library not found is skipped.
    """
    import ctypes
    import ctypes.util

    libc = ctypes.CDLL(None)
    libc.dlopen.restype = ctypes.c_void_p
    libc.dlopen.argtypes = [ctypes.c_char_p, ctypes.c_int]
    for package, folder, names in _NATIVE_LIBRARIES:
        if package in sys.modules:
            continue
        spec = importlib.util.find_spec(package)
        if spec is None or spec.origin is None:
            continue
        for name in names:
            path = os.path.join(os.path.dirname(spec.origin), folder, f"lib{name}.so")
            path = path if os.path.isfile(path) else ctypes.util.find_library(name)  # a distribution's torch
            if path:
                libc.dlopen(os.fsencode(path), os.RTLD_NOW | os.RTLD_GLOBAL)
