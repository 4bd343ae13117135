"""Battery/ESC electrical model: currents from shaft power, charge and heat bookkeeping."""

from __future__ import annotations

import math

import pytest

from tfl_mav.sitl.power import EXAMPLE, PowerModel, power_step

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


def test_power_step_compiled_is_the_python_step_bit_for_bit():
    """tfl_mav.sitl.power's per-tick arithmetic compiled (tfl_mav.accel.native) gives the Python
    step's numbers to the bit (repr: -0.0 and NaN too), on random and non-finite inputs; a
    division by zero declines (None), so the Python step raises as before."""
    import random

    from tfl_mav.accel import native
    core = native.build_function(power_step, EXAMPLE)
    rng = random.Random(7)
    special = [0.0, -0.0, 1e-300, -1.0, math.nan, math.inf, 1e308]

    def v(lo: float, hi: float) -> float:
        return rng.choice(special) if rng.random() < 0.05 else rng.uniform(lo, hi)

    for _ in range(20000):
        args = ([v(-100.0, 3000.0) for _ in range(4)], tuple(v(0.0, 6000.0) for _ in range(4)),
                tuple(v(-20.0, 200.0) for _ in range(4)), v(-1.0, 17.0), D_M * K_F, 0.7, 0.2,
                1.0 / 3600.0, math.exp(-1e-3 / 20.0), 25.0, 3.0, 5000.0, 14.0, 16.8, 0.02)
        assert repr(core(*args)) == repr(power_step(*args))
    zero = ([1.0] * 4, (0.0,) * 4, (25.0,) * 4, 16.8, D_M * K_F, 0.0, 0.2, 1.0 / 3600.0,
            1.0, 25.0, 3.0, 5000.0, 14.0, 16.8, 0.02)
    assert core(*zero) is None
    with pytest.raises(ZeroDivisionError):
        power_step(*zero)
