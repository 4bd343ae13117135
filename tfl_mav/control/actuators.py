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

The inverse is explicit state (:class:`LagState`) and two pure steps, :func:`lag_reachable`
and :func:`lag_invert`; :class:`MotorLagInverter` holds the state for the laws that share it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

__all__ = [
    "LAG_START",
    "PROCESS_STD_RADPS",
    "LagInversion",
    "LagParams",
    "LagState",
    "MotorLagInverter",
    "kalman_gain",
    "lag_invert",
    "lag_params",
    "lag_reachable",
]

PROCESS_STD_RADPS = 1.0   # per-period model error of ω (rad/s): 20 % of a 5 rad/s step


@dataclass
class LagInversion:
    """One period's result (physical rotor order, N)."""

    command_n: list[float]        # what to send: thrust whose steady ω is the command ω_c
    expected_mean_n: list[float]  # model's mean thrust over the period for that command
    clamped: list[bool]           # ω_c hit 0 or ω_max: the target is out of reach this period


V4 = tuple[float, float, float, float]
_ZERO4 = (0.0, 0.0, 0.0, 0.0)


class LagParams(NamedTuple):
    """The inverse's constants."""

    k_f: float              # thrust = k_f ω² (N s²)
    thrust_max_n: float     # f_max per rotor
    omega_max_radps: float  # √(f_max / k_f)
    e1: float               # e^{−h/τ}
    gain: float             # 1 / (1 − e^{−h/τ}): the deadbeat gain
    m1: float               # the mean of e^{−t/τ} over the period
    m2: float               # the mean of e^{−2t/τ} over the period
    lead: float             # periods the demand is extrapolated ahead
    kalman: float           # the steady Kalman gain on measured ω (1: trust it)


class LagState(NamedTuple):
    """What the inverse remembers (physical rotor order)."""

    has_prev: bool          # ``prev_demand`` is the last period's demand (N)
    prev_demand: V4
    has_model: bool         # ``omega_model`` is the model's ω at the period's end (rad/s)
    omega_model: V4
    has_latched: bool       # ``omega`` is the ω :func:`lag_reachable` used this period
    omega: V4


LAG_START = LagState(False, _ZERO4, False, _ZERO4, False, _ZERO4)


def lag_params(k_f: float, thrust_max_n: float, time_constant_s: float, dt_s: float, *,
               lead_periods: float = 1.0, rpm_std: float = 0.0) -> LagParams:
    """The inverse of a lag of ``time_constant_s`` (> 0) held over periods of ``dt_s``, with
    ESC noise of ``rpm_std`` (rpm; 0: the measured ω is trusted)."""
    if not time_constant_s > 0.0:
        raise ValueError(f"time_constant_s must be > 0 (got {time_constant_s}); "
                         "with no lag there is nothing to invert")
    e1 = math.exp(-dt_s / time_constant_s)
    return LagParams(k_f, thrust_max_n, math.sqrt(thrust_max_n / k_f), e1, 1.0 / (1.0 - e1),
                     time_constant_s * (1.0 - e1) / dt_s,
                     time_constant_s * (1.0 - e1 * e1) / (2.0 * dt_s), lead_periods,
                     kalman_gain(e1, rpm_std))


def kalman_gain(e1: float, rpm_std: float) -> float:
    """The steady Kalman gain on the measured ω for ESC noise of ``rpm_std`` (rpm) and the
    model's own error PROCESS_STD_RADPS a period (1.0 without noise)."""
    if not rpm_std > 0.0:
        return 1.0
    r = (rpm_std * 2.0 * math.pi / 60.0) ** 2
    q = PROCESS_STD_RADPS ** 2
    e2 = e1 * e1
    p = q
    for _ in range(200):                       # scalar Riccati to its fixed point
        p = e2 * p * r / (p + r) + q
    return p / (p + r)


def _speeds(p: LagParams, s: LagState, omega_meas: V4) -> V4:
    """The measured speeds clamped to [0, ω_max], through the Kalman update when there is
    noise and a model."""
    wmax = p.omega_max_radps
    meas = tuple(min(max(w, 0.0), wmax) for w in omega_meas)
    if p.kalman >= 1.0 or not s.has_model:
        return meas  # type: ignore[return-value]
    g = p.kalman
    return tuple(wp + g * (wm - wp) for wm, wp in zip(meas, s.omega_model, strict=True))  # type: ignore[return-value]


