"""The fallback where no relaxed hover holds the weight: a coning hover (explicit state, one
pure step).

With a rotor pinned at A > m g/2 the attitude hold needs f4 ≈ A (no roll torque to spare),
so the thrust is at least f_Σ = 2A + f1 + f3 > m g: held level, the vehicle climbs away.
Where the airframe has no relaxed hover either (docs/relaxed-hover.md: a slow yaw drag
cannot spin it fast enough for the gyroscope to carry the pinned rotor's torque), the
least-bad flight left is to *tilt* the thrust so that its vertical part is the weight,
f_Σ cos θ = m g, and to swing the tilt round the vertical at a rate Ω_p: the horizontal part
f_Σ sin θ then turns at Ω_p and averages out, and the centre of mass runs a circle of radius
a_h/Ω_p² (a_h = f_Σ sin θ/m) about its mean — bounded, held at the path. The thrust axis b3
follows b3_des(t) = (F_h + C(t), F_z)/f_Σ: F the mean force the outer loop wants and C the
turning part, |C|² = f_Σ² − |F|². This is no equilibrium (the torques turn in the body), so
it is flown by a reduced-attitude PD on b3 with the gyroscopic term ω × Jω and the
reference's own rate fed forward; the tilting torque is small (the precession's
Ω_p sin θ · I_z r), far inside what f4 and f3 − f1 can make.

Everything in the canonical frame of :mod:`~tfl_mav.control.allocation` (attacked rotor 2).
"""

from __future__ import annotations

import math
from typing import NamedTuple

from tfl_mav.accel.background import BackgroundLaw
from tfl_mav.control.scalar import clamp
from tfl_mav.control.spin.step import Mat3, Vec3, attitude, mat3, mean_pid

__all__ = ["CONE_START", "ConeInputs", "ConeLaw", "ConeOutputs", "ConeParams", "ConeState",
           "cone_params", "cone_step"]

CONE_RATE_RADPS = 8.0   # Ω_p: a_h/Ω_p² ≈ 0.2 m of circle at 53° of tilt
ROOM_N = 2.0            # f1 + f3 at rest: the room for τ_q (± l ROOM_N/2 … )
POS_OMEGA = 1.0         # outer loop triple pole (rad/s)
ATT_OMEGA = 25.0        # attitude PD natural frequency (rad/s) …
ATT_ZETA = 0.8          # … and damping


class ConeParams(NamedTuple):
    mass_kg: float
    inertia_kgm2: tuple[float, float, float]    # canonical (I_x', I_y', I_z)
    arm_m: float
    k_r: float
    k_t: float
    gravity_mps2: float
    thrust_max_n: float
    dt_s: float
    rot: Mat3                                   # body → canonical (rows)
    inverse: tuple[int, int, int, int]          # physical rotor k is canonical inverse[k]
    rate_radps: float                           # Ω_p (signed)
    kp: float
    kd: float
    ki: float
    kp_att: tuple[float, float]                 # N m/rad (x, y)
    kd_att: tuple[float, float]                 # N m s/rad


class ConeState(NamedTuple):
    phase_rad: float
    integral_ms: tuple[float, float, float]


class ConeInputs(NamedTuple):
    position_m: tuple[float, float, float]
    velocity_mps: tuple[float, float, float]
    quaternion_wxyz: tuple[float, float, float, float]
    body_rates_radps: tuple[float, float, float]
    stuck_thrust_n: float
    target_m: tuple[float, float, float]
    target_velocity_mps: tuple[float, float, float]
    target_accel_mps2: tuple[float, float, float]


CONE_START = ConeState(0.0, (0.0, 0.0, 0.0))
"""The state to enter with: the cone's phase at 0, no integral."""

_INPUTS_EXAMPLE = ConeInputs((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0),
                             (0.0, 0.0, 0.0), 0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0),
                             (0.0, 0.0, 0.0))


class ConeOutputs(NamedTuple):
    thrusts_n: tuple[float, float, float, float]   # physical rotors 1-4 (N)
    tilt_rad: float          # θ: the cone's half-angle asked for
    drift_m: float           # radius of the circle the centre of mass runs (m)
    axis_error_rad: float    # b3 to b3_des
    clipped: bool            # the allocation gave something up


