"""The spin law: a rotor pinned high, flown in relaxed hover, as explicit state and one pure
step (docs/relaxed-hover.md).

:func:`spin_step` is one control period: ``spin_step(params, state, inputs) -> (state,
outputs)`` in plain Python over NamedTuples of floats. In order:

1. **Canonical frame.** The body is relabelled so that the attacked rotor is rotor 2
   (:mod:`~tfl_mav.control.allocation`): R' = R rotᵀ, ω' = rot ω.
2. **Outer loop** (position of the mean). A PID on the position error towards the target
   (the path's closest point, its velocity and centripetal acceleration) gives the wanted
   acceleration a; the translational drag k_t v is fed forward. The position and velocity
   fed back are the *mean*'s: the circle the cone drives (velocity (a_y, −a_x)/Ω_z about the
   offset −a/Ω_z², a the horizontal thrust acceleration) is removed first. The mean thrust of a
   relaxed hover is f_Σ n̄_z along the spin axis (the cone averages out over a revolution),
   so the *spin axis* is steered along n_des = (a + g e3)/|a + g e3| and the mean vertical
   force W = m |a + g e3| sets f_Σ = W / n̄_z.
3. **Equilibrium at the measured f_stuck.** The relaxed hover (f1..f4, ω̄ = Ω n̄) is read from
   a table over f_stuck (:mod:`equilibrium`, solved before the flight), linearly
   interpolated (:func:`hover_at`). If no equilibrium holds m g the table holds the spin that
   comes closest (the least climb or descent) and ``exists`` is False.
4. **Spin schedule.** ρ = ω'_z / ω̄_z ∈ [0, ρ_max] is the spin relative to the equilibrium's.
   The reference rate is ω_ref = ρ Ω̄ n_ref and the torques k_r ω_ref + ω_ref × J ω_ref are
   fed forward: they balance the axis n_ref at that spin (E1), so every ρ is a
   quasi-equilibrium. With n_ref = n̄ these are true equilibria for other mean vertical
   forces: a faster spin needs less f1 + f3 to hold its drag (E1, yaw) and more torque
   from f4 (E1, roll), so f_Σ falls with ρ — the outer loop's vertical force sets the spin,
   which settles within I_z/k_r ≈ 0.5 s. Below ρ₀ (the spin-up, ~0.2 s at 8 N) the axis tilts
   from b3 to n̄ as θ = θ̄ (ρ/ρ₀)², so a slow spin is not asked for a torque only a fast one
   can balance. The vertical force is kept where ρ stays in the range the rotors can hold
   (W_lo … W_hi of the table).
5. **Reduced attitude.** Mueller & D'Andrea's LQR on (p, q, n_x, n_y) − reference, the
   vertical n = R'ᵀ n_des seen in the body, gains scheduled on ρ (designed on the
   zero-order-hold model at the control period before the flight).
6. **Allocation.** f4 = f2 + τ_p/l, f1 + f3 = f_Σ − f2 − f4, f3 − f1 = τ_q/l with f2 the
   *measured* thrust of the attacked rotor; clipped to [0, f_max] giving up the vertical
   force before τ_q and τ_q before τ_p (τ_p holds the spin's tilt: losing it topples the
   axis). Yaw is left free: the spin is the yaw.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

from tfl_mav.control.scalar import clamp

__all__ = [
    "RHO_MAX",
    "RHO_STEPS",
    "RHO_TILT",
    "SPIN_MEAN_RADPS",
    "Gain",
    "Mat3",
    "SpinHover",
    "SpinInputs",
    "SpinOutputs",
    "SpinParams",
    "SpinRow",
    "SpinState",
    "gain_at",
    "hover_at",
    "mat3",
    "spin_step",
]

SPIN_MEAN_RADPS = 5.0   # above this spin the cone's circle is removed from the feedback
RHO_MAX = 2.5           # the schedule spans ρ ∈ [0, RHO_MAX]
RHO_STEPS = 25          # gains at ρ = 0, 0.1, …, RHO_MAX
RHO_TILT = 0.6          # ρ₀: below it the reference axis tilts in as (ρ/ρ₀)²
Vec3 = tuple[float, float, float]
Vec4 = tuple[float, float, float, float]
Mat3 = tuple[Vec3, Vec3, Vec3]
Gain = tuple[Vec4, Vec4]
"""An LQR gain K (2×4): the rows give τ_p and τ_q (N m) from (p, q, n_x, n_y) − reference."""


class SpinHover(NamedTuple):
    """The relaxed hover at one f_stuck (canonical frame, SI), or where none holds m g the
    spin that comes closest; what the law flies there (:func:`hover_at`)."""

    f_stuck_n: float            # the pinned rotor's thrust
    exists: bool                # a relaxed hover holds m g here; else the closest spin
    f4_n: float                 # f̄4
    f13_n: float                # f̄1 + f̄3
    rates_radps: Vec3           # ω̄ = Ω n̄ (canonical body)
    axis: Vec3                  # n̄, the spin axis (n̄_z > 0)
    spin_radps: float           # Ω, signed
    total_n: float              # f̄_Σ
    cone_rad: float             # θ̄: thrust axis to the spin axis
    drift_m: float              # radius of the circle the centre of mass runs
    vertical_excess_mps2: float  # acceleration left over where none exists (0 where it does)
    margin_n: float             # least distance of f̄1, f̄3, f̄4 to 0 and f_max
    weight_lo_n: float          # W_lo … W_hi: the mean vertical forces the spin holds with
    weight_hi_n: float          # every rotor in range


class SpinRow(NamedTuple):
    """One row of :attr:`SpinParams.table` (built by
    :func:`tfl_mav.control.spin.law.table_row`): the hover at one f_stuck and the LQR gains
    along its spin-up, read between rows by :func:`hover_at` and :func:`gain_at`."""

    hover: SpinHover
    gains: tuple[Gain, ...]     # K at ρ = 0, RHO_MAX/RHO_STEPS, …, RHO_MAX


class SpinParams(NamedTuple):
    """The spin law's constants (SI); ``table`` from :func:`tfl_mav.control.spin.law.build`."""

    mass_kg: float              # the controller's model of the mass
    inertia_kgm2: tuple[float, float, float]    # model (I_x', I_y', I_z), canonical axes
    arm_m: float
    drag_m: float               # d' (canonical sign)
    k_r: float
    k_t: float
    gravity_mps2: float
    thrust_max_n: float
    dt_s: float                 # control period: the integral's step
    rot: Mat3                   # body → canonical body (rows)
    perm: tuple[int, int, int, int]     # canonical rotor i is physical rotor perm[i] (0-based)
    kp: float                   # outer loop (1/s², 1/s, 1/s³)
    kd: float
    ki: float
    max_tilt_tan: float         # |a_horizontal| ≤ g tan(max tilt)
    max_vertical_mps2: float    # |a_vertical| ≤ this
    integral_top_ms: float      # |∫e| ≤ this per axis (m s)
    table: tuple[SpinRow, ...]  # by increasing f_stuck


