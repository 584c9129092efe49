"""Numbers over several training seeds: mean ± std, and whether a difference is beyond the noise.

A difference between two settings is taken seed by seed (paired: the same seed, the same capture)
and called beyond noise when a two-sided paired t-test rejects "no difference" at 5 %: the mean
difference exceeds ``t(0.975, n−1)·std/√n``. One seed can never tell, and neither can seeds that
all differ by the same amount (zero spread: the test has no scale, a rounding away from "no
difference" would pass as certain); both say "n/a".
"""

from __future__ import annotations

import math

import numpy as np

SIGNIFICANCE = 0.05


def mean_std(values: list[float | None]) -> tuple[float | None, float | None, int]:
    """``(mean, sample std or None for one value, count)`` over the values that are known."""
    known = [float(v) for v in values if v is not None and math.isfinite(v)]
    if not known:
        return None, None, 0
    std = float(np.std(known, ddof=1)) if len(known) > 1 else None
    return float(np.mean(known)), std, len(known)


def paired_difference(a: list[float | None], b: list[float | None]) -> dict:
    """``a − b`` seed by seed: ``{"mean", "std", "n", "beyond_noise"}``; ``beyond_noise`` is None where
    the test cannot tell (fewer than two seeds, or no spread between them)."""
    pairs = [(x, y) for x, y in zip(a, b) if x is not None and y is not None and math.isfinite(x) and math.isfinite(y)]
    diffs = [x - y for x, y in pairs]
    mean, std, n = mean_std(diffs)
    beyond = None
    if n >= 2 and std is not None and std > 0:
        from scipy.stats import t

        beyond = bool(abs(mean) > t.ppf(1 - SIGNIFICANCE / 2, n - 1) * std / math.sqrt(n))
    return {"mean": mean, "std": std, "n": n, "beyond_noise": beyond}


def format_mean_std(values: list[float | None], digits: int) -> str:
    mean, std, _ = mean_std(values)
    if mean is None:
        return "–"
    return f"{mean:.{digits}f}" if std is None else f"{mean:.{digits}f} ± {std:.{digits}f}"


def format_difference(diff: dict, digits: int) -> str:
    """``+0.52 ± 0.10 *`` (beyond noise), ``… (n.s.)`` (within it), ``… (n/a)`` where the test
    cannot tell (one seed, or no spread)."""
    if diff["mean"] is None:
        return "–"
    text = f"{diff['mean']:+.{digits}f}"
    if diff["std"] is not None:
        text += f" ± {diff['std']:.{digits}f}"
    if diff["beyond_noise"] is True:
        text += " *"
    elif diff["beyond_noise"] is False:
        text += " (n.s.)"
    else:
        text += " (n/a)"
    return text
