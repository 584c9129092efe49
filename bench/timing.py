"""The median of a call's wall time, shared by the benchmarks that time small pieces."""

from __future__ import annotations

import statistics
import time


def median_ms(call, repeats: int, warmups: int = 1) -> float:
    """Milliseconds: the median of ``repeats`` timed calls after ``warmups`` untimed ones."""
    for _ in range(warmups):
        call()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return 1000 * statistics.median(times)
