"""The TFL law's tick (paper §V) as explicit state and one pure step.

:func:`tfl_step` is one control period: ``tfl_step(params, state, inputs, kernels) ->
(state, outputs)``, in plain Python over NamedTuples of floats, flags (bool) and codes (IntEnum),
the law's only hand-written form.
In the order the paper builds the law:

1. :func:`observe` — the attitude R(q) and the body axes bᵢ = R eᵢ (eq. (1)), relabelled to
   the canonical frame of the attacked rotor (:mod:`~tfl_mav.control.allocation`); the
   estimators (:mod:`estimators`) fed with what was applied; the Taylor rows of the output
   y = x_q from the model with the dynamic extension x13 = u_f, x14 = u̇_f (eqs. (3), (5), (9))
   plus the translational observer's unmodelled acceleration.
2. :func:`~tfl_mav.control.path.projection.project` — the virtual output along those rows:
   the closest path point (Newton on ⟨y − σ(λ), σ'(λ)⟩ = 0, eq. (13)), π's rates, α = s(y)
   and Dφ (eqs. (8), (14), (15)), on the path's generated kernels
   (:class:`~tfl_mav.control.path.projection.Kernels`, an argument).
3. :func:`command` — the ξ, η controllers (eqs. (23), (24)), the decoupling solve (eq. (21)),
   the torques (eq. (3)), the allocation (eqs. (4), (6); yaw as internal dynamics, eq. (18),
   when a rotor is attacked), saturation, the ṗ, q̇ prediction for the observer, the
   extension (eq. (9)) and the one-time switch to the fine poles.

Where the law cannot act (the projection lost, u_f too small, Dφ singular or ill-conditioned,
a non-finite result) it damps the rates and holds the thrust, and says why: ``reason`` is a
:class:`Fallback` code, the text is the holder's
(:class:`~tfl_mav.control.tfl.tfl_controller.TFLController`).
The accelerator seam (:func:`tfl_mav.accel.native.obtain_function`) compiles :func:`tfl_step`
with the path's kernels inlined (bound when it is lowered: one build per kernel set) — the
same operations in the same order, the same bits — and this very Python flies wherever it
is not built.
"""

from __future__ import annotations

import math
from enum import IntEnum
from typing import NamedTuple

from tfl_mav.control.allocation import allocate_attacked, allocate_nominal, permuted
from tfl_mav.control.path.projection import VO, Kernels, PathState, Projected, project
from tfl_mav.control.tfl.estimators import (
    DobState,
    MassModel,
    MassState,
    TdobState,
    dob_update,
    mass_update,
    tdob_update,
)
from tfl_mav.control.tfl.law_math import (
    attacked_tau_r,
    b0_inverse,
    held_rate_command,
    linear_rhs,
    output_rows,
    rate_prediction,
    rotation,
    saturate,
    solve3,
    torques,
    yaw_tau_r,
)

__all__ = ["Fallback", "Frame", "Seen", "TFLInputs", "TFLOutputs", "TFLParams", "TFLState",
           "command", "observe", "predict", "settle", "tfl_step"]


class Fallback(IntEnum):
    """Why the law fell back (``TFLOutputs.reason``): rates damped, thrust held."""

    NONE = 0            # it did not
    TUBE = 1            # the projection is lost (``TFLOutputs.vo_code`` says how)
    THRUST = 2          # u_f below ``min_thrust_n``: D(x) singular
    COND = 3            # cond(Dφ) above ``max_cond``
    NONFINITE = 4       # the decoupling solve gave a non-finite ü_f, ṗ or q̇


V3 = tuple[float, float, float]
V4 = tuple[float, float, float, float]
I4 = tuple[int, int, int, int]
_INF4 = (math.inf, math.inf, math.inf, math.inf)
_ZERO4 = (0.0, 0.0, 0.0, 0.0)


