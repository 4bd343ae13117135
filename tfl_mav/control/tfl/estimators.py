"""Online estimators that make the paper's law robust to model error (going past §VI).

Measured in a prototype (controller issue): with the paper's 2 % mass / 10 % inertia error
the plain law sits 6–7 cm off the path or crashes. Two estimators remove the two biases:

* the mass estimator (:func:`mass_update`) — the mass error biases α and the speed.
  Newton's law along the thrust direction, m (a + g i3) = u_f b3 − k_t v, is regressed with
  the acceleration taken from the velocity through a first-order filter (τ ≈ 0.2 s) and the
  regressor passed through the *same* filter, so both sides carry the same lag; the ratio
  is low-passed (τ ≈ 1 s) and clamped to a band around the nominal model.
* the rate disturbance observer (:func:`dob_update`) — the inertia error (and anything
  else: unmodelled torques, a wrong attack estimate) shows up as a mismatch between the
  measured ṗ, q̇ and the model's prediction for the torque actually applied. A fast
  (τ ≈ 4 ms) filtered difference estimates it; the law subtracts it from its p/q
  acceleration demand (INDI-like). A slower filter lags the ~60 rad/s yaw spin under attack
  by tens of degrees and crashes. The estimate is carried in the yaw-free frame (turned by
  −r·dt in (b1, b2) each tick): the inertia error's share is proportional to the law's own
  (ṗ, q̇), which point at a direction fixed over a tick and so turn at −r in the body;
  filtered in body axes it lagged by atan(r τ) ≈ 0.16 rad at r = 40 rad/s, a sideways
  error of 10 % × 0.16 on a 10 % inertia error (0.1-0.5 mm on the paper path's bends).
* the translational disturbance observer (:func:`tdob_update`) — the same construction on
  the velocity: the measured v̇ against the model's acceleration for the thrust applied,
  (Σf/m) b3 − g e3 − (k_t/m) v (eq. (3)). What the model does not know — the drag of a
  wind (k_t w/m), rotor drag — is a slowly varying acceleration d that the paper's ξ-chain
  cannot see: with d constant and four poles at −p the chain settles at
  ξ = (k₂/k₀) d = 6d/p² (130 mm for a 3 m/s wind at p = 2.5). The law adds the estimate
  to the model's ÿ (:func:`~tfl_mav.control.tfl.law_math.output_rows`), so α̈ and its
  derivatives carry it and ξ settles at zero. Horizontal only unless asked (the mass
  estimator is the vertical's integral action); its filter (τ = 0.1 s) is ten times slower
  than the rate observer's: it needs the push, not the vibration, and an estimator's
  velocity is a noisy thing to differentiate.

All three are explicit state and a pure update, called from the law's step.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NamedTuple

from tfl_mav.control.scalar import clamp

__all__ = ["DOB_START", "TDOB_START", "DobState", "MassModel", "MassState", "TdobState",
           "dob_step", "dob_update", "mass_blend", "mass_filters", "mass_model", "mass_start",
           "mass_update", "tdob_update"]

V3 = Sequence[Any]


def mass_filters(dt: Any, tau_s: Any, kt: Any, g: Any, v: V3, thrust: Any, b3: V3,
                 v_lp: V3, phi_lp: V3) -> tuple[Any, ...]:
    """One step of the mass estimator's two first-order filters: (LP(v) ×3, LP(φ) ×3,
    numerator and denominator of the instantaneous mass (LP(φ)·â / |â|², â = LP(v̇) + g e3))."""
    tau_dt = tau_s + dt
    a = dt / tau_dt
    vx, vy, vz = v
    lx, ly, lz = v_lp
    dx, dy, dz = vx - lx, vy - ly, vz - lz
    # Filtered acceleration = (v − LP(v))/τ is LP(v̇); the regressor gets the same LP.
    ax, ay, az = dx / tau_dt, dy / tau_dt, dz / tau_dt
    bx, by, bz = b3
    px, py, pz = phi_lp
    px = px + a * (thrust * bx - kt * vx - px)
    py = py + a * (thrust * by - kt * vy - py)
    pz = pz + a * (thrust * bz - kt * vz - pz)
    az = az + g
    return (lx + a * dx, ly + a * dy, lz + a * dz, px, py, pz,
            px * ax + py * ay + pz * az, ax ** 2 + ay ** 2 + az ** 2)


def mass_blend(mass: Any, m_inst: Any, dt: Any, ratio_tau_s: Any) -> Any:
    """The mass estimate low-passed towards the instantaneous one (before its clamp)."""
    return mass + dt / (ratio_tau_s + dt) * (m_inst - mass)


def dob_step(d: Any, rate: Any, rate_prev: Any, pred: Any, dt: Any, a: Any) -> Any:
    """The rate disturbance observer's filter on one axis, before its clamp."""
    return d + a * ((rate - rate_prev) / dt - pred - d)