def cone_params(vehicle: object, rotor: int, dt_s: float, *, mass_scale: float = 1.0,
                inertia_scale: float = 1.0) -> ConeParams:
    """The coning hover's constants for a scenario's ``vehicle`` with ``rotor`` attacked."""
    from tfl_mav.control.allocation import canonical_frame
    from tfl_mav.control.spin.equilibrium import airframe_from_scenario

    a = airframe_from_scenario(vehicle, rotor, mass_scale, inertia_scale)
    fr = canonical_frame(rotor)
    ix, iy, _ = a.inertia_kgm2
    w = POS_OMEGA
    # the spin the rotors' drag makes at rest, d (f1 + f3 − 2A)/k_r < 0 at A > ROOM_N/2:
    # the cone turns the other way (the torques then turn in the body at |r| + Ω_p cos θ)
    rate = CONE_RATE_RADPS if a.drag_m >= 0.0 else -CONE_RATE_RADPS
    return ConeParams(
        a.mass_kg, a.inertia_kgm2, a.arm_m, a.k_r, a.k_t, a.gravity_mps2, a.thrust_max_n,
        float(dt_s), mat3(fr.rot),
        tuple(fr.perm.index(k) for k in range(4)), rate, 3.0 * w * w, 3.0 * w, w ** 3,
        (ix * ATT_OMEGA ** 2, iy * ATT_OMEGA ** 2),
        (2.0 * ATT_ZETA * ATT_OMEGA * ix, 2.0 * ATT_ZETA * ATT_OMEGA * iy))


def canonical_body(R: Mat3, rot: Mat3, v: Vec3) -> Vec3:
    """An inertial vector ``v`` in the canonical body: rot Rᵀ v (R the body's attitude,
    ``rot`` the frame's rotation)."""
    vx, vy, vz = v
    b0 = R[0][0] * vx + R[1][0] * vy + R[2][0] * vz
    b1 = R[0][1] * vx + R[1][1] * vy + R[2][1] * vz
    b2 = R[0][2] * vx + R[1][2] * vy + R[2][2] * vz
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = rot
    return (r00 * b0 + r01 * b1 + r02 * b2, r10 * b0 + r11 * b1 + r12 * b2,
            r20 * b0 + r21 * b1 + r22 * b2)


def physical(inverse: tuple[int, int, int, int], canon: tuple[float, float, float, float]
               ) -> tuple[float, float, float, float]:
    """The canonical rotors' values in physical order: physical rotor k is canonical
    ``inverse[k]``."""
    return tuple(canon[inverse[k]] for k in range(4))  # type: ignore[return-value]


