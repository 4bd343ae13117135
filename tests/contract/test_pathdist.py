"""path_distances gives, to the bit, the distances successive PathTracker.evaluate calls
give (what the log readers used before), on the compiled σ and on the reference jets."""

from __future__ import annotations

import math
import random

import pytest

from tfl_mav.control.path.paths import PathTracker
from tfl_mav.flightlog import pathdist
from tfl_mav.from_scenario import scenario_path
from tfl_mav.scenario import load_scenario


def _positions(seed: int) -> list[list[float]]:
    """A wandering walk near the paper path, with NaN samples and jumps far away."""
    rnd = random.Random(seed)
    out, lam = [], 0.0
    for k in range(1500):
        lam += 0.002
        p = [lam + rnd.gauss(0, 0.05), math.cos(lam) + rnd.gauss(0, 0.05),
             8 - 4 * math.cos(lam) + rnd.gauss(0, 0.05)]
        if k % 400 == 7:
            p[1] = math.nan
        if k % 611 == 100:
            p = [p[0] + 3.0, p[1] - 2.0, p[2] + 1.0]
        out.append(p)
    return out


def _reference(path, positions):
    tr = PathTracker(path)
    return [tr.evaluate([[c, 0.0, 0.0, 0.0, 0.0] for c in p]).distance_m for p in positions]


@pytest.mark.parametrize("compiled", [True, False])
def test_the_same_distances_as_the_tracker(compiled: bool) -> None:
    path = scenario_path(load_scenario("paper"))
    pos = _positions(1)
    ref, ours = _reference(path, pos), pathdist.path_distances(path, pos, compiled=compiled)
    assert len(ours) == len(ref)
    assert all(a == b or (math.isnan(a) and math.isnan(b)) for a, b in zip(ours, ref,
                                                                           strict=True))
    assert sum(math.isnan(d) for d in ours) >= 3
