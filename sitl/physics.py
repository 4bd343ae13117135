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

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from tfl_mav.airframe import mix
from tfl_mav.geometry import rotation_from_quaternion

__all__ = ["RigidBodyParams", "RigidBodyState", "mix", "rk4_step"]


@dataclass(frozen=True)
class RigidBodyParams:
    """Physical constants of the airframe (SI)."""

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


def derivative(p: RigidBodyParams, x: Sequence[float], wrench: Sequence[float]) -> list[float]:
    """ẋ of the 13-float state [x_q, v_q, q, Ω] for body wrench (u_f, τ_p, τ_q, τ_r)."""
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
    return [
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
    ]


def rk4_step(p: RigidBodyParams, x: list[float], wrench: Sequence[float], h: float) -> list[float]:
    """One classical RK4 step of length ``h`` s with the wrench held; renormalises q.

    Renormalising once per step keeps |q| = 1 to rounding error (RK4 alone drifts by
    O(h⁵) per step, which adds up over a million steps).
    """
    k1 = derivative(p, x, wrench)
    x2 = [xi + 0.5 * h * ki for xi, ki in zip(x, k1, strict=True)]
    k2 = derivative(p, x2, wrench)
    x3 = [xi + 0.5 * h * ki for xi, ki in zip(x, k2, strict=True)]
    k3 = derivative(p, x3, wrench)
    x4 = [xi + h * ki for xi, ki in zip(x, k3, strict=True)]
    k4 = derivative(p, x4, wrench)
    h6 = h / 6.0
    out = [xi + h6 * (a + 2.0 * b + 2.0 * c + d)
           for xi, a, b, c, d in zip(x, k1, k2, k3, k4, strict=True)]
    n = math.sqrt(out[6] ** 2 + out[7] ** 2 + out[8] ** 2 + out[9] ** 2)
    out[6] /= n
    out[7] /= n
    out[8] /= n
    out[9] /= n
    return out
