"""The TFL law's tick (paper §V) as explicit state and one pure step.

:func:`tfl_step` is one control period: ``tfl_step(params, state, inputs) -> (state,
outputs)``, in plain Python over NamedTuples of floats, the law's only hand-written form.
In the order the paper builds the law:

1. :func:`observe` — the attitude R(q) and the body axes bᵢ = R eᵢ (eq. (1)), relabelled to
   the canonical frame of the attacked rotor (:mod:`~tfl_mav.control.allocation`); the
   estimators (:mod:`estimators`) fed with what was applied; the Taylor rows of the output
   y = x_q from the model with the dynamic extension x13 = u_f, x14 = u̇_f (eqs. (3), (5), (9))
   plus the translational observer's unmodelled acceleration.
2. :func:`~tfl_mav.control.path.projection.project` — the virtual output along those rows:
   the closest path point (Newton on ⟨y − σ(λ), σ'(λ)⟩ = 0, eq. (13)), π's rates, α = s(y)
   and Dφ (eqs. (8), (14), (15)), on the path's generated kernels (linked in per path by
   :func:`linked`).
3. :func:`command` — the ξ, η controllers (eqs. (23), (24)), the decoupling solve (eq. (21)),
   the torques (eq. (3)), the allocation (eqs. (4), (6); yaw as internal dynamics, eq. (18),
   when a rotor is attacked), saturation, the ṗ, q̇ prediction for the observer, the
   extension (eq. (9)) and the one-time switch to the fine poles.

Where the law cannot act (the projection lost, u_f too small, Dφ singular or ill-conditioned,
a non-finite result) it damps the rates and holds the thrust, and says why: ``reason`` is one
of the ``R_*`` codes, the text is the holder's (:class:`~tfl_mav.control.tfl.law.TFLController`).
The accelerator seam (:func:`tfl_mav.accel.native.obtain_function`) compiles :func:`tfl_step`
with the path's kernels inlined — the same operations in the same order, the same bits —
and this very Python flies wherever it is not built.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

from tfl_mav.accel.frontend import relinked
from tfl_mav.control.allocation import allocate_attacked, allocate_nominal
from tfl_mav.control.path import projection
from tfl_mav.control.path.projection import VO_OK, PathState, project
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

__all__ = ["R_COND", "R_NONE", "R_NONFINITE", "R_THRUST", "R_TUBE", "Frame", "TFLInputs",
           "TFLOutputs", "TFLParams", "TFLState", "command", "linked", "observe", "predict",
           "tfl_step"]

# Why the law fell back (``TFLOutputs.reason``).
R_NONE, R_TUBE, R_THRUST, R_COND, R_NONFINITE = 0.0, 1.0, 2.0, 3.0, 4.0

V3 = tuple[float, float, float]
V4 = tuple[float, float, float, float]
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
    use_mass: float             # 1.0: the mass estimator runs
    use_dob: float              # 1.0: the rate disturbance observer runs
    use_switch: float           # 1.0: the one-time switch to the fine poles
    mass: MassModel             # the mass estimator's constants
    dob_tau_s: float            # the observer's filter (s)
    dob_limit: float            # |d| ≤ this (rad/s²)
    use_tdob: float             # 1.0: the translational disturbance observer runs
    tdob_tau_s: float           # its filter (s)
    tdob_limit: float           # |d| ≤ this per axis (m/s²)
    tdob_vertical: float        # 1.0: it estimates the vertical too
    k_xi: V4                    # ξ chain gains k₀…k₃ (eq. (23))
    k_eta: V3                   # η chain gains k₀…k₂ (eq. (24))
    k_xi_fine: V4               # the same after the switch
    k_eta_fine: V3
    k_yaw: tuple[float, float]  # the nominal yaw loop's gains k₀, k₁


class Frame(NamedTuple):
    """The canonical frame of the attacked rotor (:func:`allocation.canonical_frame`) as
    numbers: b1' = s1 · (column m1 of R), p' = s1 · Ω[m1] (m ∈ {0, 1}), likewise b2', q'."""

    attacked: float             # 1.0: a rotor is attacked (f₂' = A), 0.0: all four are ours
    m1: float
    s1: float
    m2: float
    s2: float
    ixyz: V3                    # (I_x', I_y', I_z') kg m²
    d_m: float                  # the yaw-reaction ratio d' (m)
    perm: V4                    # the physical rotor (0-3) of canonical rotor i
    inv_perm: V4                # the canonical rotor of physical rotor j
    mu_den: float               # 2 I_x d' (μ2 = −p/I_z − l r/(2 I_x d), eq. (18))


class TFLState(NamedTuple):
    """Everything the law remembers between ticks."""

    x13: float                  # u_f (N), the dynamic extension (eq. (9))
    x14: float                  # u̇_f (N/s)
    mass: MassState
    dob: DobState
    tdob: TdobState             # the translational observer (paper frame, horizontal)
    has_pred: float             # 1.0: ``pred`` holds the model's ṗ, q̇ for the last command
    pred: tuple[float, float]   # (rad/s²)
    last_out: V4                # the thrusts the rotors deliver over the last period (N)
    has_psi_ref: float
    psi_ref: float              # the nominal law's yaw set point (rad)
    fine: float                 # 1.0: the fine poles
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
    lam_start_ok: float         # 1.0: that search converged
    path_failed: float          # 1.0: evaluating the path raised (the holder has the error)


class TFLOutputs(NamedTuple):
    """One decision (physical rotor order, N) and the internals worth logging."""

    command_n: V4               # thrusts within [0, f_max]; the attacked rotor: A
    attacked: float             # 1.0: the attacked law flew
    saturated: V4               # 1.0: that rotor's unbounded demand left [0, f_max]
    xi: tuple[V4, V4]           # (α1, α̇1, α̈1, α⃛1), the same for α2
    eta: V4                     # (π, π̇, π̈, π⃛)
    mu: tuple[float, float]     # (ψ, μ2), eq. (18)
    distance_m: float           # to the closest path point (NaN: none)
    lam: float
    cond: float                 # cond(Dφ)
    uf_n: float                 # u_f this tick
    mass_kg: float              # the mass the law used
    dob: tuple[float, float]    # the observer's estimate (rad/s²)
    fine: float
    reason: float               # R_*: why it fell back (R_NONE: it did not)
    vo_code: float              # VO_*: what the projection found
    margin: float               # the projection's margin (VO_MARGIN's)
    rates: V3                   # canonical (p, q, r) rad/s: :func:`predict`'s
    saturated_any: float
    demand_n: V4                # the unbounded allocation (N, physical): what the law asks


def _pick(values: tuple[float, ...], k: float) -> float:
    """``values[k]`` for a k of 0.0-3.0 (an index the compiled form can take)."""
    return values[0] if k == 0.0 else (values[1] if k == 1.0 else (
        values[2] if k == 2.0 else values[3]))


def _permuted(values: V4, perm: V4) -> V4:
    """(values[perm[0]], …, values[perm[3]])."""
    return (_pick(values, perm[0]), _pick(values, perm[1]), _pick(values, perm[2]),
            _pick(values, perm[3]))


def observe(p: TFLParams, s: TFLState, u: TFLInputs) -> tuple[Any, ...]:
    """The state seen by the law: ψ, R's last row, the canonical b1, b2, b3 and (p, q, r),
    the estimators after this tick, the mass used and the output's Taylor rows (x, y, z,
    each (y, ẏ, ÿ/2, y⃛/6, a₀/24), eqs. (3), (5), (9))."""
    fr = u.frame
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = rotation(u.quaternion_wxyz)
    psi = math.atan2(r10, r00)
    m1, s1, m2, s2 = fr.m1, fr.s1, fr.m2, fr.s2
    b1 = (s1 * (r00 if m1 == 0.0 else r01), s1 * (r10 if m1 == 0.0 else r11),
          s1 * (r20 if m1 == 0.0 else r21))
    b2 = (s2 * (r00 if m2 == 0.0 else r01), s2 * (r10 if m2 == 0.0 else r11),
          s2 * (r20 if m2 == 0.0 else r21))
    b3 = (r02, r12, r22)
    wp, wq, wr = u.body_rates_radps
    pc = s1 * (wp if m1 == 0.0 else wq)
    qc = s2 * (wp if m2 == 0.0 else wq)
    rc = wr
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
    return psi, (r20, r21, r22), b1, b2, b3, (pc, qc, rc), mass_s, dob_s, mass, rows, tdob_s


def predict(p: TFLParams, fr: Frame, delivered: V4, rates: V3) -> tuple[float, float]:
    """ṗ, q̇ the model predicts (eq. (3)) for the thrusts the physical rotors deliver
    (N) at the canonical rates (p, q, r): what the observer compares the next tick with."""
    pc, qc, rc = rates
    ix, iy, iz = fr.ixyz
    d0, d1, d2, d3 = _permuted(delivered, fr.perm)
    return rate_prediction(d0, d1, d2, d3, pc, qc, rc, ix, iy, iz, p.k_r, p.arm_m)


def command(p: TFLParams, s: TFLState, u: TFLInputs, seen: tuple[Any, ...],
            vo: tuple[Any, ...], ps: PathState) -> tuple[TFLState, TFLOutputs]:
    """The rest of the tick from what :func:`observe` saw and the virtual output ``vo``
    (:func:`project`'s, or the reference tracker's packed the same way)."""
    psi, r2, b1, b2, b3, rates, mass_s, dob_s, mass, _rows, tdob_s = seen
    code, xi1, xi2, eta, jac, lam, distance, margin = vo
    pc, qc, rc = rates
    fr = u.frame
    uf, duf = s.x13, s.x14
    fine = s.fine
    # The regular feedback (eq. (21)): w = (ü_f, ṗ, q̇) with Dφ B₀ w = v − L_f⁴φ, v the linear
    # ξ, η controllers (eqs. (23), (24)), Dφ B₀ the decoupling matrix (eq. (15)).
    kx = p.k_xi_fine if fine else p.k_xi
    ke = p.k_eta_fine if fine else p.k_eta
    rhs = linear_rhs(xi1, xi2, eta, kx, ke, p.speed_mps)
    reason = R_NONE
    if code != VO_OK:
        reason = R_TUBE
    elif uf < p.min_thrust_n:
        reason = R_THRUST
    # First Dφ z = rhs (z = B₀ w, the commanded snap) …
    z, rel = solve3(jac, rhs)
    cond = 1.0 / rel if rel > 0 else math.inf
    if reason == R_NONE and cond > p.max_cond:
        reason = R_COND
    # … then B₀ w = z with B₀ = [b3/m, −(u_f/m) b2, (u_f/m) b1]: orthogonal columns.
    if uf > 0:
        udd, pdot, qdot = b0_inverse(z, b1, b2, b3, mass, uf)
        # The torque is held over the tick while the body spins under it (eq. (3)).
        pdot, qdot = held_rate_command(pdot, qdot, rc, p.dt_s, fr.ixyz)
    else:
        udd, pdot, qdot = mass * (z[0] * b3[0] + z[1] * b3[1] + z[2] * b3[2]), 0.0, 0.0
    if reason == R_NONE and not (math.isfinite(udd) and math.isfinite(pdot)
                                 and math.isfinite(qdot)):
        reason = R_NONFINITE
    if reason != R_NONE:        # rates damped, thrust held
        udd, pdot, qdot = -4.0 * duf, -20.0 * pc, -20.0 * qc
    if p.use_dob:
        pdot -= dob_s.d_p
        qdot -= dob_s.d_q
    ix, iy, iz = fr.ixyz
    tau_p, tau_q = torques(pdot, qdot, pc, qc, rc, ix, iy, iz, p.k_r)
    # The rotors: f₂' = A and τ_r from τ_p (eq. (6)), or all four with the yaw loop.
    fmax, arm, d = p.thrust_max_n, p.arm_m, fr.d_m
    a_n = u.attack_n
    psi_ref = s.psi_ref if s.has_psi_ref else psi
    if fr.attacked:
        lo, hi = _permuted(u.lo_n, fr.perm), _permuted(u.hi_n, fr.perm)   # canonical order
        tau_r = attacked_tau_r(uf, tau_p, a_n, arm, d)
        raw_c = allocate_attacked(uf, tau_q, tau_r, a_n, arm, d, math.inf, (_ZERO4, _INF4))
        f_c = allocate_attacked(uf, tau_q, tau_r, a_n, arm, d, fmax, (lo, hi))
        raw, f = _permuted(raw_c, fr.inv_perm), _permuted(f_c, fr.inv_perm)  # physical
    else:
        tau_r = yaw_tau_r(r2, psi, psi_ref, pc, qc, rc, qdot, p.k_yaw, fr.ixyz, p.k_r)
        raw = allocate_nominal(uf, tau_p, tau_q, tau_r, arm, d, math.inf, (_ZERO4, _INF4))
        f = allocate_nominal(uf, tau_p, tau_q, tau_r, arm, d, fmax, (u.lo_n, u.hi_n))
    # Clip to [0, f_max]; the attacked rotor is given what it is (not ours to command).
    f, sat = saturate(f, raw, s.last_out, fmax)
    if fr.attacked:
        p1 = fr.perm[1]
        f = (a_n if p1 == 0.0 else f[0], a_n if p1 == 1.0 else f[1], a_n if p1 == 2.0 else f[2],
             a_n if p1 == 3.0 else f[3])
    sat_any = 1.0 if sat[0] or sat[1] or sat[2] or sat[3] else 0.0
    applied_uf = f[0] + f[1] + f[2] + f[3]
    pred = predict(p, fr, f, rates)
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
    # The one-time switch to the fine ξ, η poles once |α| has stayed small long enough.
    settled = s.settled_s
    if p.use_switch and not fine and reason == R_NONE:
        settled = settled + dt if math.hypot(xi1[0], xi2[0]) < p.settle_alpha else 0.0
        if settled >= p.settle_time_s:
            fine = 1.0
    wp, _wq, wr = u.body_rates_radps
    state = TFLState(x13, x14, mass_s, dob_s, tdob_s, 1.0, pred, f, 1.0, psi_ref, fine, settled,
                     ps)
    out = TFLOutputs(
        f, fr.attacked, (1.0 if sat[0] else 0.0, 1.0 if sat[1] else 0.0,
                         1.0 if sat[2] else 0.0, 1.0 if sat[3] else 0.0),
        ((xi1[0], xi1[1], xi1[2], xi1[3]), (xi2[0], xi2[1], xi2[2], xi2[3])),
        (eta[0], eta[1], eta[2], eta[3]), (psi, -wp / p.iz_kgm2 - arm * wr / fr.mu_den),
        distance, lam, cond, uf, mass, (dob_s.d_p, dob_s.d_q), fine, reason, code, margin,
        rates, sat_any, (raw[0], raw[1], raw[2], raw[3]))
    return state, out


def tfl_step(p: TFLParams, s: TFLState, u: TFLInputs) -> tuple[TFLState, TFLOutputs]:
    """One control period of the law (module doc): the new state and the decision."""
    seen = observe(p, s, u)
    vo, ps = project(p.tube_min, s.path, seen[9], u.lam_start, u.lam_start_ok, u.path_failed)
    return command(p, s, u, seen, vo, ps)


def linked(sigma2: Any, sigma5: Any, s4: Any, pi: Any) -> dict[str, Any]:
    """This module's functions with :func:`~tfl_mav.control.path.projection.project` on the
    path's kernels (:func:`projection.linked`): one namespace per kernel set, the same code.
    The kernels are named here too, so that a lowering of the step is keyed on them."""
    projected = projection.linked(sigma2, sigma5, s4, pi)["project"]
    return relinked(globals(), project=projected, _sigma2=sigma2, _sigma5=sigma5, _s4=s4,
                    _pi=pi)
