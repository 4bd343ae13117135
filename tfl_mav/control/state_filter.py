"""Model-based state filter for the flight computer.

The TFL law differentiates the output four times; the measured velocity enters y' and the
rates enter y''' directly, and the law's rate-disturbance observer differences the rates
(÷ dt). White sensor noise is therefore amplified by the ξ/η gains and by 1/dt. The vehicle
model knows better: between two ticks the body obeys eq. (3) driven by the rotor thrusts
the ESCs report (f = k_f ω², which is also the attacked rotor's true thrust). So:

* :class:`StateFilter` — steady-state Kalman filters, one per axis:

  - translation, state (p, v, b): ṗ = v, v̇ = (u_f/m) b3 − g e3 − (k_t/m) v + b, where b is
    the unmodelled acceleration (mass error, drag error) as a random walk; measured p and v;
  - rotation, state (ω, d): ω̇ = J⁻¹(τ − k_r ω − ω × J ω) + d, d the unmodelled angular
    acceleration (inertia error, lag, attack-estimate error); measured ω.

  Process noise is the model-error budget (:data:`ACCEL_WHITE_MPS2` …), measurement noise
  the scenario's sensor standard deviations. Attitude is passed through (its noise is not
  the problem measured). The flight computer builds a filter only for the parts whose
  scenario noise is > 0: a noise-free flight never touches it (bit-identical).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from tfl_mav.control.tfl.law_types import ModelParams
from tfl_mav.model.geometry import rotation_rows
from tfl_mav.model.state import State

__all__ = ["StateFilter", "YawRateModel"]

# Model-error budget (process noise), white densities per √s:
ACCEL_WHITE_MPS2 = 0.3     # unmodelled acceleration: ESC-noise thrust (0.2 N/1.1 kg) + drag
BIAS_WALK_MPS3 = 2.0       # how fast the acceleration bias (mass error × thrust) may change
ANG_WHITE_RADPS2 = 5.0     # unmodelled angular acceleration: rotor-thrust noise × l / J
DIST_WALK_RADPS3 = 150.0
#                            gyroscopic terms at the attacked ~60 rad/s spin)
MEAS_FLOOR = 1e-5          # a noise-free measurement's σ (keeps the Riccati equation regular)


def _steady_gain(F: np.ndarray, H: np.ndarray, Q: np.ndarray, Rm: np.ndarray) -> np.ndarray:
    """Steady-state Kalman gain K for x⁺ = F x + w (Q), z = H x + v (Rm)."""
    P = np.eye(F.shape[0])
    for _ in range(20000):
        Pp = F @ P @ F.T + Q
        S = H @ Pp @ H.T + Rm
        K = Pp @ H.T @ np.linalg.inv(S)
        Pn = (np.eye(F.shape[0]) - K @ H) @ Pp
        if np.max(np.abs(Pn - P)) <= 1e-14 * max(1.0, float(np.max(np.abs(P)))):
            P = Pn
            break
        P = Pn
    Pp = F @ P @ F.T + Q
    return Pp @ H.T @ np.linalg.inv(H @ Pp @ H.T + Rm)


class StateFilter:
    """Fuse the measured state with the model prediction (see the module docstring)."""

    def __init__(self, model: ModelParams, dt_s: float, *, position_std_m: float,
                 velocity_std_mps: float, rate_std_radps: float, translation: bool,
                 rotation: bool) -> None:
        self.m = model
        self.dt = dt_s
        self.translation = translation
        self.rotation = rotation
        h = dt_s
        F = np.array([[1.0, h, 0.5 * h * h], [0.0, 1.0, h], [0.0, 0.0, 1.0]])
        Q = np.diag([1e-12, (ACCEL_WHITE_MPS2 * h) ** 2, BIAS_WALK_MPS3 ** 2 * h])
        H = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
        Rm = np.diag([max(position_std_m, MEAS_FLOOR) ** 2,
                      max(velocity_std_mps, MEAS_FLOOR) ** 2])
        self.k_t = _steady_gain(F, H, Q, Rm).tolist()        # 3×2: rows p, v, b
        F2 = np.array([[1.0, h], [0.0, 1.0]])
        Q2 = np.diag([(ANG_WHITE_RADPS2 * h) ** 2, DIST_WALK_RADPS3 ** 2 * h])
        H2 = np.array([[1.0, 0.0]])
        R2 = np.array([[max(rate_std_radps, MEAS_FLOOR) ** 2]])
        self.k_r = [float(k) for k in _steady_gain(F2, H2, Q2, R2)[:, 0]]   # ω, d
        self._p: list[float] | None = None
        self._v = [0.0, 0.0, 0.0]
        self._b = [0.0, 0.0, 0.0]
        self._w = [0.0, 0.0, 0.0]
        self._d = [0.0, 0.0, 0.0]

    def reset(self) -> None:
        self._p = None

    def update(self, state: State, thrust_n: Sequence[float], dt_s: float) -> State:
        """The filtered state at ``state``'s time; ``thrust_n``: the rotor thrusts (N, rotors
        1-4) that acted over the ``dt_s`` s since the last call."""
        y = [float(c) for c in state.position_m]
        v = [float(c) for c in state.velocity_mps]
        w = [float(c) for c in state.body_rates_radps]
        quat = state.quaternion_wxyz
        if self._p is None or not (dt_s > 0.0) or not all(
                math.isfinite(c) for c in (*y, *v, *w)):
            self._p, self._v, self._w = y, v, w
            self._b = [0.0, 0.0, 0.0]
            self._d = [0.0, 0.0, 0.0]
            return state
        h = dt_s
        m = self.m
        f1, f2, f3, f4 = thrust_n
        uf = f1 + f2 + f3 + f4
        R = rotation_rows(quat)
        out_p, out_v, out_w = y, v, w
        if self.translation:
            kt = self.k_t
            out_p, out_v = [], []
            for i in range(3):
                acc = uf / m.mass_kg * R[i][2] - m.k_t / m.mass_kg * self._v[i] + self._b[i]
                if i == 2:
                    acc -= m.gravity_mps2
                pp = self._p[i] + h * self._v[i] + 0.5 * h * h * acc
                vp = self._v[i] + h * acc
                ep, ev = y[i] - pp, v[i] - vp
                pn = pp + kt[0][0] * ep + kt[0][1] * ev
                vn = vp + kt[1][0] * ep + kt[1][1] * ev
                self._b[i] += kt[2][0] * ep + kt[2][1] * ev
                self._p[i], self._v[i] = pn, vn
                out_p.append(pn)
                out_v.append(vn)
        else:
            self._p, self._v = y, v
        if self.rotation:
            ix, iy, iz = m.inertia_kgm2
            ell, dd, kr = m.arm_m, m.drag_thrust_ratio_m, m.k_r
            tau = (ell * (f4 - f2), ell * (f3 - f1), dd * (f1 - f2 + f3 - f4))
            p, q, r = self._w
            acc_w = ((tau[0] - kr * p - (iz - iy) * q * r) / ix,
                     (tau[1] - kr * q - (ix - iz) * p * r) / iy,
                     (tau[2] - kr * r - (iy - ix) * p * q) / iz)
            k0, k1 = self.k_r
            out_w = []
            for i in range(3):
                wp = self._w[i] + h * (acc_w[i] + self._d[i])
                e = w[i] - wp
                self._w[i] = wp + k0 * e
                self._d[i] += k1 * e
                out_w.append(self._w[i])
        else:
            self._w = w
        return State(out_p, out_v, quat, out_w, state.time_usec)



class YawRateModel:
    """A yaw rate at the gyro's range is a lower bound, not a measurement: integrate
    ṙ = (τ_r − k_r r − (I_y − I_x) p q)/I_z (eq. (3)) from the ESC-reported thrusts
    (f = k_f ω²) instead, starting from the last unsaturated reading. The spin's steady value
    τ_r/k_r does not depend on the (uncertain) inertia."""

    def __init__(self, mp: ModelParams, k_f: float, gyro_range_radps: float) -> None:
        self.model = mp
        self.k_f = k_f
        self.range_radps = gyro_range_radps
        self._r_hat: float | None = None
        self.substituted_ticks = 0

    def update(self, state: State, omega: Sequence[float], dt: float,
               events: list[str]) -> State:
        """``state`` with its yaw rate replaced while the gyro is at its range (said once in
        ``events``); ``omega`` the rotor speeds (rad/s), ``dt`` the period (s)."""
        p, q, r = (float(c) for c in state.body_rates_radps)
        rng = self.range_radps
        if abs(r) < 0.99 * rng or not math.isfinite(r):
            self._r_hat = r
            return state
        m = self.model
        f1, f2, f3, f4 = (self.k_f * w * w for w in omega)
        ix, iy, iz = m.inertia_kgm2
        r_hat = r if self._r_hat is None else self._r_hat
        tau_r = m.drag_thrust_ratio_m * (f1 - f2 + f3 - f4)
        r_hat += dt * (tau_r - m.k_r * r_hat - (iy - ix) * p * q) / iz
        if r_hat * r <= 0.0 or abs(r_hat) < abs(r):
            r_hat = r                    # the true rate is at least what the gyro shows
        if self.substituted_ticks == 0:
            events.append(f"yaw rate at the gyro's range (±{rng:g} rad/s): using the "
                          "model's yaw-rate estimate while it is saturated")
        self.substituted_ticks += 1
        self._r_hat = r_hat
        return State(state.position_m, state.velocity_mps, state.quaternion_wxyz,
                     (p, q, r_hat), state.time_usec)