class SpinState(NamedTuple):
    """What the spin law remembers between ticks."""

    integral_ms: tuple[float, float, float]    # ∫ position error (m s, inertial)
    rho: float                                  # the spin-up fraction last tick
    total_n: float = 0.0                        # f_Σ commanded last tick (N)


class SpinInputs(NamedTuple):
    """One tick's measurements and reference (paper frame: inertial ENU z up, body FLU)."""

    position_m: tuple[float, float, float]
    velocity_mps: tuple[float, float, float]
    quaternion_wxyz: tuple[float, float, float, float]   # body FLU → inertial
    body_rates_radps: tuple[float, float, float]
    stuck_thrust_n: float                       # measured thrust of the attacked rotor
    target_m: tuple[float, float, float]        # where the mean should be (path point)
    target_velocity_mps: tuple[float, float, float]
    target_accel_mps2: tuple[float, float, float]


class SpinOutputs(NamedTuple):
    """The rotor thrusts and what a supervisor needs to judge the spin."""

    thrusts_n: tuple[float, float, float, float]    # physical rotors 1-4 (N); the attacked
    #                                                  one is its measured thrust
    exists: bool             # a relaxed hover holds m g at this f_stuck
    spin_radps: float        # Ω of the equilibrium (signed, about n̄)
    cone_rad: float          # θ̄: thrust axis to the spin axis
    drift_m: float           # radius of the circle the centre of mass runs about its mean
    vertical_excess_mps2: float  # where none exists: the least climb (+) / sink (−) left
    rho: float               # spin fraction ω'_z/ω̄_z ∈ [0, RHO_MAX]
    axis_error_rad: float    # angle between the spin-axis reference and n_des, in the body
    clipped: bool            # the allocation gave something up