class TFLParams(NamedTuple):
    """The law's constants for one flight (SI units)."""

    dt_s: float                 # control period (s)
    gravity_mps2: float
    k_t: float                  # translational drag (N s/m)
    k_r: float                  # rotational drag (N m s)
    arm_m: float                # l
    thrust_max_n: float         # f_max per rotor
    iz_kgm2: float              # I_z (μ2, eq. (18))
    speed_mps: float            # the η chain's speed along the path
    min_thrust_n: float         # u_f below this: D(x) singular, fall back
    max_cond: float             # cond(Dφ) above this: fall back
    tube_min: float             # the projection's margin below this: the tube is left
    settle_alpha: float         # |α| below this …
    settle_time_s: float        # … for this long switches to the fine poles
    use_mass: bool              # the mass estimator runs
    use_dob: bool               # the rate disturbance observer runs
    use_switch: bool            # the one-time switch to the fine poles
    mass: MassModel             # the mass estimator's constants
    dob_tau_s: float            # the observer's filter (s)
    dob_limit: float            # |d| ≤ this (rad/s²)
    use_tdob: bool              # the translational disturbance observer runs
    tdob_tau_s: float           # its filter (s)
    tdob_limit: float           # |d| ≤ this per axis (m/s²)
    tdob_vertical: bool         # it estimates the vertical too
    k_xi: V4                    # ξ chain gains k₀…k₃ (eq. (23))
    k_eta: V3                   # η chain gains k₀…k₂ (eq. (24))
    k_xi_fine: V4               # the same after the switch
    k_eta_fine: V3
    k_yaw: tuple[float, float]  # the nominal yaw loop's gains k₀, k₁


class Frame(NamedTuple):
    """The canonical frame of the attacked rotor (:func:`allocation.canonical_frame`) as
    numbers: b1' = s1 · (column m1 of R), p' = s1 · Ω[m1] (m ∈ {0, 1}), likewise b2', q'."""

    attacked: bool              # a rotor is attacked (f₂' = A); False: all four are ours
    m1: int
    s1: float
    m2: int
    s2: float
    ixyz: V3                    # (I_x', I_y', I_z') kg m²
    d_m: float                  # the yaw-reaction ratio d' (m)
    perm: I4                    # the physical rotor (0-3) of canonical rotor i
    inv_perm: I4                # the canonical rotor of physical rotor j
    mu_den: float               # 2 I_x d' (μ2 = −p/I_z − l r/(2 I_x d), eq. (18))


class TFLState(NamedTuple):
    """Everything the law remembers between ticks."""

    x13: float                  # u_f (N), the dynamic extension (eq. (9))
    x14: float                  # u̇_f (N/s)
    mass: MassState
    dob: DobState
    tdob: TdobState             # the translational observer (paper frame, horizontal)
    has_pred: bool              # ``pred`` holds the model's ṗ, q̇ for the last command
    pred: tuple[float, float]   # (rad/s²)
    last_out: V4                # the thrusts the rotors deliver over the last period (N)
    has_psi_ref: bool           # ``psi_ref`` is set
    psi_ref: float              # the nominal law's yaw set point (rad)
    fine: bool                  # the fine poles
    settled_s: float            # time |α| has stayed below ``settle_alpha`` (s)
    path: PathState


class TFLInputs(NamedTuple):
    """One tick's measurements and what the holder decided (paper frame: ENU, body FLU)."""

    position_m: V3
    velocity_mps: V3
    quaternion_wxyz: V4
    body_rates_radps: V3
    frame: Frame
    attack_n: float             # the attacked rotor's thrust estimate (N)
    lo_n: V4                    # what each physical rotor can reach this period (N)
    hi_n: V4
    lam_start: float            # λ of a global search when the state has none
    lam_start_ok: bool          # that search converged
    path_failed: bool           # evaluating the path raised (the holder has the error)


