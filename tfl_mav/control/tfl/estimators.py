"""Online estimators that make the paper's law robust to model error (going past §VI).

Measured in a prototype (controller issue): with the paper's 2 % mass / 10 % inertia error
the plain law sits 6–7 cm off the path or crashes. Two estimators remove the two biases:

* :class:`MassEstimator` — the mass error biases α and the speed. Newton's law along the
  thrust direction, m (a + g i3) = u_f b3 − k_t v, is regressed with the acceleration taken
  from the velocity through a first-order filter (τ ≈ 0.2 s) and the regressor passed
  through the *same* filter, so both sides carry the same lag; the ratio is low-passed
  (τ ≈ 1 s) and clamped to a band around the nominal model.
* :class:`RateDisturbanceObserver` — the inertia error (and anything else: unmodelled
  torques, a wrong attack estimate) shows up as a mismatch between the measured ṗ, q̇ and
  the model's prediction for the torque actually applied. A fast (τ ≈ 4 ms) filtered
  difference estimates it; the law subtracts it from its p/q acceleration demand (INDI-like).
  A slower filter lags the ~60 rad/s yaw spin under attack by tens of degrees and crashes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

__all__ = ["MassEstimator", "RateDisturbanceObserver", "clamp", "dob_step", "mass_blend",
           "mass_filters"]

V3 = Sequence[Any]


def clamp(x: float, lo: float, hi: float) -> float:
    """``min(max(x, lo), hi)`` written out (the same result, NaN and ties included)."""
    x = lo if lo > x else x
    return hi if hi < x else x


def mass_filters(dt: Any, tau_s: Any, kt: Any, g: Any, v: V3, thrust: Any, b3: V3,
                 v_lp: V3, phi_lp: V3) -> tuple[Any, ...]:
    """One step of :class:`MassEstimator`'s two first-order filters (arithmetic only, so
    that :mod:`fused` traces the same operations): (LP(v) ×3, LP(φ) ×3, numerator and
    denominator of the instantaneous mass (LP(φ)·â / |â|², â = LP(v̇) + g e3))."""
    tau_dt = tau_s + dt
    a = dt / tau_dt
    vx, vy, vz = v
    lx, ly, lz = v_lp
    dx, dy, dz = vx - lx, vy - ly, vz - lz
    # Filtered acceleration = (v − LP(v))/τ is LP(v̇); the regressor gets the same LP.
    ax, ay, az = dx / tau_dt, dy / tau_dt, dz / tau_dt
    bx, by, bz = b3
    px, py, pz = phi_lp
    px = px + a * (thrust * bx - kt * vx - px)
    py = py + a * (thrust * by - kt * vy - py)
    pz = pz + a * (thrust * bz - kt * vz - pz)
    az = az + g
    return (lx + a * dx, ly + a * dy, lz + a * dz, px, py, pz,
            px * ax + py * ay + pz * az, ax ** 2 + ay ** 2 + az ** 2)


def mass_blend(mass: Any, m_inst: Any, dt: Any, ratio_tau_s: Any) -> Any:
    """The mass estimate low-passed towards the instantaneous one (before its clamp)."""
    return mass + dt / (ratio_tau_s + dt) * (m_inst - mass)


def dob_step(d: Any, rate: Any, rate_prev: Any, pred: Any, dt: Any, a: Any) -> Any:
    """:class:`RateDisturbanceObserver`'s filter on one axis, before its clamp."""
    return d + a * ((rate - rate_prev) / dt - pred - d)


class MassEstimator:
    """Estimate the vehicle mass (kg) from velocity and the applied total thrust (N)."""

    def __init__(self, model_mass_kg: float, gravity_mps2: float, k_t: float,
                 accel_tau_s: float = 0.2, ratio_tau_s: float = 1.0, band: float = 0.2,
                 min_excitation: float = 0.5) -> None:
        self.model_mass_kg = model_mass_kg
        self.mass_kg = model_mass_kg
        self.g = gravity_mps2
        self.k_t = k_t
        self.accel_tau_s = accel_tau_s
        self.ratio_tau_s = ratio_tau_s
        self.lo = model_mass_kg * (1.0 - band)
        self.hi = model_mass_kg * (1.0 + band)
        self.min_excitation = min_excitation
        self._min_den = min_excitation ** 2
        self._v_lp: tuple[float, ...] | None = None
        self._phi_lp: tuple[float, ...] = (0.0, 0.0, 0.0)
        self._g_lp = 0.0
        self.updates = 0

    def update(self, dt: float, velocity_mps: Sequence[float], thrust_n: float,
               b3: Sequence[float]) -> float:
        """Advance by ``dt`` s; returns the current mass estimate (kg)."""
        if self._v_lp is None:
            self._v_lp = tuple(velocity_mps)
            self._phi_lp = tuple(thrust_n * b - self.k_t * v
                                 for b, v in zip(b3, velocity_mps, strict=True))
            self._g_lp = self.g
            return self.mass_kg
        lx, ly, lz, px, py, pz, num, den = mass_filters(dt, self.accel_tau_s, self.k_t, self.g,
                                                        velocity_mps, thrust_n, b3, self._v_lp,
                                                        self._phi_lp)
        self._v_lp = (lx, ly, lz)
        self._phi_lp = (px, py, pz)
        if not self._min_den <= den < math.inf:
            return self.mass_kg  # free fall or nonsense: nothing to learn from
        m_inst = num / den
        mass = self.mass_kg
        if not -math.inf < m_inst < math.inf:
            return mass
        self.mass_kg = clamp(mass_blend(mass, m_inst, dt, self.ratio_tau_s), self.lo, self.hi)
        self.updates += 1
        return self.mass_kg


class RateDisturbanceObserver:
    """Filtered estimate of (measured − predicted) ṗ, q̇ in rad/s² (canonical body axes)."""

    def __init__(self, tau_s: float = 0.004, limit_radps2: float = 500.0) -> None:
        self.tau_s = tau_s
        self.limit = limit_radps2
        self.d_p = 0.0
        self.d_q = 0.0
        self._prev: tuple[float, float] | None = None

    def reset(self) -> None:
        self.d_p = self.d_q = 0.0
        self._prev = None

    def update(self, dt: float, p: float, q: float, pdot_pred: float, qdot_pred: float) -> None:
        """Feed the rates measured now and the model's ṗ, q̇ for the command just applied."""
        prev = self._prev
        self._prev = (p, q)
        if prev is None:
            return
        a = dt / (self.tau_s + dt)
        lim = self.limit
        self.d_p = clamp(dob_step(self.d_p, p, prev[0], pdot_pred, dt, a), -lim, lim)
        self.d_q = clamp(dob_step(self.d_q, q, prev[1], qdot_pred, dt, a), -lim, lim)
