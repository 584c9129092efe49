"""``compile-kernels``: compile the engine's numba kernels now, so the first run starts at full pace.

Prints JSON: the seconds of each group (about a minute of single-core work in all on an empty
cache, a second or two once cached), the wall time and the cache folder.
"""

from __future__ import annotations

import os


def add_arguments(parser) -> None:
    parser.add_argument("--jobs", type=int, default=min(3, os.cpu_count() or 1),
                        help="processes compiling at once (default: the cores, at most 3; 1: in this process)")


def run(args) -> int:
    import json
    import time

    from ..errors import InputError
    from ..precompile import compile_kernels

    if args.jobs < 1:
        raise InputError(None, "--jobs", f"expected at least 1, got {args.jobs}")
    start = time.perf_counter()
    seconds = compile_kernels(args.jobs)
    print(json.dumps({"seconds": {name: round(s, 2) for name, s in seconds.items()},
                      "wall_seconds": round(time.perf_counter() - start, 2), "jobs": args.jobs,
                      "cache": os.environ.get("NUMBA_CACHE_DIR")}, indent=1))
    return 0
