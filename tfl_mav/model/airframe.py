"""The "+" quadrotor airframe: rotor thrusts → total thrust and body torques (paper eq. (4)).

In the body frame (FLU) rotor 1 sits at +l b1 (front), rotor 2 at −l b2 (right), rotor 3 at
−l b1 (back) and rotor 4 at +l b2 (left); 1 and 3 spin one way, 2 and 4 the other. With arm
length l and drag-to-thrust ratio d: u_f = Σ fᵢ, τ_p = l (f4 − f2), τ_q = l (f3 − f1),
τ_r = d (f1 − f2 + f3 − f4). The physics integrates it; the logs use it to turn true rotor
thrusts into the wrench the vehicle felt. The control law inverts it in
:mod:`tfl_mav.control.allocation`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

__all__ = ["Airframe", "mix", "rotor_xy_m"]


class Airframe(Protocol):
    arm_m: float                 # l: rotor arm length (m)
    drag_thrust_ratio_m: float   # d: rotor drag torque / thrust (m)


def mix(p: Airframe, f: Sequence[float]) -> tuple[float, float, float, float]:
    """Rotor thrusts (N) → (u_f N, τ_p, τ_q, τ_r N m); eq. (4)."""
    f1, f2, f3, f4 = f
    ell, d = p.arm_m, p.drag_thrust_ratio_m
    return (f1 + f2 + f3 + f4, ell * (f4 - f2), ell * (f3 - f1), d * (f1 - f2 + f3 - f4))


def rotor_xy_m(p: Airframe) -> tuple[tuple[float, float], ...]:
    """Rotor positions (x forward, y left; m) in the body frame, rotors 1-4, where eq. (3)
    puts them: τ_p = l (f4 − f2) and τ_q = l (f3 − f1) place rotor 1 on +b1, 2 on −b2,
    3 on −b1, 4 on +b2 (what the flight log draws)."""
    ell = p.arm_m
    return ((ell, 0.0), (0.0, -ell), (-ell, 0.0), (0.0, ell))
