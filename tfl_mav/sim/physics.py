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
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from tfl_mav.model.airframe import mix
from tfl_mav.model.geometry import rotation_from_quaternion

__all__ = ["RigidBodyParams", "RigidBodyState", "Rk4Step", "mix", "rk4_step", "rk4_stepper"]


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


def rk4_step(p: RigidBodyParams, x: Sequence[float], wrench: Sequence[float],
             h: float) -> list[float]:
    """One classical RK4 step of length ``h`` s with the wrench held; renormalises q.

    Convenience form of :func:`rk4_stepper` (which a hot loop builds once and keeps; this
    one runs the Python step, as it builds a stepper per call).
    """
    uf, tp, tq, tr = wrench
    return rk4_stepper(p, compiled=False)(x, uf, tp, tq, tr, h)


Rk4Step = Callable[[Sequence[float], float, float, float, float, float], list[float]]


def rk4_stepper(p: RigidBodyParams, compiled: bool = True) -> Rk4Step:
    """``step(x, u_f, τ_p, τ_q, τ_r, h)``: one classical RK4 step of the 13-float state ``x``
    with the body wrench held over ``h`` s, q renormalised; a new list.

    Renormalising once per step keeps |q| = 1 to rounding error (RK4 alone drifts by
    O(h⁵) per step, which adds up over a million steps). Written out on plain floats, the
    four stages inlined and the airframe constants bound once (the simulator's hot loop: a
    call per stage and a tuple per stage cost as much as the arithmetic). Each expression
    is :func:`derivative`'s, in the same order, and the stages combine as the vector form of
    RK4 does, so the result is the same to the bit. ``compiled``: the same step compiled to C
    where a compiler is (:mod:`physics_native`: the same bits again); False: this Python.
    """
    m = p.mass_kg
    ix, iy, iz = p.inertia_kgm2
    kt = p.k_t / m
    kr = p.k_r
    g = p.gravity_mps2
    jyz, jzx, jxy = iz - iy, ix - iz, iy - ix

    def step(x: Sequence[float], uf: float, tp: float, tq: float, tr: float,
             h: float) -> list[float]:
        px, py, pz, vx, vy, vz, qw, qx, qy, qz, wp, wq, wr = x
        a = uf / m
        hh = 0.5 * h
        # k1 = f(x)
        a1x = a * (2.0 * (qx * qz + qw * qy)) - kt * vx
        a1y = a * (2.0 * (qy * qz - qw * qx)) - kt * vy
        a1z = a * (1.0 - 2.0 * (qx * qx + qy * qy)) - g - kt * vz
        d1w = 0.5 * (-qx * wp - qy * wq - qz * wr)
        d1x = 0.5 * (qw * wp + qy * wr - qz * wq)
        d1y = 0.5 * (qw * wq + qz * wp - qx * wr)
        d1z = 0.5 * (qw * wr + qx * wq - qy * wp)
        e1p = (tp - kr * wp - jyz * wq * wr) / ix
        e1q = (tq - kr * wq - jzx * wp * wr) / iy
        e1r = (tr - kr * wr - jxy * wp * wq) / iz
        # k2 = f(x + hh·k1)
        vx2 = vx + hh * a1x
        vy2 = vy + hh * a1y
        vz2 = vz + hh * a1z
        qw2 = qw + hh * d1w
        qx2 = qx + hh * d1x
        qy2 = qy + hh * d1y
        qz2 = qz + hh * d1z
        wp2 = wp + hh * e1p
        wq2 = wq + hh * e1q
        wr2 = wr + hh * e1r
        a2x = a * (2.0 * (qx2 * qz2 + qw2 * qy2)) - kt * vx2
        a2y = a * (2.0 * (qy2 * qz2 - qw2 * qx2)) - kt * vy2
        a2z = a * (1.0 - 2.0 * (qx2 * qx2 + qy2 * qy2)) - g - kt * vz2
        d2w = 0.5 * (-qx2 * wp2 - qy2 * wq2 - qz2 * wr2)
        d2x = 0.5 * (qw2 * wp2 + qy2 * wr2 - qz2 * wq2)
        d2y = 0.5 * (qw2 * wq2 + qz2 * wp2 - qx2 * wr2)
        d2z = 0.5 * (qw2 * wr2 + qx2 * wq2 - qy2 * wp2)
        e2p = (tp - kr * wp2 - jyz * wq2 * wr2) / ix
        e2q = (tq - kr * wq2 - jzx * wp2 * wr2) / iy
        e2r = (tr - kr * wr2 - jxy * wp2 * wq2) / iz
        # k3 = f(x + hh·k2)
        vx3 = vx + hh * a2x
        vy3 = vy + hh * a2y
        vz3 = vz + hh * a2z
        qw3 = qw + hh * d2w
        qx3 = qx + hh * d2x
        qy3 = qy + hh * d2y
        qz3 = qz + hh * d2z
        wp3 = wp + hh * e2p
        wq3 = wq + hh * e2q
        wr3 = wr + hh * e2r
        a3x = a * (2.0 * (qx3 * qz3 + qw3 * qy3)) - kt * vx3
        a3y = a * (2.0 * (qy3 * qz3 - qw3 * qx3)) - kt * vy3
        a3z = a * (1.0 - 2.0 * (qx3 * qx3 + qy3 * qy3)) - g - kt * vz3
        d3w = 0.5 * (-qx3 * wp3 - qy3 * wq3 - qz3 * wr3)
        d3x = 0.5 * (qw3 * wp3 + qy3 * wr3 - qz3 * wq3)
        d3y = 0.5 * (qw3 * wq3 + qz3 * wp3 - qx3 * wr3)
        d3z = 0.5 * (qw3 * wr3 + qx3 * wq3 - qy3 * wp3)
        e3p = (tp - kr * wp3 - jyz * wq3 * wr3) / ix
        e3q = (tq - kr * wq3 - jzx * wp3 * wr3) / iy
        e3r = (tr - kr * wr3 - jxy * wp3 * wq3) / iz
        # k4 = f(x + h·k3)
        vx4 = vx + h * a3x
        vy4 = vy + h * a3y
        vz4 = vz + h * a3z
        qw4 = qw + h * d3w
        qx4 = qx + h * d3x
        qy4 = qy + h * d3y
        qz4 = qz + h * d3z
        wp4 = wp + h * e3p
        wq4 = wq + h * e3q
        wr4 = wr + h * e3r
        a4x = a * (2.0 * (qx4 * qz4 + qw4 * qy4)) - kt * vx4
        a4y = a * (2.0 * (qy4 * qz4 - qw4 * qx4)) - kt * vy4
        a4z = a * (1.0 - 2.0 * (qx4 * qx4 + qy4 * qy4)) - g - kt * vz4
        d4w = 0.5 * (-qx4 * wp4 - qy4 * wq4 - qz4 * wr4)
        d4x = 0.5 * (qw4 * wp4 + qy4 * wr4 - qz4 * wq4)
        d4y = 0.5 * (qw4 * wq4 + qz4 * wp4 - qx4 * wr4)
        d4z = 0.5 * (qw4 * wr4 + qx4 * wq4 - qy4 * wp4)
        e4p = (tp - kr * wp4 - jyz * wq4 * wr4) / ix
        e4q = (tq - kr * wq4 - jzx * wp4 * wr4) / iy
        e4r = (tr - kr * wr4 - jxy * wp4 * wq4) / iz
        h6 = h / 6.0
        # position: its derivative at each stage is that stage's velocity
        npx = px + h6 * (vx + 2.0 * vx2 + 2.0 * vx3 + vx4)
        npy = py + h6 * (vy + 2.0 * vy2 + 2.0 * vy3 + vy4)
        npz = pz + h6 * (vz + 2.0 * vz2 + 2.0 * vz3 + vz4)
        nvx = vx + h6 * (a1x + 2.0 * a2x + 2.0 * a3x + a4x)
        nvy = vy + h6 * (a1y + 2.0 * a2y + 2.0 * a3y + a4y)
        nvz = vz + h6 * (a1z + 2.0 * a2z + 2.0 * a3z + a4z)
        nqw = qw + h6 * (d1w + 2.0 * d2w + 2.0 * d3w + d4w)
        nqx = qx + h6 * (d1x + 2.0 * d2x + 2.0 * d3x + d4x)
        nqy = qy + h6 * (d1y + 2.0 * d2y + 2.0 * d3y + d4y)
        nqz = qz + h6 * (d1z + 2.0 * d2z + 2.0 * d3z + d4z)
        nwp = wp + h6 * (e1p + 2.0 * e2p + 2.0 * e3p + e4p)
        nwq = wq + h6 * (e1q + 2.0 * e2q + 2.0 * e3q + e4q)
        nwr = wr + h6 * (e1r + 2.0 * e2r + 2.0 * e3r + e4r)
        n = math.sqrt(nqw ** 2 + nqx ** 2 + nqy ** 2 + nqz ** 2)
        return [npx, npy, npz, nvx, nvy, nvz, nqw / n, nqx / n, nqy / n, nqz / n,
                nwp, nwq, nwr]

    if not compiled:
        return step
    from tfl_mav.sim.physics_native import stepper  # the same step compiled (tfl_mav.accel.native)

    return stepper(step)
