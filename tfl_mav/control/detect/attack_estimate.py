"""The attacked rotor's thrust, estimated: a Kalman filter over its measured speed.

The paper knows the attacked rotor's thrust A only from its measured motor speed (§VI):
A = k_f ω². With ESC noise that measurement is noisy (60 rpm on a 5000 rpm hover speed is
±0.06 N a sample), and with a motor lag the speed trails the attacker's command by τ_m. Reading
A straight off each sample puts the noise into the law's allocation every tick (f₄ = A + τ_p/l),
and the faster the loop, the more samples of noise it flies.

The filter carries both effects in its model (per control period h, e = e^{−h/τ_m}):

    ω[k+1] = e ω[k] + (1 − e) c[k]          the motor's first-order lag (e = 0: no lag)
    c[k+1] = c[k] + w[k],  E w² = S_c h      the attacker's speed command: a random walk
    z[k]   = ω[k] + v[k],  E v² = σ_rpm²     the ESC's measurement

with the process density S_c (rad²/s³) of the attacker's command. The gain is time-varying
(a 2 × 2 Riccati step a tick) so its first samples trust the measurement. Because the
random walk's density is per second, a faster loop sees the same process with more
measurements: its estimate is better, not worse (the steady error variance falls as
√(h)). The estimate given to the law is the thrust over the coming period, k_f ω̄² with
ω̄ the mean of the model's prediction over it, and its standard deviation
σ_A = 2 k_f ω̄ σ_ω goes to the supervisor, which decides authority on A ± 2σ_A.

Without ESC noise there is nothing to filter: the flight computer uses the measured speed
directly (no filter is built), so a noise-free flight is unchanged.
"""

from __future__ import annotations

import math
from typing import NamedTuple

__all__ = ["ATTACK_START", "COMMAND_DENSITY_RAD2PS3", "AttackEstimate", "AttackParams",
           "attack_params", "attack_update"]

# The attacker's speed command as a random walk: its density (rad²/s³). √(S_c) = 100 rad/s
# per √s follows the paper's signal (dA/dt ≈ 0.5 N/s, dω/dt ≈ 80 rad/s² at hover) within a
# few milliseconds and a square wave's 4 N step within tens of them; measured on the envelope's
# lag × noise cases (50 ms, 100 rpm: 12 mm at 100, 78 mm at 300, 212 mm at 1000 rad/s per √s:
# a faster filter lets the noise through to the allocation).
COMMAND_DENSITY_RAD2PS3 = 100.0 ** 2


class AttackParams(NamedTuple):
    """The filter's constants (one control period h)."""

    k_f: float              # thrust = k_f ω² (N s²)
    thrust_max_n: float     # f_max
    e1: float               # e^{−h/τ_m}: the lag over a period (0: no lag)
    r_rad2: float           # the ESC noise's variance on ω (rad²/s²)
    q_rad2: float           # the command's random-walk variance a period, S_c h (rad²/s²)


class AttackEstimate(NamedTuple):
    """What the filter remembers (rad/s; covariance entries in rad²/s²)."""

    started: bool
    omega: float            # ω̂: the rotor's speed now
    command: float          # ĉ: the attacker's speed command
    p11: float              # the covariance of (ω̂, ĉ)
    p12: float
    p22: float


ATTACK_START = AttackEstimate(False, 0.0, 0.0, 0.0, 0.0, 0.0)
_RPM_TO_RADPS = 2.0 * math.pi / 60.0


def attack_params(k_f: float, thrust_max_n: float, motor_time_constant_s: float, dt_s: float,
                  rpm_noise_std: float, *,
                  command_density_rad2ps3: float = COMMAND_DENSITY_RAD2PS3) -> AttackParams:
    """The filter for a rotor of lag ``motor_time_constant_s`` (0: none) read by an ESC of
    noise ``rpm_noise_std`` (rpm, > 0) every ``dt_s``."""
    if not (rpm_noise_std > 0.0 and dt_s > 0.0 and k_f > 0.0):
        raise ValueError("attack_params: rpm_noise_std, dt_s and k_f must be > 0 "
                         f"(got {rpm_noise_std}, {dt_s}, {k_f})")
    e1 = math.exp(-dt_s / motor_time_constant_s) if motor_time_constant_s > 0.0 else 0.0
    sigma = rpm_noise_std * _RPM_TO_RADPS
    return AttackParams(k_f, thrust_max_n, e1, sigma * sigma, command_density_rad2ps3 * dt_s)


def attack_update(p: AttackParams, s: AttackEstimate, omega_meas_radps: float
                  ) -> tuple[AttackEstimate, float, float]:
    """One period: the new state, the thrust A (N) over the coming period and σ_A (N).

    A non-finite measurement is skipped (the prediction stands)."""
    e, q = p.e1, p.q_rad2
    if not s.started:
        if not math.isfinite(omega_meas_radps):
            return s, math.nan, math.inf
        w = max(omega_meas_radps, 0.0)
        s = AttackEstimate(True, w, w, p.r_rad2, p.r_rad2, p.r_rad2 + q)
    else:
        # predict: x⁻ = F x, P⁻ = F P Fᵀ + diag(0, q), F = [[e, 1 − e], [0, 1]]
        f = 1.0 - e
        w = e * s.omega + f * s.command
        c = s.command
        p11 = e * e * s.p11 + 2.0 * e * f * s.p12 + f * f * s.p22
        p12 = e * s.p12 + f * s.p22
        p22 = s.p22 + q
        if math.isfinite(omega_meas_radps):
            # update with z = ω + v
            k = p11 + p.r_rad2
            k1, k2 = p11 / k, p12 / k
            innov = omega_meas_radps - w
            w, c = w + k1 * innov, c + k2 * innov
            p11, p12, p22 = (1.0 - k1) * p11, (1.0 - k1) * p12, p22 - k2 * p12
        s = AttackEstimate(True, w, c, p11, p12, p22)
    # The mean speed over the coming period (the lag's trapezoid) and its thrust.
    w_next = e * s.omega + (1.0 - e) * s.command
    w_bar = max(0.5 * (s.omega + w_next), 0.0)
    a_n = min(p.k_f * w_bar * w_bar, p.thrust_max_n)
    std = 2.0 * p.k_f * w_bar * math.sqrt(max(s.p11, 0.0))
    return s, a_n, std