class TFLOutputs(NamedTuple):
    """One decision (physical rotor order, N) and the internals worth logging."""

    command_n: V4               # thrusts within [0, f_max]; the attacked rotor: A
    attacked: bool              # the attacked law flew
    saturated: tuple[bool, bool, bool, bool]    # that rotor's unbounded demand left
                                                # [0, f_max]
    xi: tuple[V4, V4]           # (α1, α̇1, α̈1, α⃛1), the same for α2
    eta: V4                     # (π, π̇, π̈, π⃛)
    mu: tuple[float, float]     # (ψ, μ2), eq. (18)
    distance_m: float           # to the closest path point (NaN: none)
    lam: float
    cond: float                 # cond(Dφ)
    uf_n: float                 # u_f this tick
    mass_kg: float              # the mass the law used
    dob: tuple[float, float]    # the observer's estimate (rad/s²)
    fine: bool
    reason: Fallback            # why it fell back (Fallback.NONE: it did not)
    vo_code: VO                 # what the projection found
    margin: float               # the projection's margin (VO.MARGIN's)
    rates: V3                   # canonical (p, q, r) rad/s: :func:`predict`'s
    saturated_any: bool
    demand_n: V4                # the unbounded allocation (N, physical): what the law asks


class Seen(NamedTuple):
    """The state as the law sees it this tick (:func:`observe`)."""

    psi: float                  # ψ = atan2(R₁₀, R₀₀) (rad)
    r2: V3                      # R's last row
    b1: V3                      # the canonical body axes b1', b2', b3 (eq. (1))
    b2: V3
    b3: V3
    rates: V3                   # canonical (p, q, r) rad/s
    mass: MassState             # the estimators after this tick
    dob: DobState
    mass_kg: float              # the mass the law uses
    rows: tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]
                                # the output's Taylor rows x, y, z, each (y, ẏ, ÿ/2, y⃛/6,
                                # a₀/24), eqs. (3), (5), (9)
    tdob: TdobState


def observe(p: TFLParams, s: TFLState, u: TFLInputs) -> Seen:
    """The state seen by the law (:class:`Seen`): ψ, R's last row, the canonical b1', b2',
    b3 and (p, q, r), the estimators fed with what was applied, and the output's Taylor
    rows."""
    fr = u.frame
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = rotation(u.quaternion_wxyz)
    psi = math.atan2(r10, r00)
    row0, row1, row2 = (r00, r01, r02), (r10, r11, r12), (r20, r21, r22)
    m1, s1, m2, s2 = fr.m1, fr.s1, fr.m2, fr.s2
    b1 = (s1 * row0[m1], s1 * row1[m1], s1 * row2[m1])
    b2 = (s2 * row0[m2], s2 * row1[m2], s2 * row2[m2])
    b3 = (r02, r12, r22)
    w = u.body_rates_radps
    pc, qc, rc = s1 * w[m1], s2 * w[m2], w[2]
    v = u.velocity_mps
    # The estimators, fed with what was applied over the last period.
    mass_s = s.mass
    if p.use_mass:
        lo = s.last_out
        mass_s = mass_update(p.mass, mass_s, p.dt_s, v, lo[0] + lo[1] + lo[2] + lo[3], b3)
    dob_s = s.dob
    if p.use_dob and s.has_pred:
        dob_s = dob_update(p.dob_tau_s, p.dob_limit, dob_s, p.dt_s, pc, qc, rc, s.pred[0],
                           s.pred[1])
    mass = mass_s.mass_kg
    tdob_s = s.tdob
    if p.use_tdob:
        lo = s.last_out
        tdob_s = tdob_update(p.tdob_tau_s, p.tdob_limit, tdob_s, p.dt_s, v,
                             lo[0] + lo[1] + lo[2] + lo[3], b3, mass, p.k_t, p.gravity_mps2,
                             p.tdob_vertical)
    rows = output_rows(u.position_m, v, b1, b2, b3, pc, qc, rc, s.x13, s.x14, mass, p.k_t,
                       p.gravity_mps2, (tdob_s.d_x, tdob_s.d_y, tdob_s.d_z))
    return Seen(psi, (r20, r21, r22), b1, b2, b3, (pc, qc, rc), mass_s, dob_s, mass, rows,
                tdob_s)