def cone_step(p: ConeParams, s: ConeState, u: ConeInputs) -> tuple[ConeState, ConeOutputs]:
    """One control period of the coning hover (module docstring)."""
    g, m = p.gravity_mps2, p.mass_kg
    ix, iy, iz = p.inertia_kgm2
    qw, qx, qy, qz = u.quaternion_wxyz
    n = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    if n == 0.0:        # no attitude measured: read as it is
        n = 1.0
    qw, qx, qy, qz = qw / n, qx / n, qy / n, qz / n
    R, w0, w1, w2 = attitude((qw, qx, qy, qz), u.body_rates_radps, p.rot)
    f2 = u.stuck_thrust_n
    fmax = p.thrust_max_n
    total = clamp(2.0 * f2 + ROOM_N, 0.0, 4.0 * fmax)
    om = p.rate_radps
    # --- outer loop on the mean: the circle (a_h turning at Ω_p) removed first
    px, py, pz = u.position_m
    vx, vy, vz = u.velocity_mps
    ahx, ahy = total / m * R[0][2], total / m * R[1][2]
    vx, vy = vx - ahy / om, vy + ahx / om
    px, py = px + ahx / (om * om), py + ahy / (om * om)
    ix_, iy_, iz_ = s.integral_ms
    ax, ay, az, ex, ey, ez = mean_pid(p.kp, p.kd, p.ki, p.k_t / m, s.integral_ms, u,
                                      (px, py, pz), (vx, vy, vz))
    az = clamp(az, -0.3 * g, 0.3 * g)
    h = math.sqrt(ax * ax + ay * ay)
    if h > 0.35 * g:
        ax, ay = ax * 0.35 * g / h, ay * 0.35 * g / h
    fx, fy, fz = m * ax, m * ay, m * (az + g)
    # --- the reference thrust axis: the mean force plus the turning part
    phase = s.phase_rad + om * p.dt_s
    phase = math.remainder(phase, math.tau)
    # the vertical part is F_z exactly; the horizontal part has the magnitude the rest of
    # f_Σ makes, F_h plus a part along (cos φ, sin φ) sized so: |F_h + c e_φ| = H
    big = total * total - fz * fz
    hmag = math.sqrt(big) if big > 0.0 else 0.0
    cph, sph = math.cos(phase), math.sin(phase)
    along = fx * cph + fy * sph
    disc = along * along - fx * fx - fy * fy + hmag * hmag
    c = -along + math.sqrt(disc) if disc > 0.0 else 0.0
    hx, hy, hz = fx + c * cph, fy + c * sph, fz
    inv = 1.0 / math.sqrt(hx * hx + hy * hy + hz * hz)
    bx, by, bz = hx * inv, hy * inv, hz * inv
    # its rate: ḃ = Ω_p e3 × (C/f_Σ) (the turning part), ω_⊥ = b × ḃ (inertial)
    dbx, dby = -om * c * math.sin(phase) * inv, om * c * math.cos(phase) * inv
    wix, wiy, wiz = by * 0.0 - bz * dby, bz * dbx - bx * 0.0, bx * dby - by * dbx
    h0, h1, h2 = canonical_body(R, p.rot, (bx, by, bz))
    pr, qr, _ = canonical_body(R, p.rot, (wix, wiy, wiz))
    # --- reduced attitude PD on e3 × h, the gyroscope and the drag fed forward
    kp_x, kp_y = p.kp_att
    kd_x, kd_y = p.kd_att
    tau_p = (kp_x * (-h1) + kd_x * (pr - w0) + p.k_r * pr
             + (iz - iy) * w1 * w2)
    tau_q = (kp_y * h0 + kd_y * (qr - w1) + p.k_r * qr
             + (ix - iz) * w0 * w2)
    # --- allocation (canonical): f2 the pinned rotor, f4 carries τ_p, f3 − f1 τ_q
    ell = p.arm_m
    clipped = False
    f4 = f2 + tau_p / ell
    if f4 < 0.0 or f4 > fmax:
        f4, clipped = clamp(f4, 0.0, fmax), True
    s13 = total - f2 - f4
    half = clamp(0.5 * tau_q / ell, -0.5 * fmax, 0.5 * fmax)
    lo, hi = 2.0 * abs(half), 2.0 * (fmax - abs(half))
    if s13 < lo or s13 > hi:
        s13, clipped = clamp(s13, lo, hi), True
    f1, f3 = 0.5 * s13 - half, 0.5 * s13 + half
    out = physical(p.inverse, (f1, f2, f3, f4))
    if not clipped:     # anti-windup: the integral frozen while the allocation gives up
        ix_ = clamp(ix_ + ex * p.dt_s, -2.0, 2.0)
        iy_ = clamp(iy_ + ey * p.dt_s, -2.0, 2.0)
        iz_ = clamp(iz_ + ez * p.dt_s, -2.0, 2.0)
    tilt = math.acos(clamp(bz, -1.0, 1.0))
    drift = total * math.sin(tilt) / m / (om * om)
    err = math.acos(clamp(h2, -1.0, 1.0))
    return ConeState(phase, (ix_, iy_, iz_)), ConeOutputs(out, tilt, drift, err, clipped)


class ConeLaw(BackgroundLaw[ConeParams, ConeState, ConeInputs, ConeOutputs]):
    """The coning hover built for one airframe and rotor: its constants (:attr:`params`) and
    its step (:func:`cone_step`), compiled by the accelerator seam in the background (a law
    is made in flight, when no relaxed hover holds the weight): :class:`BackgroundLaw`."""

    def __init__(self, params: ConeParams) -> None:
        super().__init__(cone_step, params, CONE_START, _INPUTS_EXAMPLE)
