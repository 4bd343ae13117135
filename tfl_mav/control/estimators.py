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

__all__ = ["MassEstimator", "RateDisturbanceObserver"]


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
        # Unrolled over x, y, z (runs every tick); same operations as the vector form.
        tau_dt = self.accel_tau_s + dt
        a = dt / tau_dt
        vx, vy, vz = velocity_mps
        lx, ly, lz = self._v_lp
        dx, dy, dz = vx - lx, vy - ly, vz - lz
        # Filtered acceleration = (v − LP(v))/τ is LP(v̇); the regressor gets the same LP.
        ax, ay, az = dx / tau_dt, dy / tau_dt, dz / tau_dt
        self._v_lp = (lx + a * dx, ly + a * dy, lz + a * dz)
        kt = self.k_t
        bx, by, bz = b3
        px, py, pz = self._phi_lp
        px = px + a * (thrust_n * bx - kt * vx - px)
        py = py + a * (thrust_n * by - kt * vy - py)
        pz = pz + a * (thrust_n * bz - kt * vz - pz)
        self._phi_lp = (px, py, pz)
        az += self.g
        den = ax ** 2 + ay ** 2 + az ** 2
        if not self._min_den <= den < math.inf:
            return self.mass_kg  # free fall or nonsense: nothing to learn from
        m_inst = (px * ax + py * ay + pz * az) / den
        mass = self.mass_kg
        if not -math.inf < m_inst < math.inf:
            return mass
        m = mass + dt / (self.ratio_tau_s + dt) * (m_inst - mass)
        lo, hi = self.lo, self.hi
        m = lo if lo > m else m          # min(max(m, lo), hi) written out
        self.mass_kg = hi if hi < m else m
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
        d = self.d_p
        d += a * ((p - prev[0]) / dt - pdot_pred - d)
        d = -lim if -lim > d else d      # min(max(d, −lim), lim) written out
        self.d_p = lim if lim < d else d
        d = self.d_q
        d += a * ((q - prev[1]) / dt - qdot_pred - d)
        d = -lim if -lim > d else d
        self.d_q = lim if lim < d else d
