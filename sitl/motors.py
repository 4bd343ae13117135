"""Motors and ESCs: thrust f = k_f ω², optional first-order lag on ω, limits [0, f_max].

The ESC reports the *actual* rotor speed (rpm), so a rotor whose thrust an attacker forces
shows up in telemetry — unlike PX4's SITL, which fakes rpm from the command.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

__all__ = ["RADPS_TO_RPM", "MotorBank"]

RADPS_TO_RPM = 60.0 / (2.0 * math.pi)


class MotorBank:
    """Four rotors with a first-order speed lag ``dω/dt = (ω_target − ω)/τ_m``.

    ``step`` advances ω with the exact solution of the lag for a target held over the step
    and returns the *mean* thrust over the step (∫ k_f ω² dt / h, also exact), which the
    rigid body then holds for its RK4 step. With τ_m = 0 the rotor speed jumps to the target.
    """

    def __init__(self, k_f: float, thrust_max_n: float, time_constant_s: float,
                 initial_thrust_n: Sequence[float]) -> None:
        self.k_f = k_f
        self.thrust_max_n = thrust_max_n
        self.time_constant_s = time_constant_s
        self.omega_max_radps = math.sqrt(thrust_max_n / k_f)
        self.omega_radps = [self.omega_for_thrust(f) for f in initial_thrust_n]

    def omega_for_thrust(self, thrust_n: float) -> float:
        """Steady rotor speed (rad/s) for a thrust, clamped to [0, f_max]."""
        return math.sqrt(min(max(thrust_n, 0.0), self.thrust_max_n) / self.k_f)

    @property
    def thrust_n(self) -> list[float]:
        """Instantaneous thrust of each rotor (N)."""
        return [self.k_f * w * w for w in self.omega_radps]

    @property
    def rpm(self) -> list[float]:
        """True rotor speed of each rotor (rpm)."""
        return [w * RADPS_TO_RPM for w in self.omega_radps]

    def step(self, omega_target_radps: Sequence[float], h: float) -> list[float]:
        """Advance ω by ``h`` s toward the targets; return the mean thrust of each rotor (N)."""
        tau = self.time_constant_s
        kf = self.k_f
        if tau <= 0.0:
            self.omega_radps = list(omega_target_radps)
            return [kf * w * w for w in self.omega_radps]
        e1 = math.exp(-h / tau)
        m1 = tau * (1.0 - e1) / h          # mean of exp(−t/τ) over the step
        m2 = tau * (1.0 - e1 * e1) / (2.0 * h)  # mean of exp(−2t/τ)
        mean = []
        new = []
        for w0, c in zip(self.omega_radps, omega_target_radps, strict=True):
            dw = w0 - c
            mean.append(kf * (c * c + 2.0 * c * dw * m1 + dw * dw * m2))
            new.append(c + dw * e1)
        self.omega_radps = new
        return mean
