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

__all__ = [
    "RK4_STEP_EXAMPLE",
    "RigidBodyParams",
    "RigidBodyState",
    "Rk4AirStep",
    "Rk4Step",
    "RotorAeroParams",
    "compiled_rk4_step",
    "derivative",
    "derivative_air",
    "mix",
    "rk4_air_step",
    "rk4_air_stepper",
    "rk4_step",
    "rk4_stepper",
]


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


class RotorAeroParams(NamedTuple):
    """Rotor and frame aerodynamics in moving air (RotorPy's ``Multirotor.compute_body_wrench``;
    all zero: only the paper's linear drag k_t, on the air-relative velocity). Per rotor i,
    with ω_i its speed (rad/s) and u_i its air-relative velocity in body axes (the body's
    airspeed plus Ω × r_i):

        H_i = −ω_i (k_d u_ix, k_d u_iy, k_z u_iz)      rotor drag (H-force) and induced inflow
        ΔT_i = k_h (u_ix² + u_iy²) along b3             translational lift

    and on the frame D = −|u| (c_Dx u_x, c_Dy u_y, c_Dz u_z) (parasitic drag), the rotors'
    forces also acting as moments r_i × F_i about the CG; and the rotors' angular momentum
    h_r b3, h_r = J_r (−ω₁ + ω₂ − ω₃ + ω₄) (rotors 1, 3 spin about −b3: their drag reacts
    +d f), turning with the body: the gyroscopic torque −Ω × h_r b3. (The reaction to a
    rotor's spin-up, J_r (ω̇₁ − ω̇₂ + ω̇₃ − ω̇₄) about b3, comes in with the wrench: the
    simulator has ω̇ from the motors.)"""

    rotor_drag_kgprad: float = 0.0          # k_d, N/(rad/s · m/s)
    induced_inflow_kgprad: float = 0.0      # k_z, N/(rad/s · m/s)
    translational_lift_kgpm: float = 0.0    # k_h, N/(m/s)²
    parasitic_drag_kgpm: tuple[float, float, float] = (0.0, 0.0, 0.0)   # c_D, N/(m/s)², body
    inv_k_f: float = 0.0                    # 1/k_f, (rad/s)²/N: ω_i = √(f_i / k_f)
    rotor_inertia_kgm2: float = 0.0         # J_r, each rotor about its axis


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


