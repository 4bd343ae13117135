"""The transverse-feedback-linearizing path-following law (paper §V), nominal and attacked.

Structure used (docs/design.md, "The law"). With y the position and the dynamic extension x13 = u_f,
x14 = u̇_f (eq. (9)), the fourth derivative of the position is affine in the
*virtual inputs* w = (ü_f, ṗ, q̇):

    y⁽⁴⁾ = a₀(x) + B₀(x) w,   B₀ = [b3/m, −(u_f/m) b2, (u_f/m) b1]      (bᵢ = R eᵢ)

so for the virtual output φ(y) = (α1, α2, π) (eq. (14)),
φ⁽⁴⁾ = L_f⁴φ + Dφ(y) B₀ w, where L_f⁴φ is φ⁽⁴⁾ evaluated with y⁽⁴⁾ = a₀ (computed with
Taylor jets by the path library) and Dφ is φ's Jacobian. The paper's decoupling matrix
(eq. (15)) is D = Dφ B₀ T with T the constant map from (u_d, u_r, u_q)
to w; solving eq. (21) for w first and then for the rotor
commands keeps one formula for both laws:

* attacked (rotor 2 in the canonical frame, see ``allocation``): τ_q from q̇, τ_r from ṗ via
  eq. (6) (τ_p = (u_f − τ_r/d) l/2 − 2lA), f2 = A (the *estimated* attack thrust);
  yaw is internal dynamics (μ1 = ψ, eq. (18)) — no Euler angle is used at all,
  so the law has no trouble with a vehicle spinning at tens of rad/s;
* nominal: τ_p, τ_q from ṗ, q̇, and τ_r from a second-order yaw loop (ψ held).

The ξ and η loops are eqs. (23) and (24) with repeated poles. The robust variant adds the
estimators of :mod:`estimators` and a one-time switch to faster poles once the vehicle has
settled on the path.

:meth:`TFLController.update` is the tick, one small step per idea, in the order the paper
builds the law. The path's derivatives come from :class:`compiled.CompiledPathTracker`
(straight-line code generated at start-up; ``compiled_path=False`` flies the reference jets,
which give the same numbers, for the benchmark and the tests). With the compiled tracker the
tick runs as the flight's one generated function (:mod:`fused`, the same operations; with
motor lag up to the torques), which hands every fallback back to the steps.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from tfl_mav.control.actuators import MotorLagInverter
from tfl_mav.control.allocation import (
    Bounds,
    RotorFrame,
    allocate_attacked,
    allocate_nominal,
    canonical_frame,
)
from tfl_mav.control.path.compiled import CompiledPathTracker, make_tracker
from tfl_mav.control.path.jetcode import TraceError
from tfl_mav.control.path.paths import Path
from tfl_mav.control.path.tracker import PathTracker, VirtualOutput
from tfl_mav.control.tfl.estimators import MassEstimator, RateDisturbanceObserver
from tfl_mav.control.tfl.fused import build_fused
from tfl_mav.control.tfl.fused_native import attach_native
from tfl_mav.control.tfl.law_math import (
    attacked_tau_r,
    b0_inverse,
    linear_rhs,
    output_rows,
    rate_prediction,
    saturate,
    solve3,
    torques,
    yaw_tau_r,
)
from tfl_mav.control.tfl.law_types import ControlOutput, LawConfig, ModelParams, chain_gains
from tfl_mav.model.geometry import rotation_rows
from tfl_mav.model.modes import Mode
from tfl_mav.model.state import State

__all__ = ["ControlOutput", "LawConfig", "ModelParams", "TFLController", "chain_gains"]

_NOMINAL, _ATTACKED, _FALLBACK = Mode.NOMINAL, Mode.ATTACKED, Mode.FALLBACK  # enum lookups
_new_output = tuple.__new__   # ControlOutput from its fields in order, no keyword parsing


def _floats(x: Sequence[float]) -> Sequence[float]:
    """``x`` with Python floats (``tolist`` of a numpy array; other sequences as they are)."""
    return x.tolist() if type(x) is np.ndarray else x


class TFLController:
    """The TFL path-following law with a dynamic extension on the total thrust.

    Call :meth:`update` once per control period with the measured state; call
    :meth:`set_attack` when (and whenever) the attacked rotor and its thrust estimate are
    known. Outputs never contain NaN: any numerical failure falls back to a safe command
    (rates damped, thrust held) and says why.
    """

    def __init__(self, model: ModelParams, path: Path, cfg: LawConfig, dt_s: float, *,
                 compiled_path: bool = True) -> None:
        self.model = model
        self.cfg = cfg
        self.dt = dt_s
        self.tracker, self.path_eval = make_tracker(path, compiled_path)
        self.mass_kg = model.mass_kg
        self.x13 = model.mass_kg * model.gravity_mps2   # u_f
        self.x14 = 0.0                                  # u̇_f
        self.attacked_rotor = 0
        self.attack_estimate_n = 0.0
        self.frame: RotorFrame | None = None
        self.psi_ref: float | None = None
        self.fine = False
        self._settled_s = 0.0
        self.saturation_count = 0
        self.fallback_count = 0
        self.ticks = 0
        self.mass_est = MassEstimator(model.mass_kg, model.gravity_mps2, model.k_t)
        self.dob = RateDisturbanceObserver(cfg.observer_tau_s)
        self._pred: tuple[float, float] | None = None   # model ṗ, q̇ for the last command
        self._last_out: list[float] = [model.mass_kg * model.gravity_mps2 / 4.0] * 4
        self.lag_inverter = (MotorLagInverter(model.k_f, model.thrust_max_n,
                                              model.motor_time_constant_s, dt_s)
                             if model.motor_time_constant_s > 0.0 else None)
        self.lag_clamped_count = 0
        self._use_mass = cfg.robust and cfg.mass_estimator
        self._use_dob = cfg.robust and cfg.disturbance_observer
        self._use_switch = cfg.robust and cfg.gain_switch
        self._set_frame(None)
        self._set_gains(fine=False)
        # The generated tick (:mod:`fused`), made for this tracker only.
        self._fused_for: PathTracker | None = None
        self._fused: Callable[..., tuple[Any, ...]] | None = None
        if type(self.tracker) is CompiledPathTracker:
            try:
                fused = build_fused(model, self.tracker.kernels, dt_s=dt_s,
                                    mass_est=self.mass_est, dob=self.dob)
                self._fused = fused.fn
                self._fused_for = self.tracker
                attach_native(self, fused)      # the compiled core, when there is one
            except (TraceError, ArithmeticError, ValueError):
                pass

    # ------------------------------------------------------------------ configuration
    def _set_gains(self, fine: bool) -> None:
        c = self.cfg
        self.fine = fine
        self.k_xi = chain_gains(c.xi_pole_fine if fine else c.xi_pole, 4)
        self.k_eta = chain_gains(c.eta_pole_fine if fine else c.eta_pole, 3)
        self.k_yaw = chain_gains(c.yaw_pole, 2)

    def _set_frame(self, frame: RotorFrame | None) -> None:
        """Canonical body axes for ``frame`` (None: the body axes themselves).

        ``rot`` is a signed permutation, so b1' = ±b_m and p' = ±Ω_m: kept as (m, sign)
        pairs, which gives R' = R rotᵀ and Ω' = rot Ω exactly, without 3×3 products.
        """
        self.frame = frame
        m = self.model
        ix, iy, iz = m.inertia_kgm2
        # Physical rotor of canonical rotor i (perm) and canonical index of physical rotor j.
        self._perm = frame.perm if frame is not None else (0, 1, 2, 3)
        self._inv_perm = tuple(self._perm.index(j) for j in range(4))
        if frame is None:
            self._axes = ((0, 1.0), (1, 1.0))
            self._ixyz = (ix, iy, iz)
            self._d = m.drag_thrust_ratio_m
            self._set_mu2()
            return
        axes = []
        for row in frame.rot[:2]:
            k = next(i for i, v in enumerate(row) if v)
            axes.append((k, float(row[k])))
        self._axes = (axes[0], axes[1])
        self._ixyz = (iy, ix, iz) if frame.swap_xy else (ix, iy, iz)
        self._d = m.drag_thrust_ratio_m * frame.d_sign
        self._set_mu2()

    def _set_mu2(self) -> None:
        """μ2 = −p/I_z − l r/(2 I_x d) (eq. (18)): its constants, once per frame."""
        m = self.model
        self._mu2 = (m.inertia_kgm2[2], m.arm_m, 2 * m.inertia_kgm2[0] * self._d)

    @property
    def core(self) -> str:
        """What flies the law's arithmetic: ``compiled`` (:mod:`native`), ``python`` (the
        generated tick, :mod:`fused`) or ``step-by-step`` (a path that cannot be fused)."""
        if self._fused is None:
            return "step-by-step"
        namespace = getattr(self._fused, "__globals__", {})
        return "compiled" if namespace.get("_core") is not None else "python"

    def resume(self, thrust_n: Sequence[float], lam: float | None = None) -> None:
        """Fly again, bumpless, from a state another law flew: the dynamic extension starts at
        the thrust now applied (x13 = Σ f, x14 = 0, eq. (9)), the rate observer, the ṗ, q̇
        prediction and the lag inverse start afresh, and the tracker's path parameter moves
        to ``lam`` (the other law's projection; None keeps its own)."""
        self.x13 = sum(thrust_n)
        self.x14 = 0.0
        self.dob.reset()
        self._pred = None
        self._last_out = list(thrust_n)
        if self.lag_inverter is not None:
            self.lag_inverter.reset()
        if lam is not None:
            self.tracker.lam = lam

    def set_attack(self, rotor: int, estimate_n: float) -> None:
        """Declare rotor (1-4) attacked with the given thrust estimate (N); 0 = none.

        Bumpless: the ξ/η chains and the dynamic extension carry over; only the allocation
        changes (and the yaw loop is dropped). The baseline (``aware_of_attack = False``)
        ignores this.
        """
        if not self.cfg.aware_of_attack:
            return
        if not math.isfinite(estimate_n):
            return  # keep the previous estimate: never let a NaN into the law
        estimate_n = min(max(estimate_n, 0.0), self.model.thrust_max_n)
        if rotor != self.attacked_rotor:
            self.attacked_rotor = rotor
            self._set_frame(canonical_frame(rotor) if rotor else None)
            self.dob.reset()
            self._pred = None
            if self.lag_inverter is not None:
                self.lag_inverter.reset()
        self.attack_estimate_n = estimate_n

    # ------------------------------------------------------------------ the law
    def update(self, s: State,
               rotor_speed_radps: Sequence[float] | None = None) -> ControlOutput:
        """Compute the rotor thrusts (N) for this control period from the measured state
        and, with motor lag, the measured rotor speeds ω (rad/s, from ESC rpm)."""
        self.ticks += 1
        trk = self.tracker
        # The flight's generated tick (:mod:`fused`) when it can run; it hands back to the
        # step-by-step tick after the prelude for every fallback and failure.
        k = None
        if trk is self._fused_for and trk.lam is not None:
            k = self._fused(self, trk, s)  # type: ignore[misc]
            if type(k) is ControlOutput:    # the whole tick, fused
                return k
        reason = ""
        if k is None or k[0] is None:
            y, v, psi, r2, rates, b1, b2, b3, pc, qc, rc, mass = \
                self._prelude(s) if k is None else k[1:]
            core, reason = self._stepwise_core(y, v, b1, b2, b3, pc, qc, rc, mass)
            udd, qdot, tau_p, tau_q, cond, xi, eta, lam, distance = core
        else:
            udd, qdot, tau_p, tau_q, cond, xi, eta, lam, distance, psi, r2, rates, pc, qc, rc, \
                mass = k
        uf, duf = self.x13, self.x14
        bounds = (self.lag_inverter.reachable(rotor_speed_radps)
                  if self.lag_inverter is not None else None)
        if self.frame is not None:
            f, raw = self._allocate_attacked(uf, tau_p, tau_q, bounds)
            mode = _ATTACKED
        else:
            f, raw = self._allocate_nominal(psi, r2, uf, tau_p, tau_q, qdot, pc, qc, rc, bounds)
            mode = _NOMINAL
        if reason:
            mode = _FALLBACK
        command, sat, applied_uf = self._saturate_and_apply(f, raw, pc, qc, rc)
        self._advance_extension(applied_uf, uf, duf, udd)
        self._settle(xi[0][0], xi[1][0], reason)
        iz, arm, den = self._mu2
        # ControlOutput's fields in order, built as the tuple it is (a keyword call of a
        # named tuple costs more than a microsecond a tick).
        return _new_output(ControlOutput, (
            command, mode, sat, xi, eta,
            (psi, -rates[0] / iz - arm * rates[2] / den),
            distance, lam, cond, uf, mass, (self.dob.d_p, self.dob.d_q), self.fine, reason))

    # ------------------------------------------------------------------ the steps
    def _prelude(self, s: State) -> tuple[Any, ...]:
        """State as floats, attitude, canonical axes and rates, estimators: (y, v, ψ, R's
        last row, rates, b1, b2, b3, p, q, r, mass)."""
        # Python floats: numpy scalars (the simulator's arrays) cost 3-5× per operation.
        y, v, quat, rates = (_floats(s.position_m), _floats(s.velocity_mps),
                             _floats(s.quaternion_wxyz), _floats(s.body_rates_radps))
        R = rotation_rows(quat)
        psi = math.atan2(R[1][0], R[0][0])
        if self.psi_ref is None:
            self.psi_ref = psi
        b1, b2, b3, pc, qc, rc = self._canonical_axes(R, rates)
        mass = self._update_estimators(v, b3, pc, qc)
        return y, v, psi, R[2], rates, b1, b2, b3, pc, qc, rc, mass

    def _stepwise_core(self, y: Sequence[float], v: Sequence[float], b1: Sequence[float],
                       b2: Sequence[float], b3: Sequence[float], pc: float, qc: float,
                       rc: float, mass: float) -> tuple[tuple[Any, ...], str]:
        """Model rows, virtual output, decoupling solve and torques, one step at a time
        (any tracker; every fallback). Returns (ü_f, q̇, τ_p, τ_q, cond, ξ rows, η, λ,
        distance) and the fallback reason ("" if none)."""
        uf, duf = self.x13, self.x14
        vo = self.tracker.virtual_output(self._output_taylor(y, v, b1, b2, b3, pc, qc, rc,
                                                             mass))
        reason, udd, pdot, qdot, cond = self._decoupling_solve(vo, b1, b2, b3, mass, uf, duf,
                                                               pc, qc)
        tau_p, tau_q = self._torques(pdot, qdot, pc, qc, rc)
        xi1, xi2, eta = vo.xi1, vo.xi2, vo.eta
        return (udd, qdot, tau_p, tau_q, cond,
                ((xi1[0], xi1[1], xi1[2], xi1[3]), (xi2[0], xi2[1], xi2[2], xi2[3])),
                (eta[0], eta[1], eta[2], eta[3]), vo.lam, vo.distance_m), reason

    def _canonical_axes(self, R: list[list[float]], rates: Sequence[float]
                        ) -> tuple[tuple[float, float, float], tuple[float, float, float],
                                   tuple[float, float, float], float, float, float]:
        """Body axes b1, b2, b3 (columns of R, eq. (1)) and rates (p, q, r), relabelled to
        the canonical frame of the attacked rotor (:mod:`allocation`)."""
        (m1, s1), (m2, s2) = self._axes
        r0, r1, r2 = R
        b1 = (s1 * r0[m1], s1 * r1[m1], s1 * r2[m1])
        b2 = (s2 * r0[m2], s2 * r1[m2], s2 * r2[m2])
        b3 = (r0[2], r1[2], r2[2])
        return b1, b2, b3, s1 * rates[m1], s2 * rates[m2], rates[2]

    def _update_estimators(self, v: Sequence[float], b3: Sequence[float], pc: float,
                           qc: float) -> float:
        """Robust add-ons fed with what was applied over the last period; returns the mass
        (kg) the law uses this tick."""
        if self._use_mass:
            lo = self._last_out
            self.mass_kg = self.mass_est.update(self.dt, v, lo[0] + lo[1] + lo[2] + lo[3], b3)
        if self._use_dob and self._pred is not None:
            self.dob.update(self.dt, pc, qc, self._pred[0], self._pred[1])
        return self.mass_kg

    def _output_taylor(self, y: Sequence[float], v: Sequence[float], b1: Sequence[float],
                       b2: Sequence[float], b3: Sequence[float], pc: float, qc: float,
                       rc: float, mass: float) -> tuple[tuple[float, ...], ...]:
        """Taylor rows of the output y = x_q (eq. (5)) from the model (eqs. (3), (9)):
        :func:`law_math.output_rows`."""
        m = self.model
        return output_rows(y, v, b1, b2, b3, pc, qc, rc, self.x13, self.x14, mass, m.k_t,
                           m.gravity_mps2)

    def _decoupling_solve(self, vo: VirtualOutput, b1: Sequence[float], b2: Sequence[float],
                          b3: Sequence[float], mass: float, uf: float, duf: float,
                          pc: float, qc: float) -> tuple[str, float, float, float, float]:
        """The regular feedback (eq. (21)): w = (ü_f, ṗ, q̇) with Dφ B₀ w = v − L_f⁴φ, where
        v are the linear ξ, η controllers (eqs. (23), (24)) and Dφ B₀ is the decoupling
        matrix (eq. (15)). Returns (fallback reason or "", ü_f, ṗ, q̇, cond Dφ)."""
        cfg = self.cfg
        xi1, xi2, eta = vo.xi1, vo.xi2, vo.eta
        kx, ke = self.k_xi, self.k_eta
        rhs = linear_rhs(xi1, xi2, eta, kx, ke, cfg.speed_mps)
        reason = ""
        if not vo.in_tube:
            reason = f"left the projection tube: {vo.reason}"
        elif uf < cfg.min_thrust_n:
            reason = f"total thrust {uf:.2f} N too small: D(x) singular"
        # First Dφ z = rhs (z = B₀ w, the commanded snap) …
        z, rel = solve3(vo.jacobian, rhs)
        cond = 1.0 / rel if rel > 0 else math.inf
        if not reason and cond > cfg.max_cond:
            reason = f"decoupling matrix ill-conditioned (cond {cond:.1e})"
        # … then B₀ w = z with B₀ = [b3/m, −(u_f/m) b2, (u_f/m) b1]: orthogonal columns.
        if uf > 0:
            udd, pdot, qdot = b0_inverse(z, b1, b2, b3, mass, uf)
        else:
            udd, pdot, qdot = mass * (z[0] * b3[0] + z[1] * b3[1] + z[2] * b3[2]), 0.0, 0.0
        if not reason and not (math.isfinite(udd) and math.isfinite(pdot)
                               and math.isfinite(qdot)):
            reason = "non-finite control (numerical failure)"
        if reason:
            self.fallback_count += 1
            udd, pdot, qdot = -4.0 * duf, -20.0 * pc, -20.0 * qc
        if self._use_dob:
            pdot -= self.dob.d_p
            qdot -= self.dob.d_q
        return reason, udd, pdot, qdot, cond

    def _torques(self, pdot: float, qdot: float, pc: float, qc: float, rc: float
                 ) -> tuple[float, float]:
        """τ_p, τ_q for the demanded ṗ, q̇ by Euler's equation with rate damping (eq. (3))."""
        ix, iy, iz = self._ixyz
        return torques(pdot, qdot, pc, qc, rc, ix, iy, iz, self.model.k_r)

    def _allocate_attacked(self, uf: float, tau_p: float, tau_q: float,
                           bounds: Bounds | None) -> tuple[list[float], list[float]]:
        """Rotor thrusts with f₂ = A (eq. (6)): τ_r from τ_p, rotor order restored.
        Returns (feasible thrusts, unbounded thrusts) in physical order."""
        m = self.model
        d = self._d
        a_n = self.attack_estimate_n
        arm = m.arm_m
        tau_r = attacked_tau_r(uf, tau_p, a_n, arm, d)   # eq. (6)
        raw = allocate_attacked(uf, tau_q, tau_r, a_n, arm, d)
        perm = self._perm
        cb = None if bounds is None else tuple([b[phys] for phys in perm] for b in bounds)
        f = allocate_attacked(uf, tau_q, tau_r, a_n, arm, d, m.thrust_max_n,
                              cb)  # type: ignore[arg-type]
        i0, i1, i2, i3 = self._inv_perm
        if i0:   # not rotor 2 itself: back to the physical order
            f = [f[i0], f[i1], f[i2], f[i3]]
            raw = [raw[i0], raw[i1], raw[i2], raw[i3]]
        return f, raw

    def _allocate_nominal(self, psi_e: float, r2: Sequence[float], uf: float, tau_p: float,
                          tau_q: float, qdot: float, pc: float, qc: float, rc: float,
                          bounds: Bounds | None) -> tuple[list[float], list[float]]:
        """All four rotors (inverse of eq. (4)); τ_r from the yaw loop ψ̈ = −k₁ψ̇ −
        k₀(ψ − ψ_ref), exact through the Euler chart (eq. (2)). (feasible, unbounded)."""
        m = self.model
        assert self.psi_ref is not None
        tau_r = yaw_tau_r(r2, psi_e, self.psi_ref, pc, qc, rc, qdot, self.k_yaw, self._ixyz,
                          m.k_r)
        d = self._d
        raw = allocate_nominal(uf, tau_p, tau_q, tau_r, m.arm_m, d)
        f = allocate_nominal(uf, tau_p, tau_q, tau_r, m.arm_m, d, m.thrust_max_n, bounds)
        return f, raw

    def _saturate_and_apply(self, f: list[float], raw: list[float], pc: float, qc: float,
                            rc: float) -> tuple[list[float], list[bool], float]:
        """Clip to [0, f_max], give the attacked rotor what it is (not ours to command),
        invert the motor lag, and predict ṗ, q̇ for the observer from what the rotors
        will deliver. Returns (command, saturated, applied u_f)."""
        m = self.model
        fmax = m.thrust_max_n
        f, sat = saturate(f, raw, self._last_out, fmax)
        frame = self.frame
        p0, p1, p2, p3 = self._perm
        if frame is not None:
            f[p1] = self.attack_estimate_n
        if sat[0] or sat[1] or sat[2] or sat[3]:
            self.saturation_count += 1
        applied_uf = f[0] + f[1] + f[2] + f[3]
        command = delivered = f
        if self.lag_inverter is not None:
            inv = self.lag_inverter.invert(f)
            command, delivered = inv.command_n, inv.expected_mean_n
            if frame is not None:
                command[p1] = f[p1]
                delivered[p1] = f[p1]
            if any(inv.clamped):
                self.lag_clamped_count += 1
        ix, iy, iz = self._ixyz
        self._pred = rate_prediction(delivered[p0], delivered[p1], delivered[p2], delivered[p3],
                                     pc, qc, rc, ix, iy, iz, m.k_r, m.arm_m)
        self._last_out = delivered
        return command, sat, applied_uf

    def _advance_extension(self, applied_uf: float, uf: float, duf: float,
                           udd: float) -> None:
        """Dynamic extension x13 = u_f, x14 = u̇_f, u_d = ü_f (eq. (9)), kept consistent
        with the thrust actually applied (anti-windup at the limits)."""
        dt = self.dt
        if abs(applied_uf - uf) > 1e-9:
            self.x13 = applied_uf
            if (applied_uf - uf) * duf < 0:
                self.x14 = 0.0  # anti-windup: stop pushing into the limit
        self.x13 += dt * self.x14 + 0.5 * dt * dt * udd
        self.x14 += dt * udd

    def _settle(self, alpha1: float, alpha2: float, reason: str) -> None:
        """The robust law's one-time switch to the fine ξ, η poles once |α| has stayed
        below ``settle_alpha`` for ``settle_time_s``."""
        cfg = self.cfg
        if self._use_switch and not self.fine and not reason:
            alpha_norm = math.hypot(alpha1, alpha2)
            self._settled_s = self._settled_s + self.dt if alpha_norm < cfg.settle_alpha \
                else 0.0
            if self._settled_s >= cfg.settle_time_s:
                self._set_gains(fine=True)
