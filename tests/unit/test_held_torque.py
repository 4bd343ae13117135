"""The TFL law's tick under a fast yaw spin: a torque held over the tick
(:func:`law_math.held_rate_command`) and the rate disturbance observer carried in the yaw-free
frame (:func:`estimators.dob_update`).

Under attack the yaw is internal dynamics and spins at 20-60 rad/s, so the body turns by
r·dt = 0.02-0.06 rad under one 1 kHz command. The bounds below come from Euler's equations
integrated finely over one tick, not from the law's flights.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tfl_mav.control.tfl.estimators import DOB_START, dob_update
from tfl_mav.control.tfl.law_math import held_rate_command, torques

_I = (0.0020066, 0.0020038, 0.0013323)     # the paper's J (kg m²)
_KR = 2.75e-3                               # rotational drag (N m s/rad)
_DT = 1e-3


def _euler_tick(rates: tuple[float, float, float], tau: tuple[float, float, float],
                dt: float, n: int = 400) -> np.ndarray:
    """(p, q, r) after ``dt`` s of eq. (3)'s rotational dynamics under a held torque (RK4)."""
    ix, iy, iz = _I

    def f(w: np.ndarray) -> np.ndarray:
        p, q, r = w
        return np.array([(tau[0] - (iz - iy) * q * r - _KR * p) / ix,
                         (tau[1] - (ix - iz) * p * r - _KR * q) / iy,
                         (tau[2] - (iy - ix) * p * q - _KR * r) / iz])

    w, h = np.array(rates, dtype=float), dt / n
    for _ in range(n):
        k1 = f(w)
        k2 = f(w + 0.5 * h * k1)
        k3 = f(w + 0.5 * h * k2)
        k4 = f(w + h * k3)
        w = w + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return w


def _tick_mean_error(pdot: float, qdot: float, rates: tuple[float, float, float],
                     held: bool) -> float:
    """|mean (ṗ, q̇) the vehicle gets over one tick − the continuous law's mean| (rad/s²)."""
    p, q, r = rates
    cp, cq = held_rate_command(pdot, qdot, r, _DT, _I) if held else (pdot, qdot)
    ix, iy, iz = _I
    tau_p, tau_q = torques(cp, cq, p, q, r, ix, iy, iz, _KR)
    after = _euler_tick(rates, (tau_p, tau_q, _KR * r), _DT)
    got = (after[:2] - np.array([p, q])) / _DT
    # The law's (ṗ, q̇) aim at a direction fixed over the tick: in (b1, b2) they turn by
    # −r t, so their mean is the start value turned by −r dt/2 (times sinc(r dt/2)).
    a = r * _DT / 2.0
    k = math.sin(a) / a if a else 1.0
    want = k * np.array([math.cos(a) * pdot + math.sin(a) * qdot,
                         math.cos(a) * qdot - math.sin(a) * pdot])
    return float(np.hypot(*(got - want)))


@pytest.mark.parametrize("r", [20.0, 40.0, -60.0])
@pytest.mark.parametrize("rates_pq", [(0.0, 0.0), (0.3, -0.2)])
def test_held_command_gives_the_laws_mean_acceleration(r: float,
                                                       rates_pq: tuple[float, float]) -> None:
    pdot, qdot = 1.5, -0.8
    rates = (rates_pq[0], rates_pq[1], r)
    size = math.hypot(pdot, qdot)
    plain = _tick_mean_error(pdot, qdot, rates, held=False)
    held = _tick_mean_error(pdot, qdot, rates, held=True)
    # Held as computed, the tilt lags by (I_z/I) r dt/2: the gyroscopic terms turn a held
    # torque's acceleration by −(1 − I_z/I) r t, the law's turns by −r t.
    lag = _I[2] / (0.5 * (_I[0] + _I[1])) * abs(r) * _DT / 2.0
    assert plain == pytest.approx(lag * size, rel=0.15)
    # Turned by that angle, what is left is second order in r dt (and the (p, q) terms).
    assert held < 0.1 * plain


def test_zero_spin_leaves_the_command_alone() -> None:
    assert held_rate_command(1.5, -0.8, 0.0, _DT, _I) == (1.5, -0.8)


def _observe(d_body: np.ndarray, r: float, ticks: int) -> tuple[float, float]:
    """The observer's estimate after ``ticks``: the measured rates integrate a disturbance
    whose body components at tick k are ``d_body[k]`` (the model predicts no motion)."""
    s, p, q = DOB_START, 0.0, 0.0
    for k in range(ticks):
        s = dob_update(0.004, 100.0, s, _DT, p, q, r, 0.0, 0.0)
        p, q = p + _DT * d_body[k, 0], q + _DT * d_body[k, 1]
    s = dob_update(0.004, 100.0, s, _DT, p, q, r, 0.0, 0.0)
    return s.d_p, s.d_q


def test_observer_follows_a_disturbance_fixed_as_the_law_aims() -> None:
    """A disturbance fixed in the yaw-free frame (a share of the law's own (ṗ, q̇), as an
    inertia error gives) turns at −r in the body: it is estimated without the filter's lag,
    which at r = 40 rad/s and τ = 4 ms is atan(r τ) = 0.16 rad sideways."""
    r, n = 40.0, 300
    t = (np.arange(n) + 0.5) * _DT            # the tick's mid-point: what the rates integrate
    d = np.stack([np.cos(-r * t), np.sin(-r * t)], axis=1) * 2.0
    est = np.array(_observe(d, r, n))
    now = 2.0 * np.array([math.cos(-r * n * _DT), math.sin(-r * n * _DT)])
    angle = math.atan2(now[0] * est[1] - now[1] * est[0], float(now @ est))
    assert abs(angle) < 0.03
    assert np.hypot(*est) == pytest.approx(2.0, rel=0.02)


def test_observer_learns_a_steady_body_torque_without_spin() -> None:
    n = 300
    d = np.tile([0.7, -0.4], (n, 1))
    est = _observe(d, 0.0, n)
    assert est == pytest.approx((0.7, -0.4), abs=1e-6)