def predict(p: TFLParams, fr: Frame, delivered: V4, rates: V3) -> tuple[float, float]:
    """ṗ, q̇ the model predicts (eq. (3)) for the thrusts the physical rotors deliver
    (N) at the canonical rates (p, q, r): what the observer compares the next tick with."""
    pc, qc, rc = rates
    ix, iy, iz = fr.ixyz
    d0, d1, d2, d3 = permuted(delivered, fr.perm)   # canonical order
    return rate_prediction(d0, d1, d2, d3, pc, qc, rc, ix, iy, iz, p.k_r, p.arm_m)


def command(p: TFLParams, s: TFLState, u: TFLInputs, seen: Seen, vo: Projected,
            ps: PathState) -> tuple[TFLState, TFLOutputs]:
    """The rest of the tick from what :func:`observe` saw and the virtual output ``vo``
    (:func:`project`'s, or the reference tracker's as the same type)."""
    psi, b1, b2, b3, mass = seen.psi, seen.b1, seen.b2, seen.b3, seen.mass_kg
    xi1, xi2, eta = vo.xi1, vo.xi2, vo.eta
    pc, qc, rc = seen.rates
    fr = u.frame
    uf, duf = s.x13, s.x14
    fine = s.fine
    # The regular feedback (eq. (21)): w = (ü_f, ṗ, q̇) with Dφ B₀ w = v − L_f⁴φ, v the linear
    # ξ, η controllers (eqs. (23), (24)), Dφ B₀ the decoupling matrix (eq. (15)).
    kx = p.k_xi_fine if fine else p.k_xi
    ke = p.k_eta_fine if fine else p.k_eta
    rhs = linear_rhs(xi1, xi2, eta, kx, ke, p.speed_mps)
    reason = Fallback.NONE
    if vo.code != VO.OK:
        reason = Fallback.TUBE
    elif uf < p.min_thrust_n:
        reason = Fallback.THRUST
    # First Dφ z = rhs (z = B₀ w, the commanded snap) …
    z, rel = solve3(vo.jacobian, rhs)
    cond = 1.0 / rel if rel > 0 else math.inf
    if reason == Fallback.NONE and cond > p.max_cond:
        reason = Fallback.COND
    # … then B₀ w = z with B₀ = [b3/m, −(u_f/m) b2, (u_f/m) b1]: orthogonal columns.
    if uf > 0:
        udd, pdot, qdot = b0_inverse(z, b1, b2, b3, mass, uf)
        # The torque is held over the tick while the body spins under it (eq. (3)).
        pdot, qdot = held_rate_command(pdot, qdot, rc, p.dt_s, fr.ixyz)
    else:
        udd, pdot, qdot = mass * (z[0] * b3[0] + z[1] * b3[1] + z[2] * b3[2]), 0.0, 0.0
    if reason == Fallback.NONE and not (math.isfinite(udd) and math.isfinite(pdot)
                                        and math.isfinite(qdot)):
        reason = Fallback.NONFINITE
    if reason != Fallback.NONE:     # rates damped, thrust held
        udd, pdot, qdot = -4.0 * duf, -20.0 * pc, -20.0 * qc
    if p.use_dob:
        pdot -= seen.dob.d_p
        qdot -= seen.dob.d_q
    ix, iy, iz = fr.ixyz
    tau_p, tau_q = torques(pdot, qdot, pc, qc, rc, ix, iy, iz, p.k_r)
    # The rotors: f₂' = A and τ_r from τ_p (eq. (6)), or all four with the yaw loop.
    fmax, arm, d = p.thrust_max_n, p.arm_m, fr.d_m
    a_n = u.attack_n
    psi_ref = s.psi_ref if s.has_psi_ref else psi
    if fr.attacked:
        lo, hi = permuted(u.lo_n, fr.perm), permuted(u.hi_n, fr.perm)   # canonical order
        tau_r = attacked_tau_r(uf, tau_p, a_n, arm, d)
        raw_c = allocate_attacked(uf, tau_q, tau_r, a_n, arm, d, math.inf, (_ZERO4, _INF4))
        f_c = allocate_attacked(uf, tau_q, tau_r, a_n, arm, d, fmax, (lo, hi))
        raw, f = permuted(raw_c, fr.inv_perm), permuted(f_c, fr.inv_perm)  # physical order
    else:
        tau_r = yaw_tau_r(seen.r2, psi, psi_ref, pc, qc, rc, qdot, p.k_yaw, fr.ixyz, p.k_r)
        raw = allocate_nominal(uf, tau_p, tau_q, tau_r, arm, d, math.inf, (_ZERO4, _INF4))
        f = allocate_nominal(uf, tau_p, tau_q, tau_r, arm, d, fmax, (u.lo_n, u.hi_n))
    # Clip to [0, f_max]; the attacked rotor is given what it is (not ours to command).
    f, sat = saturate(f, raw, s.last_out, fmax)
    if fr.attacked:
        attacked = fr.perm[1]       # canonical rotor 2's physical index
        f = (a_n if attacked == 0 else f[0], a_n if attacked == 1 else f[1],
             a_n if attacked == 2 else f[2], a_n if attacked == 3 else f[3])
    sat_any = sat[0] or sat[1] or sat[2] or sat[3]
    applied_uf = f[0] + f[1] + f[2] + f[3]
    pred = predict(p, fr, f, seen.rates)
    # The dynamic extension (eq. (9)), kept consistent with the thrust actually applied
    # (anti-windup at the limits).
    dt = p.dt_s
    x13, x14 = uf, duf
    if abs(applied_uf - uf) > 1e-9:
        x13 = applied_uf
        if (applied_uf - uf) * duf < 0:
            x14 = 0.0
    x13 = x13 + (dt * x14 + 0.5 * dt * dt * udd)
    x14 = x14 + dt * udd
    settled = s.settled_s
    if reason == Fallback.NONE:
        fine, settled = settle(p, fine, settled, math.hypot(xi1[0], xi2[0]), dt)
    wp, _wq, wr = u.body_rates_radps
    state = TFLState(x13, x14, seen.mass, seen.dob, seen.tdob, True, pred, f, True, psi_ref,
                     fine, settled, ps)
    out = TFLOutputs(
        f, fr.attacked, (sat[0], sat[1], sat[2], sat[3]),
        ((xi1[0], xi1[1], xi1[2], xi1[3]), (xi2[0], xi2[1], xi2[2], xi2[3])),
        (eta[0], eta[1], eta[2], eta[3]), (psi, -wp / p.iz_kgm2 - arm * wr / fr.mu_den),
        vo.distance_m, vo.lam, cond, uf, mass, (seen.dob.d_p, seen.dob.d_q), fine, reason,
        vo.code, vo.margin, seen.rates, sat_any, (raw[0], raw[1], raw[2], raw[3]))
    return state, out



def settle(p: TFLParams, fine: bool, settled_s: float, alpha_m: float, dt_s: float
           ) -> tuple[bool, float]:
    """The one-time switch to the fine ξ, η poles: (fine, settled_s) after a tick ``dt_s``
    the vehicle flew |α| = ``alpha_m`` (m) from the path. Fine once |α| has stayed below
    ``settle_alpha`` for ``settle_time_s`` — whichever law held it there
    (:meth:`~tfl_mav.control.tfl.tfl_controller.TFLController.settle_on`)."""
    if p.use_switch and not fine:
        settled_s = settled_s + dt_s if alpha_m < p.settle_alpha else 0.0
        if settled_s >= p.settle_time_s:
            fine = True
    return fine, settled_s

def tfl_step(p: TFLParams, s: TFLState, u: TFLInputs, k: Kernels
             ) -> tuple[TFLState, TFLOutputs]:
    """One control period of the law (module doc) on the path of kernels ``k``: the new
    state and the decision."""
    seen = observe(p, s, u)
    vo, ps = project(k, p.tube_min, s.path, seen.rows, u.lam_start, u.lam_start_ok,
                     u.path_failed)
    return command(p, s, u, seen, vo, ps)
