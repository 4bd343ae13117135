"""What the TFL law is configured with and what it returns (paper §V, §VI).

:class:`ModelParams` is the law's model of the vehicle (deliberately not the truth),
:class:`LawConfig` its gains and robustness switches (the scenario's ``[controller]``
table), :class:`ControlOutput` one decision with the internals worth logging.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

from tfl_mav.model.modes import Mode

__all__ = ["ControlOutput", "LawConfig", "ModelParams", "chain_gains"]


@dataclass(frozen=True)
class ModelParams:
    """The controller's model of the vehicle (deliberately not the truth), SI units."""

    mass_kg: float
    inertia_kgm2: tuple[float, float, float]
    arm_m: float
    drag_thrust_ratio_m: float
    k_t: float
    k_r: float
    thrust_max_n: float
    gravity_mps2: float = 9.81
    k_f: float = 8.0e-6                 # N/(rad/s)², thrust = k_f ω²
    motor_time_constant_s: float = 0.0  # first-order lag on ω; 0 = ideal actuators


@dataclass(frozen=True)
class LawConfig:
    """Gains and robustness switches (mirrors the scenario's ``[controller]`` table)."""

    speed_mps: float = 0.5
    xi_pole: float = -2.5
    eta_pole: float = -2.0
    xi_pole_fine: float = -8.0      # scenario.ControllerConfig.xi_pole_fine says why
    eta_pole_fine: float = -2.5
    yaw_pole: float = -4.0
    robust: bool = True
    mass_estimator: bool = True
    disturbance_observer: bool = True
    gain_switch: bool = True
    observer_tau_s: float = 0.004
    translational_observer: bool = False    # the horizontal unmodelled acceleration fed to
                                            # the ξ, η chains (estimators.tdob_update)
    translational_observer_tau_s: float = 0.1
    translational_observer_vertical: bool = False   # and the vertical (else: horizontal only)
    aware_of_attack: bool = True
    # |α| below settle_alpha for settle_time_s switches to the fine poles. A steady residual
    # acceleration d holds the coarse poles 6d/p² off (p = 2.5: 0.1 m/s² of rotor drag or of
    # an estimate's tilt is 9.6 cm), so a threshold of 1 cm kept the coarse poles exactly
    # where the fine ones are needed (the built-in realistic: 155 mm where 28 flies). The
    # switch's kick from a steady α is α (p_fine² − p²)/6: 1.9 m/s² from 20 cm, a third of
    # the tilt's g tan 30°.
    settle_alpha: float = 0.2       # |α| below this (m) …
    settle_time_s: float = 1.0      # … for this long (s) switches to the fine poles
    min_thrust_n: float = 0.5       # u_f below this makes D singular: fall back
    max_cond: float = 1e8           # cond(Dφ) above this: fall back


class ControlOutput(NamedTuple):
    """One control decision and the internals worth logging (a named tuple: one is made
    every tick, and a tuple is built about twice as fast as a dataclass)."""

    rotor_thrust_n: list[float]          # command, in [0, f_max], physical rotor order (with
                                         # motor lag: the lag inverse of the law's demand)
    mode: Mode                           # NOMINAL | ATTACKED | FALLBACK
    saturated: list[bool]
    xi: tuple[tuple[float, ...], tuple[float, ...]]   # (α1, α̇1, α̈1, α⃛1), same for α2
    eta: tuple[float, ...]               # (π, π̇, π̈, π⃛)
    mu: tuple[float, float]              # (ψ, μ2) internal states, eq. (18)
    path_distance_m: float
    lam: float
    cond_d: float
    thrust_n: float                      # u_f = x13
    mass_estimate_kg: float
    disturbance_radps2: tuple[float, float]
    fine_gains: bool
    reason: str = ""                     # why a fallback was taken
    demand_n: tuple[float, ...] = ()     # the unbounded allocation the law asked for (N,
                                         # physical; before the lag inverse and [0, f_max])


def chain_gains(pole: float, order: int) -> tuple[float, ...]:
    """Gains k₀…k_{n−1} of (s − pole)ⁿ = sⁿ + k_{n−1}sⁿ⁻¹ + … + k₀ (pole < 0)."""
    a = -pole
    return tuple(math.comb(order, i) * a ** (order - i) for i in range(order))
