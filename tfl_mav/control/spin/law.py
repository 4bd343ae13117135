"""Building the spin law: its table of equilibria and gains, and the state it starts from.

:func:`build` solves the relaxed hover (:mod:`equilibrium`) on a grid of f_stuck and designs
the reduced-attitude LQR along the spin-up schedule of :mod:`step` at each, once, before the
flight (numpy only; ~3 s). :func:`initial_state` is the state to enter with from any
vehicle state: the integral empty and ρ read from the body rates, so the first tick already
flies the schedule point the vehicle is at (bumpless: nothing in the law's state depends on
what the previous law did).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from tfl_mav.accel.background import BackgroundLaw
from tfl_mav.control.allocation import canonical_frame
from tfl_mav.control.safe.lqr import dlqr, zoh
from tfl_mav.control.spin import equilibrium
from tfl_mav.control.spin.equilibrium import Airframe, Equilibrium, reduced_model
from tfl_mav.control.spin.step import (
    RHO_MAX,
    RHO_STEPS,
    RHO_TILT,
    Gain,
    SpinHover,
    SpinInputs,
    SpinOutputs,
    SpinParams,
    SpinRow,
    SpinState,
    hover_at,
    mat3,
    spin_step,
)

__all__ = ["LQR_Q", "LQR_R", "POS_OMEGA", "STEP_INPUTS_EXAMPLE", "SpinLaw", "build",
           "equilibrium_or_closest", "initial_state", "schedule_forces", "table_row",
           "weight_range"]

# LQR weights on (p, q, n_x, n_y) and (τ_p, τ_q): Bryson's rule with 10 rad/s of rate error,
# 0.1 of axis error (≈ 6°) and 0.2 N m of torque. A lagging rotor cannot swing a body-fixed
# torque at the spin rate: the torque weight grows by 1 + (Ω τ_m)² (the lag's gain loss²).
LQR_Q = (0.01, 0.01, 100.0, 100.0)
LQR_R = (25.0, 25.0)
POS_OMEGA = 1.0             # outer-loop triple pole (rad/s)
MAX_TILT_DEG = 20.0         # the mean axis tilts at most this far from vertical
MAX_VERTICAL_G = 0.3
MAX_INTEGRAL_G = 0.2


def _schedule_point(eq: Equilibrium, rho: float) -> tuple[tuple[float, float, float],
                                                           tuple[float, float, float]]:
    """(ω_ref, n_ref) of the spin-up schedule at ρ (:mod:`step`, 4.)."""
    nbx, nby, nbz = eq.axis
    cone = math.acos(min(1.0, nbz))
    horiz = math.hypot(nbx, nby)
    th = cone * min(1.0, (rho / RHO_TILT) ** 2)
    ux, uy = (nbx / horiz, nby / horiz) if horiz > 0 else (0.0, 0.0)
    n = (math.sin(th) * ux, math.sin(th) * uy, math.cos(th))
    om = rho * eq.spin_radps
    return (om * n[0], om * n[1], om * n[2]), n


def schedule_forces(a: Airframe, eq: Equilibrium, rho: float
                    ) -> tuple[tuple[float, float, float, float], float]:
    """The rotor forces (canonical) that hold the spin ρ Ω̄ about the axis n̄ (E1) and the
    mean vertical force f_Σ n̄_z they make: the equilibria of other weights on the same axis."""
    ix, iy, iz = a.inertia_kgm2
    om = rho * eq.spin_radps
    wx, wy, wz = (om * c for c in eq.axis)
    tp = a.k_r * wx + (iz - iy) * wy * wz
    tq = a.k_r * wy + (ix - iz) * wx * wz
    tr = a.k_r * wz + (iy - ix) * wx * wy
    f2 = eq.f_stuck_n
    f4 = f2 + tp / a.arm_m
    s13 = f2 + f4 + tr / a.drag_m
    half = 0.5 * tq / a.arm_m
    f = (0.5 * s13 - half, f2, 0.5 * s13 + half, f4)
    return f, sum(f) * eq.axis[2]


def weight_range(a: Airframe, eq: Equilibrium, margin_n: float = 0.5) -> tuple[float, float]:
    """(W_lo, W_hi): the mean vertical forces (N) the spins ρ ∈ [ρ₀, RHO_MAX] on the axis n̄
    make with f1, f3, f4 at least ``margin_n`` inside [0, f_max] (the room the attitude loop
    needs); the equilibrium's own m g always inside."""
    fm = a.thrust_max_n
    ws = []
    for rho in np.linspace(RHO_TILT, RHO_MAX, 91):
        f, w = schedule_forces(a, eq, float(rho))
        if all(margin_n <= f[i] <= fm - margin_n for i in (0, 2, 3)):
            ws.append(w)
    w0 = sum(eq.thrusts_n) * eq.axis[2]
    return (min([*ws, w0]), max([*ws, w0]))