class MassModel(NamedTuple):
    """The mass estimator's constants."""

    k_t: float              # translational drag (N s/m)
    g: float                # gravity (m/s²)
    accel_tau_s: float      # the velocity → acceleration filter (s)
    ratio_tau_s: float      # the low-pass of the mass estimate (s)
    lo_kg: float            # the estimate's band around the model mass (kg)
    hi_kg: float
    min_den: float          # |â|² below this ((m/s²)²): free fall or nonsense, not learnt from


class MassState(NamedTuple):
    """What the mass estimator remembers."""

    started: bool                       # the filters hold a first sample
    mass_kg: float                      # the estimate
    v_lp: tuple[float, float, float]    # LP(v) (m/s)
    phi_lp: tuple[float, float, float]  # LP(φ), φ = u_f b3 − k_t v (N)
    updates: int                        # ticks the estimate learnt from


def mass_model(model_mass_kg: float, gravity_mps2: float, k_t: float, accel_tau_s: float = 0.2,
               ratio_tau_s: float = 1.0, band: float = 0.2, min_excitation: float = 0.5
               ) -> MassModel:
    """The estimator of a model of ``model_mass_kg``: the estimate stays within ±``band`` of
    it, and learns only while |â| ≥ ``min_excitation`` (m/s²)."""
    return MassModel(k_t, gravity_mps2, accel_tau_s, ratio_tau_s,
                     model_mass_kg * (1.0 - band), model_mass_kg * (1.0 + band),
                     min_excitation ** 2)


def mass_start(model_mass_kg: float) -> MassState:
    """The estimator before its first sample: the model's mass."""
    return MassState(False, model_mass_kg, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0)


def mass_update(m: MassModel, s: MassState, dt: float, v: V3, thrust_n: float, b3: V3
                ) -> MassState:
    """Advance by ``dt`` s with the velocity ``v`` (m/s), the total thrust applied over the
    last period (N) and the thrust axis b3: Newton's law along b3 regressed through the
    same first-order filter on both sides (module doc)."""
    vx, vy, vz = v
    mass, updates = s.mass_kg, s.updates
    if s.started:
        lx, ly, lz, px, py, pz, num, den = mass_filters(dt, m.accel_tau_s, m.k_t, m.g, v,
                                                        thrust_n, b3, s.v_lp, s.phi_lp)
        if m.min_den <= den < math.inf:
            m_inst = num / den
            if -math.inf < m_inst < math.inf:
                mass = clamp(mass_blend(mass, m_inst, dt, m.ratio_tau_s), m.lo_kg, m.hi_kg)
                updates = updates + 1
    else:       # the first sample: the filters start at it
        bx, by, bz = b3
        kt = m.k_t
        lx, ly, lz = vx, vy, vz
        px, py, pz = thrust_n * bx - kt * vx, thrust_n * by - kt * vy, thrust_n * bz - kt * vz
    return MassState(True, mass, (lx, ly, lz), (px, py, pz), updates)


class DobState(NamedTuple):
    """What the rate disturbance observer remembers (canonical body axes)."""

    d_p: float          # the estimated disturbance of ṗ, q̇ (rad/s²)
    d_q: float
    has_prev: bool      # the rates of the last tick are known
    prev_p: float       # p, q of the last tick (rad/s)
    prev_q: float


DOB_START = DobState(0.0, 0.0, False, 0.0, 0.0)


