"""Inverting the rotors' first-order speed lag so the law's thrusts are the ones flown.

Model (the simulator's, and a fair first model of a brushless motor + ESC): each rotor speed
obeys dω/dt = (ω_c − ω)/τ_m with thrust f = k_f ω² and the command ω_c held over a control
period h. The paper's law assumes f follows its demand instantly. Under attack the vehicle
spins at ~60 rad/s, so the body-frame torques the law asks for rotate at ~10 Hz and a lag of
τ_m = 20 ms costs ~50° of phase: the law flips the vehicle within two seconds.

The ESC reports ω, so the lag can be inverted *per tick, in closed loop on the measured
speed*. Over one period the lag's exact solution is ω(t+h) = ω_c + (ω(t) − ω_c) e^{−h/τ}, so
the command that puts the rotor at ω* at the end of the period is

    ω_c = (ω* − e^{−h/τ} ω(t)) / (1 − e^{−h/τ})                      (deadbeat inverse)

Aiming the *end* of the period (not its mean) at the target is what keeps this stable: a
mean-matching inverse overshoots by 2× and rings at the Nyquist rate. The target is the
law's demand extrapolated one period ahead, f* = f_d[k] + (f_d[k] − f_d[k−1])
(``lead_periods`` = 1), so on a ramp the thrust runs from f_d[k] to f_d[k+1] over the
period: its mean is the demand at mid-period, what the continuous-time law of the paper
asks for (an ideal actuator held over the period lags that by h/2).

Feedback on the measured ω makes the inverse forgiving: with τ_m off by a factor s the
per-period error is multiplied by 1 − s (−0.2 … +0.2 for ±20 %), so it still converges in
a period or two, and rpm noise passes to the rotor speed about one-to-one instead of being
amplified by 1/(1 − e^{−h/τ}) ≈ τ/h. "About one-to-one" is still too much for ESC noise of
100 rpm (10 rad/s): the deadbeat command jumps by τ/h × that every period, and the vehicle
hits the ground within a second. So with noise (:meth:`set_rpm_noise`) the
speed the inverse closes on is a steady-state Kalman estimate ω̂ from the same motor model
and the command actually sent, ω̂ = ω̂⁻ + L (ω_meas − ω̂⁻), with a process noise of
``PROCESS_STD_RADPS`` per period (the model's own error: τ_m off by ~20 %); without noise
L = 1 and the measurement is used as before. Commands are clamped to [0, ω_max]; what the rotor will
really deliver over the period is returned so the law's estimators see the truth.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

__all__ = ["PROCESS_STD_RADPS", "LagInversion", "MotorLagInverter"]

PROCESS_STD_RADPS = 1.0   # per-period model error of ω (rad/s): 20 % of a 5 rad/s step


@dataclass
class LagInversion:
    """One period's result (physical rotor order, N)."""

    command_n: list[float]        # what to send: thrust whose steady ω is the command ω_c
    expected_mean_n: list[float]  # model's mean thrust over the period for that command
    clamped: list[bool]           # ω_c hit 0 or ω_max: the target is out of reach this period