def table_row(a: Airframe, eq: Equilibrium, exists: bool, weight_n: float, dt_s: float,
              motor_time_constant_s: float = 0.0) -> SpinRow:
    """One row of :attr:`SpinParams.table`: the relaxed hover ``eq`` (``exists``: it holds
    m g; else it is the closest spin, of mean vertical force ``weight_n``) and its gains."""
    tau = max(0.0, motor_time_constant_s)
    scale = 1.0 + (eq.spin_radps * tau) ** 2
    q = np.diag(LQR_Q)
    r = np.diag(LQR_R) * scale
    gains: list[Gain] = []
    for j in range(RHO_STEPS + 1):
        w, n = _schedule_point(eq, j * RHO_MAX / RHO_STEPS)
        k = dlqr(*zoh(*reduced_model(a.inertia_kgm2, a.k_r, w, n), dt_s), q, r)
        (kp1, kp2, kp3, kp4), (kq1, kq2, kq3, kq4) = k.tolist()   # the τ_p and τ_q rows
        gains.append(((kp1, kp2, kp3, kp4), (kq1, kq2, kq3, kq4)))
    f1, _, f3, f4 = eq.thrusts_n
    excess = 0.0 if exists else (weight_n - a.mass_kg * a.gravity_mps2) / a.mass_kg
    w_lo, w_hi = weight_range(a, eq)
    wx, wy, wz = eq.rates_radps
    nx, ny, nz = eq.axis
    hover = SpinHover(
        float(eq.f_stuck_n), exists, float(f4), float(f1 + f3),
        (float(wx), float(wy), float(wz)), (float(nx), float(ny), float(nz)),
        float(eq.spin_radps), float(eq.total_n), float(eq.cone_rad),
        float(eq.radius_m), float(excess), float(eq.margin_n), float(w_lo), float(w_hi))
    return SpinRow(hover, tuple(gains))


def equilibrium_or_closest(a: Airframe, f_stuck: float) -> tuple[Equilibrium, bool, float]:
    """(the relaxed hover holding m g, True, m g) — or, where none exists, the spin whose
    mean vertical force comes closest to m g (the least climb or sink; inside a gap of the
    family the nearest sink before any climb), False, that force."""
    mg = a.mass_kg * a.gravity_mps2
    eq = equilibrium.solve(a, f_stuck, symmetric=True)
    if eq is not None:
        return eq, True, mg
    lo, hi = equilibrium.vertical_range(a, f_stuck)
    if lo <= mg <= hi:
        # m g inside the range but in a gap of the family (a slow yaw drag: the spins that
        # hold the weight need more torque than the rotors have). The nearest spin *below*
        # m g first: it sinks, along the path's vertical, to the ground — bounded; a spin
        # above climbs without end (an escape), the last resort.
        tries = [mg * k for k in (0.97, 0.94, 0.9, 0.85, 0.8, 0.7, 0.6, 0.5)]
        tries += [mg * k for k in (1.03, 1.06, 1.1, 1.2, 1.4, 1.7)]
    else:
        tries = [min(max(mg, lo + (1 - frac) * (hi - lo)), lo + frac * (hi - lo))
                 for frac in (0.98, 0.95, 0.9, 0.8)]
    for w in tries:
        eq = equilibrium.solve(a, f_stuck, weight_n=w, symmetric=True) or equilibrium.solve(
            a, f_stuck, weight_n=w)
        if eq is not None:
            return eq, False, w
    raise ValueError(f"no relaxed hover of any vertical force with a rotor at {f_stuck:.2f} N "
                     "(the airframe cannot balance the stuck rotor's torque at all)")