def dob_update(tau_s: float, limit_radps2: float, s: DobState, dt: float, p: float, q: float,
               r: float, pdot_pred: float, qdot_pred: float) -> DobState:
    """Feed the rates measured now (rad/s, r the yaw rate about b3) and the model's ṗ, q̇
    for the command just applied: the measured − predicted rate derivative through a
    first-order filter of ``tau_s`` in the yaw-free frame, clamped to ±``limit_radps2``."""
    d_p, d_q = s.d_p, s.d_q
    if s.has_prev:
        # Kept in the yaw-free frame: the body turned by r·dt under last tick's estimate.
        th = r * dt
        ct, st = math.cos(th), math.sin(th)
        d_p, d_q = ct * d_p + st * d_q, ct * d_q - st * d_p
        a = dt / (tau_s + dt)
        d_p = clamp(dob_step(d_p, p, s.prev_p, pdot_pred, dt, a), -limit_radps2, limit_radps2)
        d_q = clamp(dob_step(d_q, q, s.prev_q, qdot_pred, dt, a), -limit_radps2, limit_radps2)
    return DobState(d_p, d_q, True, p, q)


class TdobState(NamedTuple):
    """What the translational disturbance observer remembers (paper frame, z up)."""

    d_x: float          # the estimated unmodelled acceleration (m/s²)
    d_y: float
    d_z: float          # 0 unless the vertical is estimated too
    has_prev: bool      # the last tick's velocity and thrust axis are known
    prev_vx: float      # the velocity of the last tick (m/s)
    prev_vy: float
    prev_vz: float
    prev_bx: float      # the thrust axis b3 of the last tick
    prev_by: float
    prev_bz: float


TDOB_START = TdobState(0.0, 0.0, 0.0, False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def tdob_update(tau_s: float, limit_mps2: float, s: TdobState, dt: float, v: V3,
                thrust_n: float, b3: V3, mass_kg: float, k_t: float, g: float,
                vertical: bool) -> TdobState:
    """Feed the velocity measured now (m/s) with the total thrust applied over the last
    period (N), the thrust axis b3 and the model's mass (kg) and drag (N s/m): the
    measured − modelled acceleration through a first-order filter of ``tau_s`` (the rate
    observer's :func:`dob_step` on each axis), clamped to ±``limit_mps2``; vertically only
    when ``vertical`` (``d_z`` stays 0 otherwise).

    In still air the mass estimator is the law's vertical integral action (a steady
    vertical force reads as a mass); an observer there too fights it through every change
    of the attack's thrust (the envelope's attacked flights: 0.09 → 0.2 mm, 0.3 → 12 mm at
    250 Hz). The rotors' inflow drag, a vertical force that follows the climb rate, is what
    a mass cannot stand for: there the vertical is estimated too.

    The velocity's difference is the mean acceleration over the period, so the model's is
    taken at the period's middle (b3 and v the means of its ends): with b3 of either end,
    a tilt rate ω reads as an acceleration ½ (u_f/m) ω Δt — 0.06 m/s² at 3 rad/s and
    250 Hz, which the law then flies against."""
    vx, vy, vz = v
    bx, by, bz = b3
    d_x, d_y, d_z = s.d_x, s.d_y, s.d_z
    if s.has_prev:
        a = dt / (tau_s + dt)
        ufm, ktm = thrust_n / mass_kg, k_t / mass_kg
        mbx, mby = 0.5 * (bx + s.prev_bx), 0.5 * (by + s.prev_by)
        mvx, mvy = 0.5 * (vx + s.prev_vx), 0.5 * (vy + s.prev_vy)
        d_x = clamp(dob_step(d_x, vx, s.prev_vx, ufm * mbx - ktm * mvx, dt, a),
                    -limit_mps2, limit_mps2)
        d_y = clamp(dob_step(d_y, vy, s.prev_vy, ufm * mby - ktm * mvy, dt, a),
                    -limit_mps2, limit_mps2)
        if vertical:
            mbz, mvz = 0.5 * (bz + s.prev_bz), 0.5 * (vz + s.prev_vz)
            d_z = clamp(dob_step(d_z, vz, s.prev_vz, ufm * mbz - ktm * mvz - g, dt, a),
                        -limit_mps2, limit_mps2)
    return TdobState(d_x, d_y, d_z, True, vx, vy, vz, bx, by, bz)