def _lerp3(a: Vec3, b: Vec3, w: float) -> Vec3:
    """a + w (b − a), by component."""
    a1, a2, a3 = a
    b1, b2, b3 = b
    return (a1 + w * (b1 - a1), a2 + w * (b2 - a2), a3 + w * (b3 - a3))


def _lerp_gain(ka: Gain, kb: Gain, w: float) -> Gain:
    """ka + w (kb − ka), by entry."""
    (a1, a2, a3, a4), (a5, a6, a7, a8) = ka
    (b1, b2, b3, b4), (b5, b6, b7, b8) = kb
    return ((a1 + w * (b1 - a1), a2 + w * (b2 - a2), a3 + w * (b3 - a3), a4 + w * (b4 - a4)),
            (a5 + w * (b5 - a5), a6 + w * (b6 - a6), a7 + w * (b7 - a7), a8 + w * (b8 - a8)))


def _dot4(k: Vec4, x: Vec4) -> float:
    """k · x, summed left to right."""
    k1, k2, k3, k4 = k
    x1, x2, x3, x4 = x
    return k1 * x1 + k2 * x2 + k3 * x3 + k4 * x4


def _lerp(x: float, y: float, w: float) -> float:
    """x + w (y − x)."""
    return x + w * (y - x)


def _bracket(table: tuple[SpinRow, ...], f: float) -> tuple[bool, SpinRow, SpinRow, float]:
    """Whether f_stuck ``f`` lies between two rows, those rows and the weight w of the upper
    one (a + w (b − a)); at and beyond the table's ends not (False), the end row twice and
    w = 0."""
    first, last = table[0], table[-1]
    if f <= first.hover.f_stuck_n:
        return False, first, first, 0.0
    if f >= last.hover.f_stuck_n:
        return False, last, last, 0.0
    i = 0
    below = True        # every row from the second up to j lies below f
    for j in range(1, len(table) - 1):
        if below and table[j].hover.f_stuck_n < f:
            i = j
        else:
            below = False
    a, b = table[i], table[i + 1]
    return True, a, b, (f - a.hover.f_stuck_n) / (b.hover.f_stuck_n - a.hover.f_stuck_n)


def hover_at(table: tuple[SpinRow, ...], f: float) -> SpinHover:
    """The hover at f_stuck ``f`` (N): linear in f between the rows around it, the end row's
    beyond the table. A relaxed hover exists there when one exists at a row the blend gives
    weight to (1 − w to the lower, w to the upper)."""
    return _hover_between(_bracket(table, f))