def build(vehicle: object, rotor: int, dt_s: float, *, mass_scale: float = 1.0,
          inertia_scale: float = 1.0, motor_time_constant_s: float = 0.0,
          f_stuck_grid: Sequence[float] | None = None) -> SpinParams:
    """The spin law's constants for a scenario's ``vehicle`` section with ``rotor`` (1-4)
    attacked, the controller's model off by ``mass_scale``/``inertia_scale``, rotors of time
    constant ``motor_time_constant_s`` and control period ``dt_s``. The table spans f_stuck
    from m g/2 − 0.5 N (rounded down to 0.5 N) to f_max in 0.5 N steps
    unless ``f_stuck_grid`` is given. ValueError, in one line with the airframe's numbers and
    the thrusts at which no spin of any vertical force exists, if there are any."""
    a = equilibrium.airframe_from_scenario(vehicle, rotor, mass_scale, inertia_scale)
    mg = a.mass_kg * a.gravity_mps2
    if f_stuck_grid is None:
        lo = max(0.5, math.floor(2.0 * (0.5 * mg - 0.5)) / 2.0)
        f_stuck_grid = list(np.arange(lo, a.thrust_max_n + 1e-9, 0.5))
    rows = []
    missing = []
    for f in f_stuck_grid:
        try:
            eq, exists, w = equilibrium_or_closest(a, float(f))
        except ValueError:
            missing.append(float(f))
            continue
        rows.append(table_row(a, eq, exists, w, dt_s, motor_time_constant_s))
    if missing:
        # A table with holes would be interpolated (or clamped) across them: a spin flown
        # where none exists. The law is built for the whole band or not at all.
        raise ValueError(
            f"no relaxed hover with rotor {rotor} pinned at "
            f"{', '.join(f'{f:g}' for f in missing)} N for this airframe (m = {a.mass_kg:.2f} kg, "
            f"J = {', '.join(f'{j:.2e}' for j in a.inertia_kgm2)} kg m^2, "
            f"yaw drag {abs(a.drag_m):.4f} m, k_r = {a.k_r:.2e} N m s): the spin law cannot fly")
    fr = canonical_frame(rotor)
    w_p = POS_OMEGA
    g = a.gravity_mps2
    ki = w_p ** 3
    return SpinParams(
        a.mass_kg, a.inertia_kgm2, a.arm_m, a.drag_m, a.k_r, a.k_t, g, a.thrust_max_n,
        float(dt_s), mat3(fr.rot),
        fr.perm, 3.0 * w_p * w_p, 3.0 * w_p, ki, math.tan(math.radians(MAX_TILT_DEG)),
        MAX_VERTICAL_G * g, MAX_INTEGRAL_G * g / ki, tuple(rows))


def initial_state(params: SpinParams, body_rates_radps: Sequence[float] = (0.0, 0.0, 0.0),
                  stuck_thrust_n: float | None = None) -> SpinState:
    """The state to enter with: no integral, ρ from the rates (reported only; the step
    recomputes it every tick from the measurement, so any entry state is bumpless)."""
    _, _, (r20, r21, r22) = params.rot
    wp, wq, wr = body_rates_radps
    w2 = r20 * wp + r21 * wq + r22 * wr
    f = params.table[-1].hover.f_stuck_n if stuck_thrust_n is None else stuck_thrust_n
    _, _, wbz = hover_at(params.table, f).rates_radps
    rho = min(RHO_MAX, max(0.0, w2 / wbz)) if wbz != 0.0 else 1.0
    return SpinState((0.0, 0.0, 0.0), rho)


_ZERO3 = (0.0, 0.0, 0.0)
# spin_step's inputs' shape, for the seam's lowering (its kinds: floats)
STEP_INPUTS_EXAMPLE = SpinInputs(_ZERO3, _ZERO3, (1.0, 0.0, 0.0, 0.0), _ZERO3, 0.0, _ZERO3,
                                 _ZERO3, _ZERO3)


class SpinLaw(BackgroundLaw[SpinParams, SpinState, SpinInputs, SpinOutputs]):
    """The spin law built for one airframe and rotor: its constants (:attr:`params`) and its
    step (:func:`~tfl_mav.control.spin.step.spin_step`), compiled by the accelerator seam for
    a table of their shape in the background (a build takes ~15 s of compiler; a law is made
    in flight, as the attack nears m g/2): :class:`BackgroundLaw`."""

    def __init__(self, params: SpinParams) -> None:
        super().__init__(spin_step, params, initial_state(params), STEP_INPUTS_EXAMPLE)
