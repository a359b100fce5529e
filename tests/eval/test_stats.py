"""The confidence intervals every measurement reports."""

from __future__ import annotations

import numpy as np
import pytest

from trainer.eval.stats import median_interval, wilson_interval


@pytest.mark.parametrize("successes,n", [(0, 10), (5, 10), (10, 10), (1, 30), (81, 263)])
def test_wilson_interval_matches_scipy(successes, n) -> None:
    from scipy.stats import binomtest

    expected = binomtest(successes, n).proportion_ci(method="wilson")
    np.testing.assert_allclose(wilson_interval(successes, n), (expected.low, expected.high), atol=1e-4)


def test_median_interval_holds_the_median_narrows_with_more_episodes_and_is_seeded() -> None:
    distances = np.random.default_rng(3).exponential(10.0, 400)
    small, large = median_interval(distances[:40]), median_interval(distances)
    assert small[0] <= np.median(distances[:40]) <= small[1] and large[0] <= np.median(distances) <= large[1]
    assert large[1] - large[0] < small[1] - small[0]
    assert median_interval(distances) == large and median_interval(distances[:1]) is None