def _hover_between(bracket: tuple[bool, SpinRow, SpinRow, float]) -> SpinHover:
    """:func:`hover_at` on the rows :func:`_bracket` found."""
    inside, below, above, w = bracket
    a, b = below.hover, above.hover
    if not inside:
        return a
    return SpinHover(
        _lerp(a.f_stuck_n, b.f_stuck_n, w), (a.exists and w < 1.0) or (b.exists and w > 0.0),
        _lerp(a.f4_n, b.f4_n, w), _lerp(a.f13_n, b.f13_n, w),
        _lerp3(a.rates_radps, b.rates_radps, w), _lerp3(a.axis, b.axis, w),
        _lerp(a.spin_radps, b.spin_radps, w), _lerp(a.total_n, b.total_n, w),
        _lerp(a.cone_rad, b.cone_rad, w), _lerp(a.drift_m, b.drift_m, w),
        _lerp(a.vertical_excess_mps2, b.vertical_excess_mps2, w),
        _lerp(a.margin_n, b.margin_n, w),
        _lerp(a.weight_lo_n, b.weight_lo_n, w), _lerp(a.weight_hi_n, b.weight_hi_n, w))


def gain_at(table: tuple[SpinRow, ...], f: float, rho: float) -> Gain:
    """K at f_stuck ``f`` (N) and spin fraction ``rho`` ∈ [0, RHO_MAX]: linear in f between
    the rows around it (as :func:`hover_at`), then in ρ between the schedule's points."""
    return _gain_between(_bracket(table, f), rho)


def _gain_between(bracket: tuple[bool, SpinRow, SpinRow, float], rho: float) -> Gain:
    """:func:`gain_at` on the rows :func:`_bracket` found."""
    inside, below, above, w = bracket
    k = rho * (RHO_STEPS / RHO_MAX)
    j = int(k)
    j = RHO_STEPS - 1 if j >= RHO_STEPS else j
    if inside:
        k_lo = _lerp_gain(below.gains[j], above.gains[j], w)
        k_hi = _lerp_gain(below.gains[j + 1], above.gains[j + 1], w)
    else:
        k_lo, k_hi = below.gains[j], below.gains[j + 1]
    return _lerp_gain(k_lo, k_hi, k - j)


def mat3(rows: Sequence[Sequence[float]]) -> Mat3:
    """A 3×3 matrix (rows) of floats, e.g. the canonical frame's integer rotation."""
    (a, b, c), (d, e, f), (g, h, i) = rows
    return ((float(a), float(b), float(c)), (float(d), float(e), float(f)),
            (float(g), float(h), float(i)))


def attitude(quat: tuple[float, float, float, float], rates: tuple[float, float, float],
             rot: Mat3) -> tuple[Mat3, float, float, float]:
    """R(q) of the unit quaternion ``quat`` (w, x, y, z) and the body rates ``rates`` (rad/s)
    in the canonical frame, ω' = rot ω (``rot``: the frame's rotation).
    One reading for the spin law and the coning hover."""
    qw, qx, qy, qz = quat
    R = ((1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qw * qz), 2 * (qx * qz + qw * qy)),
         (2 * (qx * qy + qw * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qw * qx)),
         (2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx * qx + qy * qy)))
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = rot
    wp, wq, wr = rates
    w0 = r00 * wp + r01 * wq + r02 * wr
    w1 = r10 * wp + r11 * wq + r12 * wr
    w2 = r20 * wp + r21 * wq + r22 * wr
    return R, w0, w1, w2


def mean_pid(kp: float, kd: float, ki: float, kt: float,
             integral_ms: tuple[float, float, float], target: SpinInputs | object,
             position_m: tuple[float, float, float], velocity_mps: tuple[float, float, float]
             ) -> tuple[float, float, float, float, float, float]:
    """The mean position's PID towards the target (point m, velocity m/s, acceleration m/s²
    of ``target``'s ``target_*`` fields) with the drag k_t/m v fed forward: the wanted mean
    acceleration (m/s², paper frame) and the position error e (m). One loop for the spin
    law and the coning hover (:mod:`~tfl_mav.control.spin.cone`), both steering the mean of
    a turning vehicle (``position_m``, ``velocity_mps``: the turning part removed)."""
    px, py, pz = position_m
    vx, vy, vz = velocity_mps
    tx, ty, tz = target.target_m                    # type: ignore[attr-defined]
    tvx, tvy, tvz = target.target_velocity_mps      # type: ignore[attr-defined]
    tax, tay, taz = target.target_accel_mps2        # type: ignore[attr-defined]
    ex, ey, ez = tx - px, ty - py, tz - pz
    ix_, iy_, iz_ = integral_ms
    ax = kp * ex + kd * (tvx - vx) + ki * ix_ + tax + kt * vx
    ay = kp * ey + kd * (tvy - vy) + ki * iy_ + tay + kt * vy
    az = kp * ez + kd * (tvz - vz) + ki * iz_ + taz + kt * vz
    return ax, ay, az, ex, ey, ez