def lag_reachable(p: LagParams, s: LagState, omega_meas: V4 | None
                  ) -> tuple[LagState, list[float], list[float]]:
    """Per-rotor (lo, hi) *demand* (N) this period's command can honour, and the ω it used
    latched in the state for :func:`lag_invert`.

    A rotor at ω can end the period anywhere in [e ω, ω + (ω_max − ω)(1 − e)]
    (e = e^{−h/τ}); with the lead this bounds the demand. Near zero thrust the range is
    tiny (f ∝ ω²): a stopped rotor gains ~0.02 N in 1 ms at τ = 20 ms. Handing these
    bounds to the allocation lets it keep u_f and τ_q exact and give up τ_r/τ_p, as it
    does for the [0, f_max] limits, instead of the inverter clipping blindly.
    """
    kf, fmax = p.k_f, p.thrust_max_n
    if omega_meas is not None and all(math.isfinite(w) for w in omega_meas):
        omega: V4 | None = _speeds(p, s, omega_meas)
    elif s.has_model:
        omega = s.omega_model
    else:
        omega = None
    if omega is None:
        return s._replace(has_latched=False), [0.0] * 4, [fmax] * 4
    e1, wmax = p.e1, p.omega_max_radps
    k = 1.0 + p.lead
    lo: list[float] = []
    hi: list[float] = []
    for i, w in enumerate(omega):
        f_lo = kf * (e1 * w) ** 2
        f_hi = kf * (w + (wmax - w) * (1.0 - e1)) ** 2
        if s.has_prev:
            f_lo = (f_lo + p.lead * s.prev_demand[i]) / k
            f_hi = (f_hi + p.lead * s.prev_demand[i]) / k
        lo.append(min(max(f_lo, 0.0), fmax))
        hi.append(min(max(f_hi, 0.0), fmax))
    return s._replace(has_latched=True, omega=tuple(omega)), lo, hi


def lag_invert(p: LagParams, s: LagState, demand_n: V4, omega_meas: V4 | None = None
               ) -> tuple[LagState, LagInversion]:
    """Commands for this period given the law's ``demand_n`` (N).

    ω comes from ``omega_meas`` if given, else from the last :func:`lag_reachable`, else
    from the inverse's own model of the rotors (open loop)."""
    kf, fmax, wmax = p.k_f, p.thrust_max_n, p.omega_max_radps
    if omega_meas is not None and all(math.isfinite(w) for w in omega_meas):
        omega = _speeds(p, s, omega_meas)
    elif s.has_latched:
        omega = s.omega
    elif s.has_model:
        omega = s.omega_model
    else:
        omega = tuple(math.sqrt(min(max(f, 0.0), fmax) / kf) for f in demand_n)  # type: ignore[assignment]
    e1, gain, m1, m2, lead = p.e1, p.gain, p.m1, p.m2, p.lead
    cmd: list[float] = []
    mean: list[float] = []
    clamped: list[bool] = []
    nxt: list[float] = []
    for i, f in enumerate(demand_n):
        target = f + lead * (f - s.prev_demand[i]) if s.has_prev else f
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
    state = LagState(True, tuple(demand_n), True, tuple(nxt), False, s.omega)  # type: ignore[arg-type]
    return state, LagInversion(cmd, mean, clamped)


class MotorLagInverter:
    """Deadbeat inverse of a first-order rotor-speed lag, closed on the measured speed: the
    holder of :class:`LagState` for the laws that share one set of motors."""

    def __init__(self, k_f: float, thrust_max_n: float, time_constant_s: float, dt_s: float,
                 *, lead_periods: float = 1.0) -> None:
        self.params = lag_params(k_f, thrust_max_n, time_constant_s, dt_s,
                                 lead_periods=lead_periods)
        self.time_constant_s = time_constant_s
        self.dt_s = dt_s
        self.state = LAG_START

    @property
    def gain(self) -> float:
        """The Kalman gain on measured ω (1 = trust it)."""
        return self.params.kalman

    def set_rpm_noise(self, rpm_std: float) -> None:
        """ESC noise (rpm std): filter the measured speed with the steady Kalman gain."""
        self.params = self.params._replace(kalman=kalman_gain(self.params.e1, rpm_std))

    def reset(self) -> None:
        """Forget the demand history (mode switch: the old demand is not a trend)."""
        self.state = self.state._replace(has_prev=False)

    def reachable(self, omega_meas_radps: Sequence[float] | None
                  ) -> tuple[list[float], list[float]]:
        """:func:`lag_reachable` on the held state."""
        self.state, lo, hi = lag_reachable(self.params, self.state, omega_meas_radps)  # type: ignore[arg-type]
        return lo, hi

    def invert(self, demand_n: Sequence[float],
               omega_meas_radps: Sequence[float] | None = None) -> LagInversion:
        """:func:`lag_invert` on the held state."""
        self.state, out = lag_invert(self.params, self.state, demand_n,  # type: ignore[arg-type]
                                     omega_meas_radps)  # type: ignore[arg-type]
        return out
