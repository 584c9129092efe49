"""The training core: everything that does not need Blender. Never imports ``bpy``."""

import os

from . import numba_cache

# Compiled kernels are cached per user, in a private folder of this import name (numba_cache).
numba_cache.configure(__name__.rpartition(".")[0] or __name__)

# torch and numba share one OpenMP runtime whose idle threads spin by default; on a busy
# machine that makes 2 threads slower than 1 (docs/splat.md). Only effective before torch loads.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