def spin_step(params: SpinParams, state: SpinState, inputs: SpinInputs
              ) -> tuple[SpinState, SpinOutputs]:
    """One control period of the spin law (see the module docstring)."""
    p = params
    g = p.gravity_mps2
    m = p.mass_kg
    ix, iy, iz = p.inertia_kgm2
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = p.rot
    # --- 1. the attitude, canonical: R' = R rotᵀ, ω' = rot ω
    wp, wq, wr = inputs.body_rates_radps
    R, w0, w1, w2 = attitude(inputs.quaternion_wxyz, (wp, wq, wr), p.rot)
    # --- 2. outer loop: the wanted acceleration of the mean (inertial)
    px, py, pz = inputs.position_m
    vx, vy, vz = inputs.velocity_mps
    # The mean, not the cone's circle: the horizontal thrust a = (f_Σ/m) (b3x, b3y) turns at
    # the spin Ω_z = (R ω)_z, so the centre of mass runs v_c = (a_y, −a_x)/Ω_z about
    # x_c = −a/Ω_z² (ȧ = Ω e3 × a). Fed back, that circle is synchronous with the body: in
    # the body it is a constant bias of the axis the attitude loop holds (0.35 m/s of v_c
    # at 6 N tilts the wanted axis ~0.1 rad), which widens the cone, drops the vertical force
    # and slows the spin further. Removed before the PID.
    spin_i = R[2][0] * wp + R[2][1] * wq + R[2][2] * wr
    if spin_i > SPIN_MEAN_RADPS or spin_i < -SPIN_MEAN_RADPS:
        acc = state.total_n / m
        ahx, ahy = acc * R[0][2], acc * R[1][2]
        inv = 1.0 / spin_i
        vx, vy = vx - ahy * inv, vy + ahx * inv
        inv2 = inv * inv
        px, py = px + ahx * inv2, py + ahy * inv2
    ix_, iy_, iz_ = state.integral_ms
    ax, ay, az, ex, ey, ez = mean_pid(p.kp, p.kd, p.ki, p.k_t / m, state.integral_ms,
                                      inputs, (px, py, pz), (vx, vy, vz))
    limited = False     # the wanted acceleration or vertical force was cut to its range
    top = g * p.max_tilt_tan
    h = math.sqrt(ax * ax + ay * ay)
    if h > top:
        ax, ay, limited = ax * top / h, ay * top / h, True
    vtop = p.max_vertical_mps2
    if az > vtop or az < -vtop:
        az, limited = clamp(az, -vtop, vtop), True
    fx, fy, fz = m * ax, m * ay, m * (az + g)
    weight = math.sqrt(fx * fx + fy * fy + fz * fz)
    ndx, ndy, ndz = fx / weight, fy / weight, fz / weight
    f2 = inputs.stuck_thrust_n
    rows = _bracket(p.table, f2)        # 3. the equilibrium at the measured f_stuck
    hover = _hover_between(rows)
    if weight < hover.weight_lo_n or weight > hover.weight_hi_n:
        # keep the spin where the rotors hold it
        weight, limited = clamp(weight, hover.weight_lo_n, hover.weight_hi_n), True
    # n_des in the canonical body: rot Rᵀ n_des
    bx = R[0][0] * ndx + R[1][0] * ndy + R[2][0] * ndz
    by = R[0][1] * ndx + R[1][1] * ndy + R[2][1] * ndz
    bz = R[0][2] * ndx + R[1][2] * ndy + R[2][2] * ndz
    nx = r00 * bx + r01 * by + r02 * bz
    ny = r10 * bx + r11 * by + r12 * bz
    nz = r20 * bx + r21 * by + r22 * bz
    _, _, wbz = hover.rates_radps
    nbx, nby, nbz = hover.axis
    spin = hover.spin_radps
    # --- 4. the spin schedule: ρ and the reference (rate ρ Ω̄ n_ref, axis tilted in below ρ₀)
    rho = clamp(w2 / wbz, 0.0, RHO_MAX) if wbz != 0.0 else 1.0
    cone = math.acos(clamp(nbz, -1.0, 1.0))
    horiz = math.sqrt(nbx * nbx + nby * nby)
    ramp = rho / RHO_TILT
    th = cone * (ramp * ramp if ramp < 1.0 else 1.0)
    s_th = math.sin(th)
    ux, uy = (nbx / horiz, nby / horiz) if horiz > 0.0 else (0.0, 0.0)
    rx, ry, rz = s_th * ux, s_th * uy, math.cos(th)
    om = rho * spin
    orx, ory, orz = om * rx, om * ry, om * rz
    # the torques that balance this reference (E1), x and y
    tff_p = p.k_r * orx + (iz - iy) * ory * orz
    tff_q = p.k_r * ory + (ix - iz) * orx * orz
    # --- 5. reduced-attitude LQR, gains at ρ
    k_p, k_q = _gain_between(rows, rho)
    err = (w0 - orx, w1 - ory, nx - rx, ny - ry)    # (p, q, n_x, n_y) − reference
    tau_p = tff_p - _dot4(k_p, err)
    tau_q = tff_q - _dot4(k_q, err)
    # --- 6. allocation (canonical), f2 the measured thrust of the attacked rotor
    ell, fmax = p.arm_m, p.thrust_max_n
    clipped = False     # the allocation gave something up
    f4 = f2 + tau_p / ell
    if f4 < 0.0 or f4 > fmax:
        f4, clipped = clamp(f4, 0.0, fmax), True
    total = weight / (rz if rz > 0.3 else 0.3)
    s13 = total - f2 - f4
    half = 0.5 * tau_q / ell
    ah = abs(half)
    if ah > fmax:   # τ_q beyond what a pair can make at all: keep its sign
        half, ah, clipped = math.copysign(fmax, half), fmax, True
    lo, hi = 2.0 * ah, 2.0 * (fmax - ah)
    if lo > hi:     # τ_q so large no sum carries it: give up τ_q to the middle
        half = math.copysign(0.5 * fmax, half)
        lo = hi = fmax
        clipped = True
    if s13 < lo or s13 > hi:
        s13, clipped = clamp(s13, lo, hi), True
    f1, f3 = 0.5 * s13 - half, 0.5 * s13 + half
    c0, c1, c2, _ = p.perm     # physical rotor k: the canonical one perm maps to it
    out = [f1 if c0 == k else (f2 if c1 == k else (f3 if c2 == k else f4)) for k in range(4)]
    # --- the integral (anti-windup: frozen while the demand is limited or clipped)
    if not limited and not clipped:
        top_i = p.integral_top_ms
        ix_ = clamp(ix_ + ex * p.dt_s, -top_i, top_i)
        iy_ = clamp(iy_ + ey * p.dt_s, -top_i, top_i)
        iz_ = clamp(iz_ + ez * p.dt_s, -top_i, top_i)
    axis_err = math.acos(clamp(nx * rx + ny * ry + nz * rz, -1.0, 1.0))
    return (SpinState((ix_, iy_, iz_), rho, f1 + f2 + f3 + f4),
            SpinOutputs((out[0], out[1], out[2], out[3]), hover.exists, spin, hover.cone_rad,
                        hover.drift_m, hover.vertical_excess_mps2, rho, axis_err, clipped))
