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
    O(h⁵) per step, which adds up over a million steps). Written out on floats (the
    simulator's hot loop): the same operations in the same order as :func:`derivative`
    and the vector form of RK4, so the results are identical to the bit.
    """
    m = p.mass_kg
    ix, iy, iz = p.inertia_kgm2
    uf, tp, tq, tr = wrench
    a = uf / m
    kt = p.k_t / m
    kr = p.k_r
    g = p.gravity_mps2
    jyz, jzx, jxy = iz - iy, ix - iz, iy - ix

    def f(vx: float, vy: float, vz: float, qw: float, qx: float, qy: float, qz: float,
          wp: float, wq: float, wr: float) -> tuple[float, ...]:
        return (a * (2.0 * (qx * qz + qw * qy)) - kt * vx,
                a * (2.0 * (qy * qz - qw * qx)) - kt * vy,
                a * (1.0 - 2.0 * (qx * qx + qy * qy)) - g - kt * vz,
                0.5 * (-qx * wp - qy * wq - qz * wr),
                0.5 * (qw * wp + qy * wr - qz * wq),
                0.5 * (qw * wq + qz * wp - qx * wr),
                0.5 * (qw * wr + qx * wq - qy * wp),
                (tp - kr * wp - jyz * wq * wr) / ix,
                (tq - kr * wq - jzx * wp * wr) / iy,
                (tr - kr * wr - jxy * wp * wq) / iz)

    px, py, pz, vx, vy, vz, qw, qx, qy, qz, wp, wq, wr = x
    hh = 0.5 * h
    k1 = f(vx, vy, vz, qw, qx, qy, qz, wp, wq, wr)
    v2 = (vx + hh * k1[0], vy + hh * k1[1], vz + hh * k1[2])
    k2 = f(*v2, qw + hh * k1[3], qx + hh * k1[4], qy + hh * k1[5], qz + hh * k1[6],
           wp + hh * k1[7], wq + hh * k1[8], wr + hh * k1[9])
    v3 = (vx + hh * k2[0], vy + hh * k2[1], vz + hh * k2[2])
    k3 = f(*v3, qw + hh * k2[3], qx + hh * k2[4], qy + hh * k2[5], qz + hh * k2[6],
           wp + hh * k2[7], wq + hh * k2[8], wr + hh * k2[9])
    v4 = (vx + h * k3[0], vy + h * k3[1], vz + h * k3[2])
    k4 = f(*v4, qw + h * k3[3], qx + h * k3[4], qy + h * k3[5], qz + h * k3[6],
           wp + h * k3[7], wq + h * k3[8], wr + h * k3[9])
    h6 = h / 6.0
    # Position: its derivative at each stage is that stage's velocity.
    out = [px + h6 * (vx + 2.0 * v2[0] + 2.0 * v3[0] + v4[0]),
           py + h6 * (vy + 2.0 * v2[1] + 2.0 * v3[1] + v4[1]),
           pz + h6 * (vz + 2.0 * v2[2] + 2.0 * v3[2] + v4[2])]
    for i, xi in enumerate((vx, vy, vz, qw, qx, qy, qz, wp, wq, wr)):
        out.append(xi + h6 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]))
    n = math.sqrt(out[6] ** 2 + out[7] ** 2 + out[8] ** 2 + out[9] ** 2)
    out[6] /= n
    out[7] /= n
    out[8] /= n
    out[9] /= n
    return out
