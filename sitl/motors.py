"""Motors and ESCs: thrust f = k_f ω², optional first-order lag on ω, limits [0, f_max].

The ESC reports the *actual* rotor speed (rpm), so a rotor whose thrust an attacker forces
shows up in telemetry — unlike PX4's SITL, which fakes rpm from the command.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

__all__ = ["RADPS_TO_RPM", "MotorBank"]

RADPS_TO_RPM = 60.0 / (2.0 * math.pi)
_sqrt = math.sqrt


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
        self._lag: tuple[float, float, float, float] = (math.nan, 0.0, 0.0, 0.0)
        """(h, e1, m1, m2) of the last step: the lag's constants depend on h alone."""

    def omega_for_thrust(self, thrust_n: float) -> float:
        """Steady rotor speed (rad/s) for a thrust, clamped to [0, f_max]."""
        # min(max(f, 0.0), f_max) as conditionals (what the builtins return, NaN included;
        # this runs every physics step for an attacked rotor)
        f = 0.0 if thrust_n < 0.0 else thrust_n
        fmax = self.thrust_max_n
        return math.sqrt((fmax if fmax < f else f) / self.k_f)

    def omegas_for_thrusts(self, thrust_n: Sequence[float]) -> list[float]:
        """:meth:`omega_for_thrust` of each thrust (a control period's held targets)."""
        fmax = self.thrust_max_n
        f1, f2, f3, f4 = thrust_n
        if 0.0 <= f1 <= fmax and 0.0 <= f2 <= fmax and 0.0 <= f3 <= fmax and 0.0 <= f4 <= fmax:
            kf = self.k_f               # in range: the clamp returns f itself
            return [_sqrt(f1 / kf), _sqrt(f2 / kf), _sqrt(f3 / kf), _sqrt(f4 / kf)]
        return [self.omega_for_thrust(f) for f in thrust_n]   # out of range or NaN (rare)

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
            w1, w2, w3, w4 = self.omega_radps = list(omega_target_radps)
            return [kf * w1 * w1, kf * w2 * w2, kf * w3 * w3, kf * w4 * w4]
        h0, e1, m1, m2 = self._lag
        if h != h0:
            e1 = math.exp(-h / tau)
            m1 = tau * (1.0 - e1) / h          # mean of exp(−t/τ) over the step
            m2 = tau * (1.0 - e1 * e1) / (2.0 * h)  # mean of exp(−2t/τ)
            self._lag = (h, e1, m1, m2)
        w1, w2, w3, w4 = self.omega_radps
        c1, c2, c3, c4 = omega_target_radps
        d1, d2, d3, d4 = w1 - c1, w2 - c2, w3 - c3, w4 - c4
        self.omega_radps = [c1 + d1 * e1, c2 + d2 * e1, c3 + d3 * e1, c4 + d4 * e1]
        return [kf * (c1 * c1 + 2.0 * c1 * d1 * m1 + d1 * d1 * m2),
                kf * (c2 * c2 + 2.0 * c2 * d2 * m1 + d2 * d2 * m2),
                kf * (c3 * c3 + 2.0 * c3 * d3 * m1 + d3 * d3 * m2),
                kf * (c4 * c4 + 2.0 * c4 * d4 * m1 + d4 * d4 * m2)]
