"""Flight metrics helpers that must agree with numpy to the bit (summaries are goldens)."""

from __future__ import annotations

import numpy as np
import pytest

from tfl_mav.flightlog.metrics import median


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 10, 11, 1000, 1001, 20000])
def test_median_is_numpys_to_the_bit(n: int) -> None:
    rng = np.random.default_rng(n)
    for _ in range(20):
        x = rng.standard_normal(n) * rng.uniform(1e-6, 1e3)
        assert median(x) == float(np.median(x))
    ticks = np.diff(np.arange(n + 1) * 0.001)      # a log's dt: ties everywhere
    assert median(ticks) == float(np.median(ticks))
