"""Battery/ESC electrical model: currents from shaft power, charge and heat bookkeeping."""

from __future__ import annotations

import math

import pytest

from sitl.power import PowerModel

D_M, K_F = 0.016, 8.0e-6       # paper scenario: drag/thrust ratio, thrust coefficient
HOVER_N = 1.1 * 9.81 / 4


def model() -> PowerModel:
    return PowerModel(drag_thrust_ratio_m=D_M, k_f=K_F)


def test_current_is_shaft_power_over_efficiency_and_voltage():
    pm = model()
    w = math.sqrt(HOVER_N / K_F)
    s = pm.step([w] * 4, 0.0)               # dt = 0: the full-pack voltage is used
    shaft_w = D_M * HOVER_N * w              # τ ω with τ = d f
    assert s.currents_a[0] == pytest.approx(shaft_w / (0.7 * 16.8) + 0.2)
    assert s.voltage_v == pytest.approx(16.8 - 0.02 * s.total_current_a)
    assert 1.5 < s.currents_a[0] < 4.0       # a few amps per ESC at hover: plausible


def test_stopped_rotor_draws_nothing_and_stays_at_ambient():
    pm = model()
    for _ in range(100):
        s = pm.step([0.0, 600.0, 600.0, 600.0], 0.1)
    assert s.currents_a[0] == 0.0
    assert s.temperatures_c[0] == 25.0
    assert s.temperatures_c[1] > 25.0


def test_charge_and_temperature_integrate_on_sim_time():
    pm = model()
    w = math.sqrt(HOVER_N / K_F)
    dt, n = 0.01, 6000                        # 60 s
    currents = []
    for _ in range(n):
        s = pm.step([w] * 4, dt)
        currents.append(s.currents_a[0])
    expected_mah = sum(currents) * dt / 3.6
    assert s.consumed_mah[0] == pytest.approx(expected_mah, rel=1e-9)
    assert s.remaining_pct == pytest.approx(100 * (1 - 4 * expected_mah / 5000), rel=1e-9)
    # After three thermal time constants the ESC is within 5 % of its settling temperature.
    settle = 25.0 + 3.0 * currents[-1]
    assert s.temperatures_c[0] == pytest.approx(settle, abs=0.05 * (settle - 25.0) + 0.05)
