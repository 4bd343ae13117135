"""Motor lag: the deadbeat lag inverse against the simulator's own motors, the
allocation under per-rotor bounds, and the law with and without lag."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from tfl_mav.control.actuators import (
    LAG_START,
    MotorLagInverter,
    lag_invert,
    lag_params,
    lag_reachable,
)
from tfl_mav.control.allocation import allocate_attacked, allocate_nominal
from tfl_mav.from_scenario import build_controller
from tfl_mav.offline import fly_offline
from tfl_mav.scenario import load_scenario
from tfl_mav.sitl.motors import MotorBank

KF = 8.0e-6
FMAX = 8.0
DT = 0.001


def _bank(tau_s: float, thrust_n: list[float]) -> MotorBank:
    return MotorBank(KF, FMAX, tau_s, thrust_n)


def test_deadbeat_reaches_a_reachable_target_in_one_period_exactly():
    """The command puts the simulator's rotor on the target at the end of the period."""
    tau = 0.02
    bank = _bank(tau, [2.0, 2.5, 3.0, 2.7])
    inv = MotorLagInverter(KF, FMAX, tau, DT, lead_periods=0.0)
    demand = [2.1, 2.4, 3.05, 2.75]
    lo, hi = inv.reachable(bank.omega_radps)
    assert all(lo[i] <= demand[i] <= hi[i] for i in range(4))
    res = inv.invert(demand)
    assert not any(res.clamped)
    mean = bank.step([math.sqrt(c / KF) for c in res.command_n], DT)
    assert bank.thrust_n == pytest.approx(demand, rel=1e-12)
    # The controller's prediction of the delivered thrust is the simulator's, exactly.
    assert res.expected_mean_n == pytest.approx(mean, rel=1e-12)


def test_lead_makes_the_mean_thrust_that_of_the_continuous_time_law():
    """With one period of lead a ramping demand is delivered as the continuous law would
    deliver it: the mean over [t_k, t_k + h] is the demand at mid-period, f_d[k] + Δ/2, to
    the curvature of f = k_f ω² across one period (≪ 1e-4 N for a 20 N/s ramp)."""
    tau = 0.02
    bank = _bank(tau, [2.0] * 4)
    inv = MotorLagInverter(KF, FMAX, tau, DT)
    errors = []
    for k in range(50):
        demand = [2.0 + 0.02 * k] * 4     # 20 N/s ramp
        inv.reachable(bank.omega_radps)
        res = inv.invert(demand)
        mean = bank.step([math.sqrt(c / KF) for c in res.command_n], DT)
        if k >= 2:
            errors.append(abs(mean[0] - (demand[0] + 0.01)))
    assert max(errors) < 1e-4
    # Without the inverse the same ramp lags by τ: 0.02 s × 20 N/s = 0.4 N.
    assert 1000 * max(errors) < 0.02 * 20.0


@pytest.mark.parametrize("scale", [0.8, 1.2])
def test_inverse_with_tau_off_by_20_percent_converges_geometrically(scale):
    """Model τ = scale × true τ: each period's error is multiplied by about 1 − scale."""
    tau_true = 0.02
    bank = _bank(tau_true, [1.0] * 4)
    inv = MotorLagInverter(KF, FMAX, tau_true * scale, DT, lead_periods=0.0)
    target = [1.3] * 4
    errs = []
    for _ in range(6):
        inv.reachable(bank.omega_radps)
        res = inv.invert(target)
        bank.step([math.sqrt(c / KF) for c in res.command_n], DT)
        errs.append(abs(bank.thrust_n[0] - target[0]))
    assert errs[-1] < 1e-4          # from 0.3 N: |1 − s|⁶ · 0.3 N ≈ 2e-5 N
    for a, b in itertools.pairwise(errs):
        assert b <= 0.3 * a + 1e-12


def test_a_stopped_rotor_can_only_gain_a_little_thrust_per_period():
    """f ∝ ω²: from ω = 0 one period reaches k_f (ω_max (1 − e^{−h/τ}))² ≈ 0.019 N at 20 ms."""
    inv = MotorLagInverter(KF, FMAX, 0.02, DT, lead_periods=0.0)
    lo, hi = inv.reachable([0.0, 500.0, 500.0, 500.0])
    wmax = math.sqrt(FMAX / KF)
    assert hi[0] == pytest.approx(KF * (wmax * (1 - math.exp(-DT / 0.02))) ** 2, rel=1e-12)
    assert lo[0] == 0.0
    res = inv.invert([2.0, 2.0, 2.0, 2.0])
    assert res.clamped[0] and res.command_n[0] == pytest.approx(FMAX)


def test_no_measurement_falls_back_to_the_inverters_own_model():
    inv = MotorLagInverter(KF, FMAX, 0.02, DT)
    bank = _bank(0.02, [2.0] * 4)
    for k in range(20):
        demand = [2.0 + 0.01 * k, 2.0, 2.0, 2.0 - 0.01 * k]
        inv.reachable(None if k else bank.omega_radps)
        res = inv.invert(demand)
        bank.step([math.sqrt(c / KF) for c in res.command_n], DT)
    assert bank.thrust_n[0] == pytest.approx(2.0 + 0.01 * 20, abs=2e-3)