def derivative_air(p: RigidBodyParams, a: RotorAeroParams, x: Sequence[float],
                   wrench: Sequence[float], air: Sequence[float]) -> tuple[float, ...]:
    """:func:`derivative` in moving air: the drag acts on the air-relative velocity
    v_q − w, and the rotor/frame aerodynamics of ``a`` (:class:`RotorAeroParams`) are added.
    ``air`` = (w_x, w_y, w_z, f_1, f_2, f_3, f_4): the wind (m/s, paper frame) and the
    rotors' thrusts (N), from which their speeds. Rotor i sits at r_i (eq. (4)'s "+" layout:
    (l, 0, 0), (0, −l, 0), (−l, 0, 0), (0, l, 0) in FLU)."""
    _, _, _, vx, vy, vz, qw, qx, qy, qz, wp, wq, wr = x
    uf, tp, tq, tr = wrench
    windx, windy, windz, f1, f2, f3, f4 = air
    kd, kz, kh, cd, inv_kf, jr = a
    cdx, cdy, cdz = cd
    m = p.mass_kg
    ix, iy, iz = p.inertia_kgm2
    ell = p.arm_m
    # R(q), body → inertial, by columns b1, b2, b3
    r11 = 1.0 - 2.0 * (qy * qy + qz * qz)
    r21 = 2.0 * (qx * qy + qw * qz)
    r31 = 2.0 * (qx * qz - qw * qy)
    r12 = 2.0 * (qx * qy - qw * qz)
    r22 = 1.0 - 2.0 * (qx * qx + qz * qz)
    r32 = 2.0 * (qy * qz + qw * qx)
    r13 = 2.0 * (qx * qz + qw * qy)
    r23 = 2.0 * (qy * qz - qw * qx)
    r33 = 1.0 - 2.0 * (qx * qx + qy * qy)
    ax = vx - windx          # air-relative velocity, inertial
    ay = vy - windy
    az = vz - windz
    ub = r11 * ax + r21 * ay + r31 * az      # Rᵀ (v − w): the body's airspeed, FLU
    vb = r12 * ax + r22 * ay + r32 * az
    wb = r13 * ax + r23 * ay + r33 * az
    o1 = math.sqrt(f1 * inv_kf)
    o2 = math.sqrt(f2 * inv_kf)
    o3 = math.sqrt(f3 * inv_kf)
    o4 = math.sqrt(f4 * inv_kf)
    # each rotor's airspeed: ub + Ω × r_i
    lp, lq, lr = ell * wp, ell * wq, ell * wr
    u1x, u1y, u1z = ub, vb + lr, wb - lq
    u2x, u2y, u2z = ub + lr, vb, wb - lp
    u3x, u3y, u3z = ub, vb - lr, wb + lq
    u4x, u4y, u4z = ub - lr, vb, wb + lp
    h1x, h1y = -o1 * kd * u1x, -o1 * kd * u1y
    h2x, h2y = -o2 * kd * u2x, -o2 * kd * u2y
    h3x, h3y = -o3 * kd * u3x, -o3 * kd * u3y
    h4x, h4y = -o4 * kd * u4x, -o4 * kd * u4y
    h1z = -o1 * kz * u1z + kh * (u1x * u1x + u1y * u1y)
    h2z = -o2 * kz * u2z + kh * (u2x * u2x + u2y * u2y)
    h3z = -o3 * kz * u3z + kh * (u3x * u3x + u3y * u3y)
    h4z = -o4 * kz * u4z + kh * (u4x * u4x + u4y * u4y)
    speed = math.sqrt(ub * ub + vb * vb + wb * wb)
    fbx = h1x + h2x + h3x + h4x - speed * cdx * ub      # aerodynamic force, body
    fby = h1y + h2y + h3y + h4y - speed * cdy * vb
    fbz = h1z + h2z + h3z + h4z - speed * cdz * wb
    hr = jr * (o2 + o4 - o1 - o3)                        # the rotors' angular momentum, b3
    mx = ell * (h4z - h2z) - wq * hr                     # Σ r_i × F_i − Ω × h_r b3
    my = ell * (h3z - h1z) + wp * hr
    mz = ell * (h1y - h3y + h2x - h4x)
    a_ = uf / m
    kt = p.k_t / m
    kr = p.k_r
    return (
        vx, vy, vz,
        a_ * r13 - kt * ax + (r11 * fbx + r12 * fby + r13 * fbz) / m,
        a_ * r23 - kt * ay + (r21 * fbx + r22 * fby + r23 * fbz) / m,
        a_ * r33 - p.gravity_mps2 - kt * az + (r31 * fbx + r32 * fby + r33 * fbz) / m,
        0.5 * (-qx * wp - qy * wq - qz * wr),
        0.5 * (qw * wp + qy * wr - qz * wq),
        0.5 * (qw * wq + qz * wp - qx * wr),
        0.5 * (qw * wr + qx * wq - qy * wp),
        (tp + mx - kr * wp - (iz - iy) * wq * wr) / ix,
        (tq + my - kr * wq - (ix - iz) * wp * wr) / iy,
        (tr + mz - kr * wr - (iy - ix) * wp * wq) / iz,
    )


