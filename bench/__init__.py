"""Benchmarks: each module has ``run(threads, quick) -> dict`` and is reached by ``python -m mogaface bench NAME``."""
