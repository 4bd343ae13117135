"""The hand-back's thrust rate: the trend of the safe law's thrust, and TFL resuming from it
(control/tfl/thrust_trend.py, TFLController.resume)."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest

from tfl_mav.control.tfl.thrust_trend import TREND_TAU_S, thrust_trend
from tfl_mav.from_scenario import build_controller
from tfl_mav.model.state import State
from tfl_mav.scenario import load_scenario


@pytest.mark.parametrize("dt", [0.001, 0.002, 0.004])
def test_the_trend_reads_a_ramp_exactly_at_any_rate(dt):
    trend = None
    for k in range(round(0.5 / dt)):
        trend = thrust_trend(trend, 10.0 + 1.7 * k * dt, dt)
    assert trend.rate_nps == pytest.approx(1.7, rel=1e-7)


def test_the_trend_averages_the_noise_of_a_law_s_tick_to_tick_thrust():
    """0.05 N of white noise a tick at 500 Hz: a difference of two ticks scatters by 35 N/s;
    the trend's rate by about σ √(dt/τ³)/2 ≈ 0.4 N/s about the true 1 N/s."""
    rng = random.Random(3)
    dt, rates = 0.002, []
    trend = None
    for k in range(5000):
        trend = thrust_trend(trend, 10.0 + 1.0 * k * dt + rng.gauss(0.0, 0.05), dt)
        if k > 100:
            rates.append(trend.rate_nps)
    rates = np.array(rates)
    assert abs(rates.mean() - 1.0) < 0.1
    assert rates.std() < 0.6 * 0.05 * math.sqrt(dt / TREND_TAU_S ** 3)
    assert thrust_trend(None, 10.0, dt).rate_nps == 0.0     # no rate before two samples


def _state(pos=(1.5, 0.3, 0.5), vel=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0)):
    return State(pos, vel, (1.0, 0.0, 0.0, 0.0), w)


def _resumed_first_tick(thrust, rate):
    ctrl = build_controller(load_scenario("paper"))
    ctrl.set_attack(2, 1.0)
    ctrl.update(_state())
    ctrl.resume(thrust, None, rate)
    assert ctrl.x13 == pytest.approx(sum(thrust)) and ctrl.x14 == rate
    return ctrl.update(_state(pos=(1.5, 0.302, 0.5), w=(0.05, -0.03, 20.0)))


def test_tfl_resumes_at_the_thrust_and_its_rate():
    """The rate goes into the chain's jerk and nowhere else on the first tick: α⃛ moves by
    what the same step of thrust moves α̈ (both are (Δ/m)·b3 across the path), α̈ not at all."""
    thrust = [3.0, 1.0, 3.0, 3.0]
    base = _resumed_first_tick(thrust, 0.0)
    turning = _resumed_first_tick(thrust, 0.5)                    # +0.5 N/s
    more = _resumed_first_tick([3.5, 1.0, 3.0, 3.0], 0.0)         # +0.5 N
    for i in (0, 1):
        assert turning.xi[i][2] == pytest.approx(base.xi[i][2], abs=1e-12)
        assert turning.xi[i][3] - base.xi[i][3] == pytest.approx(
            more.xi[i][2] - base.xi[i][2], rel=1e-4)
    assert max(abs(turning.xi[0][3] - base.xi[0][3]), abs(turning.xi[1][3] - base.xi[1][3])) > 0