class MotorLagInverter:
    """Deadbeat inverse of a first-order rotor-speed lag, closed on the measured speed."""

    def __init__(self, k_f: float, thrust_max_n: float, time_constant_s: float, dt_s: float,
                 *, lead_periods: float = 1.0) -> None:
        if not time_constant_s > 0.0:
            raise ValueError(f"time_constant_s must be > 0 (got {time_constant_s}); "
                             "with no lag there is nothing to invert")
        self.k_f = k_f
        self.thrust_max_n = thrust_max_n
        self.time_constant_s = time_constant_s
        self.dt_s = dt_s
        self.lead_periods = lead_periods
        self.omega_max_radps = math.sqrt(thrust_max_n / k_f)
        e1 = math.exp(-dt_s / time_constant_s)
        self._e1 = e1
        self._gain = 1.0 / (1.0 - e1)
        self._m1 = time_constant_s * (1.0 - e1) / dt_s            # mean of e^{−t/τ}
        self._m2 = time_constant_s * (1.0 - e1 * e1) / (2.0 * dt_s)  # mean of e^{−2t/τ}
        self._prev_demand: list[float] | None = None
        self._omega_model: list[float] | None = None
        self._omega: list[float] | None = None   # latched by reachable() for invert()
        self.gain = 1.0                            # Kalman gain on measured ω (1 = trust it)

    def set_rpm_noise(self, rpm_std: float) -> None:
        """ESC noise (rpm std): filter the measured speed with the steady Kalman gain."""
        if not rpm_std > 0.0:
            self.gain = 1.0
            return
        r = (rpm_std * 2.0 * math.pi / 60.0) ** 2
        q = PROCESS_STD_RADPS ** 2
        e2 = self._e1 * self._e1
        p = q
        for _ in range(200):                       # scalar Riccati to its fixed point
            p = e2 * p * r / (p + r) + q
        self.gain = p / (p + r)

    def _measured(self, omega_meas_radps: Sequence[float]) -> list[float]:
        wmax = self.omega_max_radps
        meas = [min(max(w, 0.0), wmax) for w in omega_meas_radps]
        pred = self._omega_model
        if self.gain >= 1.0 or pred is None:
            return meas
        g = self.gain
        return [wp + g * (wm - wp) for wm, wp in zip(meas, pred, strict=True)]

    def reset(self) -> None:
        """Forget the demand history (mode switch: the old demand is not a trend)."""
        self._prev_demand = None

    def reachable(self, omega_meas_radps: Sequence[float] | None) -> tuple[list[float],
                                                                           list[float]]:
        """Per-rotor (lo, hi) *demand* (N) this period's command can honour, and latch ω.

        A rotor at ω can end the period anywhere in [e ω, ω + (ω_max − ω)(1 − e)]
        (e = e^{−h/τ}); with the lead this bounds the demand. Near zero thrust the range is
        tiny (f ∝ ω²): a stopped rotor gains ~0.02 N in 1 ms at τ = 20 ms. Handing these
        bounds to the allocation lets it keep u_f and τ_q exact and give up τ_r/τ_p, as it
        does for the [0, f_max] limits, instead of the inverter clipping blindly.
        """
        kf = self.k_f
        fmax = self.thrust_max_n
        if omega_meas_radps is not None and all(math.isfinite(w) for w in omega_meas_radps):
            omega = self._measured(omega_meas_radps)
        elif self._omega_model is not None:
            omega = self._omega_model
        else:
            omega = None
        self._omega = omega
        if omega is None:
            return [0.0] * 4, [fmax] * 4
        e1 = self._e1
        wmax = self.omega_max_radps
        prev = self._prev_demand
        k = 1.0 + self.lead_periods
        lo: list[float] = []
        hi: list[float] = []
        for i, w in enumerate(omega):
            f_lo = kf * (e1 * w) ** 2
            f_hi = kf * (w + (wmax - w) * (1.0 - e1)) ** 2
            if prev is not None:
                f_lo = (f_lo + self.lead_periods * prev[i]) / k
                f_hi = (f_hi + self.lead_periods * prev[i]) / k
            lo.append(min(max(f_lo, 0.0), fmax))
            hi.append(min(max(f_hi, 0.0), fmax))
        return lo, hi

    def invert(self, demand_n: Sequence[float],
               omega_meas_radps: Sequence[float] | None = None) -> LagInversion:
        """Commands for this period given the law's ``demand_n``.

        ω comes from ``omega_meas_radps`` if given, else from the last :meth:`reachable`,
        else from the inverter's own model of the rotors (open loop).
        """
        kf = self.k_f
        fmax = self.thrust_max_n
        wmax = self.omega_max_radps
        prev = self._prev_demand
        lead = self.lead_periods
        if omega_meas_radps is not None and all(math.isfinite(w) for w in omega_meas_radps):
            omega = self._measured(omega_meas_radps)
        elif self._omega is not None:
            omega = self._omega
        elif self._omega_model is not None:
            omega = self._omega_model
        else:
            omega = [math.sqrt(min(max(f, 0.0), fmax) / kf) for f in demand_n]
        self._omega = None
        e1, gain, m1, m2 = self._e1, self._gain, self._m1, self._m2
        cmd: list[float] = []
        mean: list[float] = []
        clamped: list[bool] = []
        nxt: list[float] = []
        for i, f in enumerate(demand_n):
            target = f if prev is None else f + lead * (f - prev[i])
            w_star = math.sqrt(min(max(target, 0.0), fmax) / kf)
            w0 = omega[i]
            c = (w_star - e1 * w0) * gain
            hit = c < -1e-6 * wmax or c > wmax * (1.0 + 1e-6)
            c = min(max(c, 0.0), wmax)
            dw = w0 - c
            cmd.append(kf * c * c)
            mean.append(kf * (c * c + 2.0 * c * dw * m1 + dw * dw * m2))
            clamped.append(hit)
            nxt.append(c + dw * e1)
        self._prev_demand = list(demand_n)
        self._omega_model = nxt
        return LagInversion(cmd, mean, clamped)