def test_nan_measurement_never_reaches_a_command():
    inv = MotorLagInverter(KF, FMAX, 0.02, DT)
    inv.reachable([math.nan, 500.0, math.inf, 500.0])
    res = inv.invert([2.0] * 4)
    assert all(math.isfinite(c) and 0.0 <= c <= FMAX for c in res.command_n)


def test_zero_time_constant_is_refused():
    with pytest.raises(ValueError, match="time_constant_s"):
        MotorLagInverter(KF, FMAX, 0.0, DT)


def test_bounded_allocation_keeps_thrust_and_pitch_torque_and_gives_up_roll():
    """Rotor 4 pinned near zero (a stopped, lagging motor): u_f and τ_q are kept exact."""
    lo = (0.0, 0.0, 0.0, 0.0)
    hi = (8.0, 8.0, 8.0, 0.02)
    f = allocate_attacked(10.0, 0.1, -0.5, 0.0, 0.2656, 0.016, 8.0, (lo, hi))
    assert f[3] <= 0.02 + 1e-12
    assert sum(f) == pytest.approx(10.0, abs=1e-12)
    assert 0.2656 * (f[2] - f[0]) == pytest.approx(0.1, abs=1e-12)


def test_bounds_equal_to_the_limits_change_nothing():
    """The bounded allocations reduce to the [0, f_max] ones (τ_m = 0 flies bit for bit)."""
    bounds = ((0.0,) * 4, (FMAX,) * 4)
    for args in ((11.0, 0.3, -0.2, 0.05), (3.0, -0.9, 0.4, 0.2), (30.0, 0.0, 0.1, -0.3)):
        assert allocate_nominal(*args, 0.2656, 0.016, FMAX, bounds) == \
            allocate_nominal(*args, 0.2656, 0.016, FMAX)
    for args in ((11.0, 0.3, -0.2, 0.05), (3.0, -0.9, 0.4, 0.0), (20.0, 0.1, 2.0, 7.9)):
        assert allocate_attacked(*args, 0.2656, 0.016, FMAX, bounds) == \
            allocate_attacked(*args, 0.2656, 0.016, FMAX)


def test_zero_lag_flies_without_an_inverter():
    """With ``motor_time_constant_s = 0`` the controller builds no lag inverter, so the lag
    work cannot change an ideal-motor flight: scaling the controller's τ_m (0 × anything)
    flies bit for bit the same. (Whole-flight goldens: tests/golden/test_golden.py.)"""
    sc = load_scenario("paper").replace(**{"vehicle.rpm_noise_std": 20.0,
                                           "sensors.rate_noise_std_radps": 0.005})
    assert build_controller(sc).lag_inverter is None
    a = fly_offline(sc, attack_info="detector", duration_s=1.0)
    b = fly_offline(sc.replace(**{"controller.motor_time_constant_scale": 2.0}),
                    attack_info="detector", duration_s=1.0)
    assert np.array_equal(a["position_m"], b["position_m"])
    assert np.array_equal(a["thrust_cmd_n"], b["thrust_cmd_n"])


@pytest.mark.slow
def test_lag_unaware_law_flips_and_the_lag_aware_law_does_not():
    """τ_m = 20 ms under the paper's attack: ignoring the lag flips the vehicle within
    8 s (measured 4.6 s, the safe law flying a lag it does not know; 1.7 s before the TFL
    tick allowed for the yaw spin); inverting it keeps the vehicle upright and closing in."""
    sc = load_scenario("paper").replace(**{"vehicle.motor_time_constant_s": 0.02})
    blind = fly_offline(sc.replace(**{"controller.motor_time_constant_scale": 0.0}),
                        duration_s=8.0)
    assert blind.crashed  # flipped, or (the safe law took over too late) hit the ground
    aware = fly_offline(sc, attack_info="detector", duration_s=8.0)
    assert not aware.crashed
    d = aware.data["path_distance_m"]
    assert d[-1] < 0.5 * d[0]


def test_the_inverse_is_two_pure_steps_the_holder_only_keeps():
    """The same (params, state, input) give the same result, the state given is unchanged,
    and the holder's answers are the pure steps' over the state it keeps; with ESC noise the
    measured speed goes through a Kalman gain below 1."""
    p = lag_params(KF, FMAX, 0.02, DT, rpm_std=100.0)
    assert 0.0 < p.kalman < 1.0
    inv = MotorLagInverter(KF, FMAX, 0.02, DT)
    inv.set_rpm_noise(100.0)
    s = LAG_START
    rng = np.random.default_rng(4)
    for _ in range(50):
        omega = tuple(float(w) for w in rng.uniform(300.0, 900.0, 4))
        demand = tuple(float(f) for f in rng.uniform(0.0, FMAX, 4))
        before = repr(s)
        a, b = lag_reachable(p, s, omega), lag_reachable(p, s, omega)
        assert repr(a) == repr(b) and repr(s) == before
        s, lo, hi = a
        assert all(0.0 <= x <= y <= FMAX for x, y in zip(lo, hi, strict=True))
        assert (lo, hi) == inv.reachable(omega)
        s, out = lag_invert(p, s, demand)
        held = inv.invert(demand)
        assert (out.command_n, out.expected_mean_n, out.clamped) == \
            (held.command_n, held.expected_mean_n, held.clamped)
        assert repr(s) == repr(inv.state)

