"""The training core: everything that does not need Blender. Never imports ``bpy``."""

import os
import pathlib


def _user_cache_dir() -> pathlib.Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return pathlib.Path(base) / "mogaface"


# numba caches compiled kernels beside their source unless told otherwise; the
# extension folder may be read-only, so kernels are cached per user instead.
os.environ.setdefault("NUMBA_CACHE_DIR", str(_user_cache_dir() / "numba"))

# torch and numba share one OpenMP runtime whose idle threads spin by default; on a busy
# machine that makes 2 threads slower than 1 (docs/splat.md). Only effective before torch loads.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
