"""``python -m mogaface environment``: where this process finds its code and packages (JSON).

What a worker started by Blender actually sees: the package's folder and import name, the
numba cache folder, and for each required package the file it imports from (null: missing).
Checked with ``find_spec``, so nothing heavy is imported.
"""

from __future__ import annotations

import importlib.util
import json
import os
import sys

MODULES = ("numpy", "torch", "numba", "scipy", "skimage", "PIL", "OpenEXR", "trimesh")


def add_arguments(parser) -> None:
    parser.add_argument("--module", action="append", default=[], help="also locate this module (repeatable)")


def _origin(name: str) -> str | None:
    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError):
        return None
    return None if spec is None else spec.origin


def run(args) -> int:
    package = sys.modules[__name__.split(".")[0]]
    print(json.dumps({
        "package": package.__name__,
        "package_folder": os.path.dirname(package.__file__),
        "python": sys.executable,
        "version": list(sys.version_info[:3]),
        "numba_cache": os.environ.get("NUMBA_CACHE_DIR"),
        "sys_path": sys.path,
        "modules": {name: _origin(name) for name in (*MODULES, *args.module)},
    }, indent=1))
    return 0
