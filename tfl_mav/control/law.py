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

The ξ and η loops are eqs. linear-xi-controller and linear-eta-controller with repeated
poles. The robust variant adds the estimators of :mod:`estimators` and a one-time switch to
faster poles once the vehicle has settled on the path.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from tfl_mav.control.actuators import MotorLagInverter
from tfl_mav.control.allocation import (
    RotorFrame,
    allocate_attacked,
    allocate_nominal,
    canonical_frame,
)
from tfl_mav.control.estimators import MassEstimator, RateDisturbanceObserver
from tfl_mav.control.paths import Path, PathTracker
from tfl_mav.geometry import rotation_rows
from tfl_mav.modes import Mode
from tfl_mav.state import State

__all__ = ["ControlOutput", "LawConfig", "ModelParams", "TFLController", "chain_gains"]


@dataclass(frozen=True)
class ModelParams:
    """The controller's model of the vehicle (deliberately not the truth), SI units."""

    mass_kg: float
    inertia_kgm2: tuple[float, float, float]
    arm_m: float
    drag_thrust_ratio_m: float
    k_t: float
    k_r: float
    thrust_max_n: float
    gravity_mps2: float = 9.81
    k_f: float = 8.0e-6                 # N/(rad/s)², thrust = k_f ω²
    motor_time_constant_s: float = 0.0  # first-order lag on ω; 0 = ideal actuators


@dataclass(frozen=True)
class LawConfig:
    """Gains and robustness switches (mirrors the scenario's ``[controller]`` table)."""

    speed_mps: float = 0.5
    xi_pole: float = -2.5
    eta_pole: float = -2.0
    xi_pole_fine: float = -4.0
    eta_pole_fine: float = -2.5
    yaw_pole: float = -4.0
    robust: bool = True
    mass_estimator: bool = True
    disturbance_observer: bool = True
    gain_switch: bool = True
    observer_tau_s: float = 0.004
    aware_of_attack: bool = True
    settle_alpha: float = 0.01      # |α| below this …
    settle_time_s: float = 1.0      # … for this long switches to the fine poles
    min_thrust_n: float = 0.5       # u_f below this makes D singular: fall back
    max_cond: float = 1e8           # cond(Dφ) above this: fall back


@dataclass
class ControlOutput:
    """One control decision and the internals worth logging."""

    rotor_thrust_n: list[float]          # command, in [0, f_max], physical rotor order (with
                                         # motor lag: the lag inverse of the law's demand)
    mode: Mode                           # NOMINAL | ATTACKED | FALLBACK
    saturated: list[bool]
    xi: tuple[tuple[float, ...], tuple[float, ...]]   # (α1, α̇1, α̈1, α⃛1), same for α2
    eta: tuple[float, ...]               # (π, π̇, π̈, π⃛)
    mu: tuple[float, float]              # (ψ, μ2) internal states, eq. (18)
    path_distance_m: float
    lam: float
    cond_d: float
    thrust_n: float                      # u_f = x13
    mass_estimate_kg: float
    disturbance_radps2: tuple[float, float]
    fine_gains: bool
    reason: str = ""                     # why a fallback was taken
    extra: dict[str, float] = field(default_factory=dict)


def chain_gains(pole: float, order: int) -> tuple[float, ...]:
    """Gains k₀…k_{n−1} of (s − pole)ⁿ = sⁿ + k_{n−1}sⁿ⁻¹ + … + k₀ (pole < 0)."""
    a = -pole
    return tuple(math.comb(order, i) * a ** (order - i) for i in range(order))


def _solve3(A: Sequence[Sequence[float]], b: Sequence[float]) -> tuple[list[float], float]:
    """Solve a 3×3 system by Cramer's rule; returns (x, |det| relative to the row norms)."""
    (a, b_, c), (d, e, f), (g, h, i) = A
    co0 = e * i - f * h
    co1 = f * g - d * i
    co2 = d * h - e * g
    det = a * co0 + b_ * co1 + c * co2
    norms = (math.sqrt(a * a + b_ * b_ + c * c) * math.sqrt(d * d + e * e + f * f)
             * math.sqrt(g * g + h * h + i * i))
    rel = abs(det) / norms if norms > 0 else 0.0
    if rel < 1e-12:
        return [0.0, 0.0, 0.0], rel
    inv = 1.0 / det
    x0 = (b[0] * co0 + b[1] * (c * h - b_ * i) + b[2] * (b_ * f - c * e)) * inv
    x1 = (b[0] * co1 + b[1] * (a * i - c * g) + b[2] * (c * d - a * f)) * inv
    x2 = (b[0] * co2 + b[1] * (b_ * g - a * h) + b[2] * (a * e - b_ * d)) * inv
    return [x0, x1, x2], rel


