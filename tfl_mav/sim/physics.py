"""Rigid-body quadrotor dynamics, integrated singularity-free (unit quaternion, RK4).

Equivalent to the paper's model (eq. (3)) but without the Euler chart, which is the
controller's business, not the plant's:

    ẋ_q = v_q
    v̇_q = (u_f/m) R b3 − g i3 − (k_t/m) v_q
    q̇   = ½ q ⊗ (0, Ω)                         (R = R(q): body → inertial)
    J Ω̇ = τ − k_r Ω − Ω × JΩ

Frame: the paper's inertial frame, z **up** (treated as ENU), body b1 forward, b2 left,
b3 up (FLU). Rotor layout ("+", eq. (4)): rotor 1 on +b1 (front),
rotor 2 on −b2 (right), rotor 3 on −b1 (back), rotor 4 on +b2 (left); rotors 1 and 3
react +d·f about b3, rotors 2 and 4 −d·f. MAVLink actuator index i is rotor i+1.

The state is kept as plain Python floats: for 13 numbers numpy's per-call overhead costs
more than the arithmetic, and the simulator must run many times faster than real time.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from tfl_mav.accel import native
from tfl_mav.model.airframe import mix
from tfl_mav.model.geometry import rotation_from_quaternion

__all__ = ["RigidBodyParams", "RigidBodyState", "Rk4Step", "derivative", "mix",
           "rk4_step", "rk4_stepper"]


class RigidBodyParams(NamedTuple):
    """Physical constants of the airframe (SI): a tuple of floats, so that the one compiled
    RK4 takes them as an argument (one build serves every airframe)."""

    mass_kg: float
    inertia_kgm2: tuple[float, float, float]
    arm_m: float
    drag_thrust_ratio_m: float
    k_t: float
    k_r: float
    gravity_mps2: float = 9.81


@dataclass
class RigidBodyState:
    """True state, paper frame (z up). ``quaternion_wxyz`` rotates body (FLU) to inertial."""

    position_m: np.ndarray
    velocity_mps: np.ndarray
    quaternion_wxyz: np.ndarray
    body_rates_radps: np.ndarray

    def as_list(self) -> list[float]:
        return [*self.position_m, *self.velocity_mps, *self.quaternion_wxyz,
                *self.body_rates_radps]

    @classmethod
    def from_list(cls, x: Sequence[float]) -> RigidBodyState:
        a = np.asarray(x, dtype=float)
        return cls(a[0:3].copy(), a[3:6].copy(), a[6:10].copy(), a[10:13].copy())

    @property
    def rotation(self) -> np.ndarray:
        """R (3×3): body FLU → inertial (paper frame)."""
        return rotation_from_quaternion(self.quaternion_wxyz)


def derivative(p: RigidBodyParams, x: Sequence[float], wrench: Sequence[float]
               ) -> tuple[float, ...]:
    """ẋ of the 13-float state [x_q, v_q, q, Ω] for body wrench (u_f, τ_p, τ_q, τ_r):
    eq. (3) with the quaternion kinematics above in place of the Euler chart."""
    _, _, _, vx, vy, vz, qw, qx, qy, qz, wp, wq, wr = x
    uf, tp, tq, tr = wrench
    m = p.mass_kg
    ix, iy, iz = p.inertia_kgm2
    # Third column of R(q) = R b3: where the thrust points.
    b3x = 2.0 * (qx * qz + qw * qy)
    b3y = 2.0 * (qy * qz - qw * qx)
    b3z = 1.0 - 2.0 * (qx * qx + qy * qy)
    a = uf / m
    kt = p.k_t / m
    kr = p.k_r
    return (
        vx, vy, vz,
        a * b3x - kt * vx,
        a * b3y - kt * vy,
        a * b3z - p.gravity_mps2 - kt * vz,
        0.5 * (-qx * wp - qy * wq - qz * wr),
        0.5 * (qw * wp + qy * wr - qz * wq),
        0.5 * (qw * wq + qz * wp - qx * wr),
        0.5 * (qw * wr + qx * wq - qy * wp),
        (tp - kr * wp - (iz - iy) * wq * wr) / ix,
        (tq - kr * wq - (ix - iz) * wp * wr) / iy,
        (tr - kr * wr - (iy - ix) * wp * wq) / iz,
    )


def rk4_step(p: RigidBodyParams, x: Sequence[float], wrench: Sequence[float],
             h: float) -> tuple[float, ...]:
    """One classical RK4 step of length ``h`` s of the 13-float state ``x`` with the body
    wrench held; q renormalised.

    The stages are :func:`derivative` at x, x + (h/2)·k1, x + (h/2)·k2 and x + h·k3, and
    x + (h/6)·(k1 + 2 k2 + 2 k3 + k4) combines them. Renormalising once per step keeps
    |q| = 1 to rounding error (RK4 alone drifts by O(h⁵) per step, which adds up over a
    million steps). The simulator flies this function compiled (:func:`rk4_stepper`), which
    does its operations in its order: the same bits.
    """
    hh = 0.5 * h
    k1 = derivative(p, x, wrench)
    k2 = derivative(p, [x[i] + hh * k1[i] for i in range(13)], wrench)
    k3 = derivative(p, [x[i] + hh * k2[i] for i in range(13)], wrench)
    k4 = derivative(p, [x[i] + h * k3[i] for i in range(13)], wrench)
    h6 = h / 6.0
    px, py, pz, vx, vy, vz, qw, qx, qy, qz, wp, wq, wr = [
        x[i] + h6 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]) for i in range(13)]
    n = math.sqrt(qw ** 2 + qx ** 2 + qy ** 2 + qz ** 2)
    return (px, py, pz, vx, vy, vz, qw / n, qx / n, qy / n, qz / n, wp, wq, wr)


Rk4Step = Callable[[Sequence[float], Sequence[float], float], Sequence[float]]

# The compiled rk4_step, once built: one for every airframe (its constants are an argument).
_compiled: dict[str, Any] = {"core": None}
# The arguments' shapes, which the lowering reads (their values are not folded in).
_EXAMPLE = (RigidBodyParams(1.0, (1.0, 1.0, 1.0), 1.0, 1.0, 1.0, 1.0, 1.0), (0.0,) * 13,
            (0.0,) * 4, 1.0)


def rk4_stepper(p: RigidBodyParams, compiled: bool = True) -> Rk4Step:
    """``step(x, wrench, h)``: :func:`rk4_step` of the airframe ``p``, compiled
    (:func:`tfl_mav.accel.native.obtain_function`) once it is built (this process, the
    cache, ``TFL_MAV_NATIVE=sync``; ``auto``: a background build, switched to when ready —
    the same bits, so the switch is invisible). On a state that is not plain floats (a
    numpy-scalar state on the diverging path), or where the Python step would raise (the
    compiled one then returns None), the Python step runs and decides. ``compiled``
    False, or ``TFL_MAV_NATIVE=off``: the Python step alone."""
    python = functools.partial(rk4_step, p)
    if not compiled or native.mode() == "off":
        return python
    _attach()
    plain = float
    # A plain tuple: the core reads its items in place (a NamedTuple, a tuple subclass, it
    # would copy into a list on every call).
    constants = tuple(p)

    def step(x: Sequence[float], wrench: Sequence[float], h: float) -> Sequence[float]:
        core = _compiled["core"]
        if core is not None and type(x[0]) is plain:
            r = core(constants, x, wrench, h)
            if r is not None:
                return r  # type: ignore[no-any-return]
        return python(x, wrench, h)

    return step


def _attach() -> None:
    """The compiled rk4_step into ``_compiled``: now if it is built, else when a background
    build completes (``auto``)."""
    if _compiled["core"] is not None:
        return

    def ready(core: Any) -> None:
        _compiled["core"] = core

    core = native.obtain_function(rk4_step, _EXAMPLE, ready)
    if core is not None:
        ready(core)