def rk4_air_step(p: RigidBodyParams, a: RotorAeroParams, x: Sequence[float],
                 wrench: Sequence[float], air: Sequence[float], h: float
                 ) -> tuple[float, ...]:
    """:func:`rk4_step` over :func:`derivative_air`: the wind and rotor thrusts ``air`` held
    over the step as the wrench is."""
    hh = 0.5 * h
    k1 = derivative_air(p, a, x, wrench, air)
    k2 = derivative_air(p, a, [x[i] + hh * k1[i] for i in range(13)], wrench, air)
    k3 = derivative_air(p, a, [x[i] + hh * k2[i] for i in range(13)], wrench, air)
    k4 = derivative_air(p, a, [x[i] + h * k3[i] for i in range(13)], wrench, air)
    h6 = h / 6.0
    px, py, pz, vx, vy, vz, qw, qx, qy, qz, wp, wq, wr = [
        x[i] + h6 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]) for i in range(13)]
    n = math.sqrt(qw ** 2 + qx ** 2 + qy ** 2 + qz ** 2)
    return (px, py, pz, vx, vy, vz, qw / n, qx / n, qy / n, qz / n, wp, wq, wr)


Rk4Step = Callable[[Sequence[float], Sequence[float], float], Sequence[float]]
Rk4AirStep = Callable[[Sequence[float], Sequence[float], Sequence[float], float],
                      Sequence[float]]

# The compiled rk4_step, once built: one for every airframe (its constants are an argument).
_compiled: dict[str, Any] = {"core": None}
#: Arguments shaped like :func:`rk4_step`'s (airframe, state, wrench, h), which the seam's
#: lowering reads to build it (their values are not folded in).
RK4_STEP_EXAMPLE = (RigidBodyParams(1.0, (1.0, 1.0, 1.0), 1.0, 1.0, 1.0, 1.0, 1.0),
                    (0.0,) * 13, (0.0,) * 4, 1.0)
_compiled_air: dict[str, Any] = {"core": None}
_EXAMPLE_AIR = (RK4_STEP_EXAMPLE[0],
                RotorAeroParams(1.0, 1.0, 1.0, (1.0, 1.0, 1.0), 1.0, 1.0), (0.0,) * 13,
                (0.0,) * 4, (0.0,) * 7, 1.0)


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


def compiled_rk4_step() -> Any:
    """The compiled :func:`rk4_step` this process's steppers fly — one for every airframe
    (the airframe's constants are an argument) — or None while it is not built (or
    ``TFL_MAV_NATIVE=off``, or no compiler): the Python step flies then, the same bits."""
    return _compiled["core"]


def _attach() -> None:
    """The compiled rk4_step into ``_compiled``: now if it is built, else when a background
    build completes (``auto``)."""
    if _compiled["core"] is not None:
        return

    def ready(core: Any) -> None:
        _compiled["core"] = core

    core = native.obtain_function(rk4_step, RK4_STEP_EXAMPLE, ready)
    if core is not None:
        ready(core)


def rk4_air_stepper(p: RigidBodyParams, a: RotorAeroParams, compiled: bool = True
                    ) -> Rk4AirStep:
    """``step(x, wrench, air, h)``: :func:`rk4_air_step` of the airframe ``p`` and its
    aerodynamics ``a``, compiled as :func:`rk4_stepper` compiles :func:`rk4_step` (the same
    fallbacks to the Python step)."""
    python = functools.partial(rk4_air_step, p, a)
    if not compiled or native.mode() == "off":
        return python
    if _compiled_air["core"] is None:
        def ready(core: Any) -> None:
            _compiled_air["core"] = core

        core = native.obtain_function(rk4_air_step, _EXAMPLE_AIR, ready)
        if core is not None:
            ready(core)
    plain = float
    constants = tuple(p)
    aero = (a[0], a[1], a[2], tuple(a[3]), a[4], a[5])

    def step(x: Sequence[float], wrench: Sequence[float], air: Sequence[float],
             h: float) -> Sequence[float]:
        core = _compiled_air["core"]
        if core is not None and type(x[0]) is plain:
            r = core(constants, aero, x, wrench, air, h)
            if r is not None:
                return r  # type: ignore[no-any-return]
        return python(x, wrench, air, h)

    return step