class TFLController:
    """The TFL path-following law with a dynamic extension on the total thrust.

    Call :meth:`update` once per control period with the measured state; call
    :meth:`set_attack` when (and whenever) the attacked rotor and its thrust estimate are
    known. Outputs never contain NaN: any numerical failure falls back to a safe command
    (rates damped, thrust held) and says why.
    """

    def __init__(self, model: ModelParams, path: Path, cfg: LawConfig, dt_s: float) -> None:
        self.model = model
        self.cfg = cfg
        self.dt = dt_s
        self.tracker = PathTracker(path)
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
        self._set_gains(fine=False)

    # ------------------------------------------------------------------ configuration
    def _set_gains(self, fine: bool) -> None:
        c = self.cfg
        self.fine = fine
        self.k_xi = chain_gains(c.xi_pole_fine if fine else c.xi_pole, 4)
        self.k_eta = chain_gains(c.eta_pole_fine if fine else c.eta_pole, 3)
        self.k_yaw = chain_gains(c.yaw_pole, 2)

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
            self.frame = canonical_frame(rotor) if rotor else None
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
        m = self.model
        cfg = self.cfg
        dt = self.dt
        R = rotation_rows(s.quaternion_wxyz)
        p, q, r = s.body_rates_radps
        v = list(s.velocity_mps)
        y = list(s.position_m)
        if self.psi_ref is None:
            self.psi_ref = math.atan2(R[1][0], R[0][0])

        frame = self.frame
        attacked = frame is not None
        # Canonical body axes: R' = R rotᵀ, Ω' = rot Ω (identity when not attacked).
        if attacked:
            rot = frame.rot
            Rc = [[sum(R[i][k] * rot[j][k] for k in range(3)) for j in range(3)]
                  for i in range(3)]
            pc = rot[0][0] * p + rot[0][1] * q + rot[0][2] * r
            qc = rot[1][0] * p + rot[1][1] * q + rot[1][2] * r
            ix, iy = ((m.inertia_kgm2[1], m.inertia_kgm2[0]) if frame.swap_xy
                      else (m.inertia_kgm2[0], m.inertia_kgm2[1]))
            d = m.drag_thrust_ratio_m * frame.d_sign
        else:
            Rc = R
            pc, qc = p, q
            ix, iy = m.inertia_kgm2[0], m.inertia_kgm2[1]
            d = m.drag_thrust_ratio_m
        iz = m.inertia_kgm2[2]
        rc = r
        b1 = (Rc[0][0], Rc[1][0], Rc[2][0])
        b2 = (Rc[0][1], Rc[1][1], Rc[2][1])
        b3 = (Rc[0][2], Rc[1][2], Rc[2][2])

        # Robust add-ons: estimators fed with what was applied over the last period.
        if cfg.robust and cfg.mass_estimator:
            applied_uf = sum(self._last_out)
            self.mass_kg = self.mass_est.update(dt, v, applied_uf, (R[0][2], R[1][2], R[2][2]))
        if cfg.robust and cfg.disturbance_observer and self._pred is not None:
            self.dob.update(dt, pc, qc, self._pred[0], self._pred[1])
        mass = self.mass_kg
        g = m.gravity_mps2
        kt = m.k_t / mass
        uf, duf = self.x13, self.x14

        # Derivatives of y from the model (eq. (3) with the extension).
        ydd = [uf / mass * b3[i] - kt * v[i] for i in range(3)]
        ydd[2] -= g
        db3 = [qc * b1[i] - pc * b2[i] for i in range(3)]
        yddd = [duf / mass * b3[i] + uf / mass * db3[i] - kt * ydd[i] for i in range(3)]
        pq2 = pc * pc + qc * qc
        a0 = [2.0 * duf / mass * db3[i]
              + uf / mass * (pc * rc * b1[i] + qc * rc * b2[i] - pq2 * b3[i])
              - kt * yddd[i] for i in range(3)]
        taylor = [[y[i], v[i], ydd[i] / 2.0, yddd[i] / 6.0, a0[i] / 24.0] for i in range(3)]

        out = self.tracker.evaluate(taylor)
        xi1 = out.alpha[0].derivatives()
        xi2 = out.alpha[1].derivatives()
        eta = out.pi.derivatives()
        J = out.jacobian

        # Auxiliary inputs: eqs. (23), (24).
        kx, ke = self.k_xi, self.k_eta
        v_xi1 = -(kx[0] * xi1[0] + kx[1] * xi1[1] + kx[2] * xi1[2] + kx[3] * xi1[3])
        v_xi2 = -(kx[0] * xi2[0] + kx[1] * xi2[1] + kx[2] * xi2[2] + kx[3] * xi2[3])
        v_eta = -(ke[0] * (eta[1] - cfg.speed_mps) + ke[1] * eta[2] + ke[2] * eta[3])
        rhs = [v_xi1 - xi1[4], v_xi2 - xi2[4], v_eta - eta[4]]

        reason = ""
        if not out.in_tube:
            reason = f"left the projection tube: {out.reason}"
        elif uf < cfg.min_thrust_n:
            reason = f"total thrust {uf:.2f} N too small: D(x) singular"
        # Solve Dφ · B₀ w = rhs: first Dφ z = rhs (z = B₀ w = the commanded snap part)…
        z, rel = _solve3(J, rhs)
        cond = 1.0 / rel if rel > 0 else math.inf
        if not reason and cond > cfg.max_cond:
            reason = f"decoupling matrix ill-conditioned (cond {cond:.1e})"
        # … then B₀ w = z with B₀ = [b3/m, −(u_f/m) b2, (u_f/m) b1] orthogonal columns.
        udd = mass * (z[0] * b3[0] + z[1] * b3[1] + z[2] * b3[2])
        pdot = -mass / uf * (z[0] * b2[0] + z[1] * b2[1] + z[2] * b2[2]) if uf > 0 else 0.0
        qdot = mass / uf * (z[0] * b1[0] + z[1] * b1[1] + z[2] * b1[2]) if uf > 0 else 0.0

        if not reason and not all(math.isfinite(c) for c in (udd, pdot, qdot)):
            reason = "non-finite control (numerical failure)"
        if reason:
            self.fallback_count += 1
            udd, pdot, qdot = -4.0 * duf, -20.0 * pc, -20.0 * qc

        if cfg.robust and cfg.disturbance_observer:
            pdot -= self.dob.d_p
            qdot -= self.dob.d_q

        # Model torques for the demanded angular accelerations (Euler's equation).
        kr = m.k_r
        tau_p = ix * pdot + kr * pc + (iz - iy) * qc * rc
        tau_q = iy * qdot + kr * qc + (ix - iz) * pc * rc
        # Motor lag: what each rotor can reach this period bounds the allocation.
        bounds = (self.lag_inverter.reachable(rotor_speed_radps)
                  if self.lag_inverter is not None else None)
        if attacked:
            a_n = self.attack_estimate_n
            tau_r = d * (uf - 2.0 * (tau_p + 2.0 * m.arm_m * a_n) / m.arm_m)   # eq. (6)
            raw_c = allocate_attacked(uf, tau_q, tau_r, a_n, m.arm_m, d)
            cb = None if bounds is None else tuple([b[phys] for phys in frame.perm]
                                                   for b in bounds)
            canon = allocate_attacked(uf, tau_q, tau_r, a_n, m.arm_m, d, m.thrust_max_n,
                                      cb)  # type: ignore[arg-type]
            f = [0.0] * 4
            raw = [0.0] * 4
            for i, phys in enumerate(frame.perm):
                f[phys] = canon[i]
                raw[phys] = raw_c[i]
            mode = Mode.ATTACKED
        else:
            # Nominal: yaw held by ψ̈ = −k₁ψ̇ − k₀(ψ − ψ_ref), exact through the Euler chart.
            phi_e = math.atan2(R[2][1], R[2][2])
            th_e = -math.asin(max(-1.0, min(1.0, R[2][0])))
            psi_e = math.atan2(R[1][0], R[0][0])
            sph, cph = math.sin(phi_e), math.cos(phi_e)
            cth, sth = math.cos(th_e), math.sin(th_e)
            dphi = pc + (qc * sph + rc * cph) * sth / cth
            dth = qc * cph - rc * sph
            dpsi = (qc * sph + rc * cph) / cth
            err = math.remainder(psi_e - self.psi_ref, math.tau)
            psi_dd = -self.k_yaw[1] * dpsi - self.k_yaw[0] * err
            drift = (qc * cph * dphi - rc * sph * dphi) / cth + (qc * sph + rc * cph) * sth \
                * dth / (cth * cth)
            rdot = ((psi_dd - drift) * cth - qdot * sph) / cph
            tau_r = iz * rdot + kr * rc + (iy - ix) * pc * qc
            raw = allocate_nominal(uf, tau_p, tau_q, tau_r, m.arm_m, d)
            f = allocate_nominal(uf, tau_p, tau_q, tau_r, m.arm_m, d, m.thrust_max_n, bounds)
            mode = Mode.NOMINAL
        if reason:
            mode = Mode.FALLBACK

        # Saturate, and keep the dynamic extension consistent with what is applied.
        fmax = m.thrust_max_n
        sat = [not (-1e-9 <= fi <= fmax + 1e-9) for fi in raw]
        f = [min(max(fi, 0.0), fmax) if math.isfinite(fi) else self._last_out[i]
             for i, fi in enumerate(f)]
        if attacked:
            f[frame.perm[1]] = self.attack_estimate_n  # not ours to command; what it is
        if any(sat):
            self.saturation_count += 1
        applied_uf = sum(f)
        # Motor lag (#6): command what makes the rotors *reach* f; the estimators see what
        # the rotors will deliver, not what was asked.
        command = f
        delivered = f
        if self.lag_inverter is not None:
            inv = self.lag_inverter.invert(f)
            command, delivered = inv.command_n, inv.expected_mean_n
            if attacked:
                command[frame.perm[1]] = f[frame.perm[1]]
                delivered[frame.perm[1]] = f[frame.perm[1]]
            if any(inv.clamped):
                self.lag_clamped_count += 1
        # Predicted ṗ, q̇ for the observer (canonical axes), from the delivered thrusts.
        fc = [delivered[phys] for phys in frame.perm] if attacked else delivered
        tp_app = m.arm_m * (fc[3] - fc[1])
        tq_app = m.arm_m * (fc[2] - fc[0])
        self._pred = ((tp_app - kr * pc - (iz - iy) * qc * rc) / ix,
                      (tq_app - kr * qc - (ix - iz) * pc * rc) / iy)
        self._last_out = delivered

        # Dynamic extension x13 = u_f, x14 = u̇_f, u_d = ü_f (eq. (9)).
        if abs(applied_uf - uf) > 1e-9:
            self.x13 = applied_uf
            if (applied_uf - uf) * duf < 0:
                self.x14 = 0.0  # anti-windup: stop pushing into the limit
        self.x13 += dt * self.x14 + 0.5 * dt * dt * udd
        self.x14 += dt * udd

        # Settling detector for the one-time gain switch (robust law).
        alpha_norm = math.hypot(xi1[0], xi2[0])
        if cfg.robust and cfg.gain_switch and not self.fine and not reason:
            self._settled_s = self._settled_s + dt if alpha_norm < cfg.settle_alpha else 0.0
            if self._settled_s >= cfg.settle_time_s:
                self._set_gains(fine=True)

        psi = math.atan2(R[1][0], R[0][0])
        mu2 = -p / m.inertia_kgm2[2] - m.arm_m * r / (2 * m.inertia_kgm2[0] * d)
        return ControlOutput(
            rotor_thrust_n=command, mode=mode, saturated=sat,
            xi=(tuple(xi1[:4]), tuple(xi2[:4])), eta=tuple(eta[:4]), mu=(psi, mu2),
            path_distance_m=out.distance_m, lam=out.lam, cond_d=cond, thrust_n=uf,
            mass_estimate_kg=mass, disturbance_radps2=(self.dob.d_p, self.dob.d_q),
            fine_gains=self.fine, reason=reason,
        )
