"""Confidence intervals shared by the measurements: a success rate's (Wilson) and a median's (bootstrap)."""

from __future__ import annotations

import math

import numpy as np
from scipy import stats


def wilson_interval(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson score interval of a success rate: stays inside [0, 1] and is sensible at 0 or n
    successes, where the normal approximation collapses to a point."""
    if n < 1:
        raise ValueError("a confidence interval needs at least one episode")
    p, z2 = successes / n, z * z
    centre = (p + z2 / (2 * n)) / (1 + z2 / n)
    half = z * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n)) / (1 + z2 / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def median_interval(values: np.ndarray) -> list[float] | None:
    """95 % bootstrap (percentile) interval of the median, seeded so a result file is reproducible; None for
    fewer than 2 values. Percentile rather than BCa: BCa's jackknife is degenerate for a median of ties."""
    if len(values) < 2:
        return None
    res = stats.bootstrap((values,), np.median, n_resamples=2000, method="percentile",
                          random_state=np.random.default_rng(0))
    return [round(float(res.confidence_interval.low), 2), round(float(res.confidence_interval.high), 2)]
