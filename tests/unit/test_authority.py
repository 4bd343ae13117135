"""The authority monitor: the share of recent ticks a healthy rotor was pinned at a bound."""

from __future__ import annotations

import math

import pytest

from tfl_mav.control.safe.authority import LOST_SHARE, WINDOW_S, AuthorityMonitor

DT_S = 0.001
FREE = (2.0, 2.0)   # side rotors well inside [0, f_max]


def _ticks_to_lose(mon: AuthorityMonitor, f_opp: float, side=FREE, limit: int = 5000) -> int:
    for k in range(1, limit + 1):
        if mon.update(f_opp, *side, DT_S):
            return k
    return -1


def test_sustained_pinning_is_lost_after_the_first_order_time():
    """A first-order average of a 0/1 indicator crosses s after −τ ln(1 − s): 0.139 s for
    τ = 0.2 s, s = 0.5 (within one tick)."""
    mon = AuthorityMonitor(8.0)
    n = _ticks_to_lose(mon, 0.0)
    expected = -WINDOW_S * math.log(1.0 - LOST_SHARE) / DT_S
    assert abs(n - expected) <= 1.5
    assert mon.bound == "floor"


def test_short_or_intermittent_pinning_keeps_authority():
    """50 ms pinned, or pinned on 40 % of the ticks for ever (the paper's A = 0 stretch is
    pinned about half the time): the share never exceeds one half."""
    mon = AuthorityMonitor(8.0)
    for _ in range(50):
        assert not mon.update(0.0, *FREE, DT_S)
    for _ in range(200):
        mon.update(1.0, *FREE, DT_S)
    for k in range(5000):
        assert not mon.update(0.0 if k % 5 < 2 else 1.0, *FREE, DT_S)


@pytest.mark.parametrize(("f_opp", "side", "bound"), [
    (8.0, FREE, "ceiling"),            # f₄ at f_max
    (3.0, (0.0, 2.0), "ceiling"),      # a side rotor at 0: A too large
    (3.0, (2.0, 8.0), "floor"),        # a side rotor at f_max
])
def test_every_healthy_rotor_counts(f_opp, side, bound):
    mon = AuthorityMonitor(8.0)
    assert _ticks_to_lose(mon, f_opp, side) > 0
    assert mon.bound == bound


def test_reset_and_bad_periods():
    mon = AuthorityMonitor(8.0)
    _ticks_to_lose(mon, 0.0)
    mon.reset()
    assert not mon.lost and mon.share == 0.0
    for dt in (math.nan, -1.0, 0.0):
        mon.update(0.0, *FREE, dt)
    assert mon.share == 0.0
    mon.update(0.0, *FREE, 10.0)          # a long gap counts as one whole window
    assert mon.share == 1.0


@pytest.mark.parametrize("kw", [{"thrust_max_n": 0.0}, {"thrust_max_n": 8.0, "window_s": 0.0},
                                {"thrust_max_n": 8.0, "lost_share": 1.0}])
def test_bad_configuration_is_one_clear_error(kw):
    with pytest.raises(ValueError, match="AuthorityMonitor"):
        AuthorityMonitor(**kw)
