"""The hand-back's arithmetic: the ξ chain's free response, the thrust trend, and the state
TFL would resume from (control/tfl/free_response.py, TFLController.preview/resume)."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest

from tfl_mav.control.tfl.free_response import (
    TREND_TAU_S,
    peak_distance_m,
    response_rows,
    thrust_trend,
)
from tfl_mav.control.tfl.tfl_controller import chain_gains
from tfl_mav.from_scenario import build_controller
from tfl_mav.model.state import State
from tfl_mav.scenario import load_scenario

ZERO = (0.0, 0.0, 0.0, 0.0)


@pytest.mark.parametrize("pole", [-2.5, -4.0])
def test_the_free_response_peaks_where_the_closed_forms_say(pole):
    """A quadruple pole at −λ: from an offset alone α decays monotonically (peak: the offset);
    from a jerk j alone α(t) = j t³/6 e^(−λt), which peaks at t = 3/λ."""
    lam = -pole
    k = chain_gains(pole, 4)
    assert peak_distance_m(k, ((2e-3, 0.0, 0.0, 0.0), ZERO)) == pytest.approx(2e-3, rel=1e-12)
    j = 0.5
    want = j * (3.0 / lam) ** 3 / 6.0 * math.exp(-3.0)
    assert peak_distance_m(k, (ZERO, (0.0, 0.0, 0.0, j))) == pytest.approx(want, rel=2e-3)


def test_the_peak_is_of_the_distance_across_both_directions():
    k = chain_gains(-4.0, 4)
    one = peak_distance_m(k, ((0.0, 0.0, 0.03, 0.0), ZERO))
    both = peak_distance_m(k, ((0.0, 0.0, 0.03, 0.0), (0.0, 0.0, 0.03, 0.0)))
    assert both == pytest.approx(math.sqrt(2.0) * one, rel=1e-12)
    # a state mid-correction: close to the path but accelerating across it
    assert peak_distance_m(k, ((1e-3, 0.0, 0.03, 0.0), ZERO)) > 2.2e-3


def test_a_state_with_no_number_has_no_peak_and_an_unstable_chain_is_refused():
    k = chain_gains(-4.0, 4)
    assert math.isnan(peak_distance_m(k, ((math.nan,) * 4, ZERO)))
    with pytest.raises(ValueError, match="not stable"):
        peak_distance_m((1.0, 0.0, 0.0, 0.0), ((1e-3, 0.0, 0.0, 0.0), ZERO))


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


def test_the_preview_is_what_tfl_sees_on_its_first_tick_after_the_resume_and_changes_nothing():
    ctrl = build_controller(load_scenario("paper"))
    ctrl.set_attack(2, 1.0)
    ctrl.update(_state())
    s = _state(pos=(1.5, 0.302, 0.5), vel=(0.01, -0.02, 0.0), w=(0.05, -0.03, 20.0))
    thrust, rate = [3.2, 1.0, 3.3, 2.9], 1.5
    before = ctrl.state
    xi = ctrl.preview(s, thrust, None, rate)
    assert ctrl.state == before
    ctrl.resume(thrust, None, rate)
    assert ctrl.x13 == pytest.approx(sum(thrust)) and ctrl.x14 == rate
    out = ctrl.update(s)
    assert np.allclose(np.array(out.xi), np.array(xi), rtol=0.0, atol=1e-12)


def test_the_preview_carries_the_thrust_and_its_rate_into_the_chain():
    """α̈ follows u_f/m and α⃛ follows u̇_f/m along b3's part across the path: the same
    change of thrust and of rate moves them in the same ratio (the lever is b3's)."""
    ctrl = build_controller(load_scenario("paper"))
    ctrl.set_attack(2, 1.0)
    ctrl.update(_state())
    s = _state()
    base = ctrl.preview(s, [3.0, 1.0, 3.0, 3.0], None, 0.0)
    more = ctrl.preview(s, [3.5, 1.0, 3.0, 3.0], None, 0.0)       # +0.5 N
    turning = ctrl.preview(s, [3.0, 1.0, 3.0, 3.0], None, 0.5)    # +0.5 N/s
    for i in (0, 1):
        d_acc = more[i][2] - base[i][2]
        d_jerk = turning[i][3] - base[i][3]
        assert d_jerk == pytest.approx(d_acc, rel=1e-4)
    assert max(abs(more[0][2] - base[0][2]), abs(more[1][2] - base[1][2])) > 0.0


def test_the_response_is_the_matrix_exponential_s():
    """The runtime's own exp (the library does not need scipy) against scipy's, row by row:
    e₁ᵀ exp(A t) over 10 time constants of the slowest pole."""
    from scipy.linalg import expm

    for pole in (-2.5, -4.0, -9.0):
        k = chain_gains(pole, 4)
        rows = response_rows(k)
        a = np.zeros((4, 4))
        a[0, 1] = a[1, 2] = a[2, 3] = 1.0
        a[3] = [-x for x in k]
        horizon = 10.0 / -float(np.max(np.linalg.eigvals(a).real))    # ≈ 10/|pole|
        for j in (0, 1, len(rows) // 3, len(rows) - 1):
            want = expm(a * (horizon * j / (len(rows) - 1)))[0]
            assert np.allclose(rows[j], want, rtol=1e-9, atol=1e-12)
