"""The safe law's tick as explicit state and one pure step: a rotor attacked, or none.

:func:`safe_tick` is :meth:`~tfl_mav.control.safe.recovery.RecoveryLaw.update` with a rotor
attacked, :func:`healthy_tick` with four healthy rotors: the closest point of the path
(:func:`closest_point`, Newton on ⟨y − σ(λ), σ'(λ)⟩ = 0), the outer PID loop
(:func:`accel_demand`) and its conditional integral, then the three-rotor step
(:func:`~tfl_mav.control.safe.lost_rotor.lost_rotor_step`) or the four-rotor attitude loop
and mixer, in plain Python over tuples of floats. The path comes in as its σ kernel
(``sigma2((λ,))`` → σ, σ', σ''/2: the path's generated code, or :func:`no_path`), and the
accelerator seam compiles the three-rotor tick (:func:`tfl_mav.accel.native.obtain_function`)
with that kernel inlined — the same operations in the same order, the same bits — where it
is built; this very Python flies otherwise. :mod:`recovery` says what the law does and why.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, NamedTuple

from tfl_mav.control.allocation import allocate_nominal
from tfl_mav.control.safe.lost_rotor import lost_rotor_step, thrust_direction

__all__ = [
    "ATTACK_TAU_S",
    "ATT_KD",
    "ATT_KP",
    "INTEGRAL_BAND_M",
    "LAG_POLE_PRODUCT",
    "MAX_INTEGRAL_G",
    "MAX_TILT_RAD",
    "MAX_VERTICAL_G",
    "MIN_POS_OMEGA",
    "POS_OMEGA",
    "SETTLE_TAU_S",
    "SIDE_SHARE_FAST",
    "SIDE_SHARE_SLOW",
    "YAW_DAMP",
    "SafeParams",
    "SafeState",
    "Sigma2",
    "accel_demand",
    "attack_omega",
    "closest_point",
    "healthy_tick",
    "integrated",
    "no_path",
    "outer_loop_omega",
    "pid_gains",
    "safe_tick",
    "target",
]

MAX_TILT_RAD = math.radians(30.0)   # outer loop: horizontal acceleration ≤ g tan 30°
MAX_VERTICAL_G = 0.5                # outer loop: |vertical acceleration| ≤ 0.5 g
POS_OMEGA = 3.0                    # outer-loop triple pole (rad/s) with prompt motors …
LAG_POLE_PRODUCT = 0.1              # … and ω_p τ_m ≤ this with a motor lag τ_m …
MIN_POS_OMEGA = 1.25                # … but never below (rad/s): see :func:`outer_loop_omega`;
                                    # the four-rotor take-over's, under a 10 rad/s attitude loop
SIDE_SHARE_FAST = 0.9               # the side rotors carry this much of the weight: full ω_p …
SIDE_SHARE_SLOW = 0.6               # … this little: MIN_POS_OMEGA (:func:`attack_omega`)
ATTACK_TAU_S = 2.0                  # … the attack low-passed over this (s) for it
MAX_INTEGRAL_G = 0.2                # |integral action| ≤ 0.2 g per axis (a 20 % model error)
INTEGRAL_BAND_M = 0.05              # the integral learns within this of its target (m),
                                    # or farther once the vehicle has settled
TAN_MAX_TILT = math.tan(MAX_TILT_RAD)
ATT_KP = 100.0                      # four healthy rotors: reduced attitude (10 rad/s)² …
ATT_KD = 20.0                       # … critically damped
YAW_DAMP = 2.0                      # … and r decays at 2 /s
SETTLE_TAU_S = 0.5                  # … over this: a spinning vehicle's wobble (≥ 5 Hz) averages
                                    # out; and a law's start passes (the integral waits it)


class SafeParams(NamedTuple):
    """The safe law's constants."""

    model: tuple[float, ...]    # (m kg, k_t N s/m, g m/s², l m, f_max N): lost_rotor_step's
    speed_mps: float            # the speed along the path
    dt_s: float                 # control period (s): the integral's step
    omega_p_radps: float        # the three-rotor outer loop's fastest pole (rad/s,
                                # :func:`outer_loop_omega`); each tick's: :func:`attack_omega`
    has_path: bool              # False: a point is held, no path to project on
    thrust_known: bool          # f_max and the mass make the climb authority (False where
                                # forces the model lacks act: :func:`accel_demand`)
    airframe: tuple[float, float, float, float, float]  # (I_x, I_y, I_z kg m², k_r N m s,
                                # d m): the four-rotor attitude loop's (:func:`healthy_tick`)


def outer_loop_omega(motor_time_constant_s: float, noisy: bool) -> float:
    """The three-rotor outer loop's fastest triple pole ω_p (rad/s) for motors that lag by
    τ_m (s, the controller's model): POS_OMEGA, lowered to LAG_POLE_PRODUCT/τ_m, never below
    MIN_POS_OMEGA; MIN_POS_OMEGA where the measurements are ``noisy`` (rpm or state noise,
    an onboard estimator, moving air): what a stiffer loop gains on the model's errors it
    pays there in noise (the realistic sensors behind the EKF: 65 → 83 mm at 3 rad/s).

    Why these: the position error a dead rotor leaves is the acceleration the loop does not
    feed forward (the spinning attitude loop's lag behind a turning thrust direction, the
    model's errors before the integral has learnt them) over k_p = 3ω_p², so it falls as
    1/ω_p² — the paper path with a dead rotor, exact model: 4.2 mm at 1.25 rad/s, 0.08 mm at
    3. The pole is bounded by the attitude loop under the spin, whose bandwidth the motor lag
    takes: a dead rotor with 50 ms lag flies at ω_p = 2.5 rad/s (0.3 mm), rings at 3 (6 mm),
    crashes at 4; with 60 ms it diverges at 3. ω_p τ_m ≤ 0.1 keeps a factor ≥ 1.5 to the
    ring with a lag the model underestimates by 30 %. Faster than 3 rad/s buys little
    (the error is already the attitude loop's) and leaves less margin to wind and sensor
    noise."""
    if noisy:
        return MIN_POS_OMEGA
    if motor_time_constant_s > 0.0:
        w = LAG_POLE_PRODUCT / motor_time_constant_s
        w = POS_OMEGA if w > POS_OMEGA else w
        return MIN_POS_OMEGA if w < MIN_POS_OMEGA else w
    return POS_OMEGA


def attack_omega(omega_p_radps: float, attack_n: float, weight_n: float) -> float:
    """The three-rotor outer loop's pole (rad/s) with the attacked rotor at ``attack_n``
    (N, within [0, f_max]): ``omega_p_radps`` while the two side rotors carry at least
    SIDE_SHARE_FAST of the weight (N), MIN_POS_OMEGA from SIDE_SHARE_SLOW down, linear
    between. The side rotors make u_f − 2A and, from its difference, all of τ_q: the less
    of the weight they carry the sooner the spinning attitude loop saturates, and a stiff
    outer loop there drives it into a limit cycle (a constant 5 N: 0.15 m at 1.25 rad/s,
    lost at 2)."""
    share = (weight_n - 2.0 * attack_n) / weight_n
    k = (share - SIDE_SHARE_SLOW) / (SIDE_SHARE_FAST - SIDE_SHARE_SLOW)
    k = 0.0 if k < 0.0 else (1.0 if k > 1.0 else k)
    return MIN_POS_OMEGA + k * (omega_p_radps - MIN_POS_OMEGA)


def pid_gains(omega_p_radps: float) -> tuple[float, float, float]:
    """(k_p 1/s², k_d 1/s, k_i 1/s³) placing the outer loop's poles at (s + ω_p)³."""
    w = omega_p_radps
    return 3.0 * w * w, 3.0 * w, w * w * w


class SafeState(NamedTuple):
    """What the safe law remembers between ticks."""

    lam: float                          # the path parameter of the closest point
    holding: bool                       # holding ``hold_m`` (told to, or the path lost)
    hold_m: tuple[float, float, float]  # the held point (m)
    integral_mps2: tuple[float, float, float]   # the integral action k_i ∫e (m/s²,
                                                # inertial): what the loop has learnt
    drift_mps: tuple[float, float, float]       # v − v_target across the path, low-passed
                                                # over SETTLE_TAU_S (m/s)
    drift_age_s: float                  # how long the filter has run (0: the law has just
                                        # started: it starts at the first velocity)
    attack_lp_n: float                  # the attack estimate low-passed over ATTACK_TAU_S
                                        # (N; started at the first estimate): the pole's


Sigma2 = Callable[[tuple[float]], tuple[float, ...]]
"""A path's σ kernel: ``sigma2((λ,))`` → σ, σ', σ''/2 at λ (nine floats, x y z of each)."""


def no_path(a0: tuple[float]) -> tuple[float, ...]:
    """The σ kernel of a law without a path (``SafeParams.has_path`` False: it holds a
    point and never evaluates it): zeros."""
    return (0.0,) * 9


def closest_point(sigma2: Sigma2, lam: float, y: tuple[float, float, float]
                  ) -> tuple[bool, float, tuple[float, float, float],
                             tuple[float, float, float], tuple[float, float, float], float]:
    """Newton from ``lam`` on ⟨y − σ(λ), σ'(λ)⟩ = 0 on the path of ``sigma2``: (found, the
    new λ — the old one if Newton left the reals —, the point, the unit tangent T, the
    curvature vector κN, the distance m). σ, σ' and σ'' come exactly from one ``sigma2``
    evaluation a step."""
    yx, yy, yz = y
    lam0 = lam
    for _ in range(8):
        c0x, c0y, c0z, c1x, c1y, c1z, c2x, c2y, c2z = sigma2((lam,))
        ex, ey, ez = yx - c0x, yy - c0y, yz - c0z
        g = ex * c1x + ey * c1y + ez * c1z
        dg = 2.0 * (ex * c2x + ey * c2y + ez * c2z) - (c1x * c1x + c1y * c1y + c1z * c1z)
        step = -g / dg if dg < 0.0 else -0.1 * math.copysign(1.0, g)
        step = -0.5 if step < -0.5 else (0.5 if step > 0.5 else step)
        lam += step
        if abs(step) < 1e-9:
            break
    found, lam_out, dist = False, lam0, 0.0
    point = tangent = curvature = (0.0, 0.0, 0.0)
    if math.isfinite(lam):
        lam_out = lam
        c0x, c0y, c0z, c1x, c1y, c1z, c2x, c2y, c2z = sigma2((lam,))
        s1sq = c1x * c1x + c1y * c1y + c1z * c1z
        if s1sq > 0.0:
            found = True
            s1 = math.sqrt(s1sq)
            tx, ty, tz = c1x / s1, c1y / s1, c1z / s1
            # κN = (σ'' − (σ''·T) T)/|σ'|², σ'' = 2 c2
            d2x, d2y, d2z = 2.0 * c2x, 2.0 * c2y, 2.0 * c2z
            a = d2x * tx + d2y * ty + d2z * tz
            ex, ey, ez = yx - c0x, yy - c0y, yz - c0z
            point, tangent = (c0x, c0y, c0z), (tx, ty, tz)
            curvature = ((d2x - a * tx) / s1sq, (d2y - a * ty) / s1sq, (d2z - a * tz) / s1sq)
            dist = math.sqrt(ex * ex + ey * ey + ez * ez)
    return found, lam_out, point, tangent, curvature, dist


def accel_demand(p: SafeParams, target: tuple[float, float, float],
                 tangent: tuple[float, float, float], curvature: tuple[float, float, float],
                 integral: tuple[float, float, float], drift: tuple[float, float, float],
                 drift_age_s: float, y: tuple[float, float, float],
                 v: tuple[float, float, float], g: float, on_path: float,
                 omega_p_radps: float, thrust_max_n: float
                 ) -> tuple[float, float, float, tuple[float, float, float], float,
                            tuple[float, float, float], float]:
    """The outer loop's wanted acceleration (m/s², z up): PID towards ``target`` (the
    closest path point, with the path's speed × tangent and centripetal term when
    ``on_path``; else a held point, velocity zero), poles at (s + ``omega_p_radps``)³
    (:func:`pid_gains`), limited to MAX_TILT_RAD and
    ±MAX_VERTICAL_G, and to what ``thrust_max_n`` (the most the rotors can make along b3,
    N) can fly with the model mass m: vertically within ±(thrust_max_n/m − g) — never a
    descent faster than the rotors can arrest: a heavy airframe on two side rotors climbs at
    0.1-0.2 g, and a dive at 0.5 g from half a metre is a crash —, horizontally within
    √((thrust_max_n/m)² − (g + a_z)²), the tilt the vertical demand leaves. A vehicle that
    cannot hover (thrust_max_n ≤ m g), or whose authority is not known (0), keeps the fixed
    limits: where the rotors' inflow and the wind act the estimated mass carries forces that
    are not mass (1.14 kg for 1.0 in the built-in ``realistic``), and limits drawn from it
    cost the flight 10-30 %. Returns (a_x, a_y, a_z, the
    position error e m, integrate, the new drift m/s and its age s).

    ``integrate`` says whether e may enter the integral (conditional integration): not on a
    limited demand, not before the law has flown SETTLE_TAU_S since it started
    (``drift_age_s``), and beyond INTEGRAL_BAND_M of the target only once the vehicle has
    settled: v − v_target across the path, low-passed over SETTLE_TAU_S (``drift``, started at
    the first tick's value when ``drift_age_s`` is 0) below ω_p INTEGRAL_BAND_M — a vehicle at
    rest when a law starts is about to move, not held off.
    An integral fed on the approach (a take-over a metre off the path) is a debt of ~0.3 m s
    that the loop pays back as an overshoot of 0.15 m decaying at ω_p/3; a steady force (mass
    error, drag) holds the vehicle still off its target, settled, and is learnt wherever it
    leaves it. Nor is a law's own start a steady force: a take-over on the path spins the
    vehicle up (r to the three-rotor equilibrium with the yaw drag's I_z/k_r ≈ 0.5 s), and
    the ~10 mm its first 0.3 s leave, learnt, banked ~0.06 m/s². What the path then turns
    along its tangent the error no longer shows (the closest point moves with it), so the
    loop unlearns it only as fast as the path turns: a circle of 3 m at 0.5 m/s carried
    0.014 m/s² for 20 s, 0.09 mm off where the safe law flown from the start holds 0.006."""
    w = omega_p_radps
    kp, kd = 3.0 * w * w, 3.0 * w       # (s + ω_p)³, as pid_gains; k_i is in the integral
    settled_mps = w * INTEGRAL_BAND_M
    e = (target[0] - y[0], target[1] - y[1], target[2] - y[2])
    ff = (0.0, 0.0, 0.0)
    vt = (0.0, 0.0, 0.0)
    if on_path:
        sp = p.speed_mps
        sp2 = sp * sp
        vt = (sp * tangent[0], sp * tangent[1], sp * tangent[2])
        ff = (kd * sp * tangent[0] + sp2 * curvature[0], kd * sp * tangent[1]
              + sp2 * curvature[1], kd * sp * tangent[2] + sp2 * curvature[2])
    # Settled: the vehicle moves across the path (or against a held point) slower than the
    # loop closes a band-sized error. On an approach it is not; held off by a steady force it
    # is. Along the path it may fly faster or slower than the path speed (a tangential force
    # against k_d: the closest point moves with it, so no error, and nothing to learn).
    wx, wy, wz = v[0] - vt[0], v[1] - vt[1], v[2] - vt[2]
    wt = wx * tangent[0] + wy * tangent[1] + wz * tangent[2] if on_path else 0.0
    if on_path:
        wx, wy, wz = wx - wt * tangent[0], wy - wt * tangent[1], wz - wt * tangent[2]
    if drift_age_s > 0.0:
        k = p.dt_s / SETTLE_TAU_S
        wx, wy, wz = (drift[0] + k * (wx - drift[0]), drift[1] + k * (wy - drift[1]),
                      drift[2] + k * (wz - drift[2]))
    started = drift_age_s >= SETTLE_TAU_S
    settled = wx * wx + wy * wy + wz * wz <= settled_mps * settled_mps
    near = e[0] * e[0] + e[1] * e[1] + e[2] * e[2] <= INTEGRAL_BAND_M * INTEGRAL_BAND_M
    a0 = kp * e[0] - kd * v[0] + ff[0] + integral[0]
    a1 = kp * e[1] - kd * v[1] + ff[1] + integral[1]
    a2 = kp * e[2] - kd * v[2] + ff[2] + integral[2]
    lim = MAX_VERTICAL_G * g
    top = thrust_max_n / p.model[0]          # the most acceleration along b3 (m/s²)
    lim = top - g if g < top < g + lim else lim
    az = lim if a2 > lim else (-lim if a2 < -lim else a2)
    ah = math.hypot(a0, a1)
    amax = (g + az) * TAN_MAX_TILT
    if top > g:
        side = top * top - (g + az) * (g + az)
        side = math.sqrt(side) if side > 0.0 else 0.0
        amax = side if side < amax else amax
    limited = az != a2
    if ah > amax:
        a0 *= amax / ah
        a1 *= amax / ah
        limited = True
    integrate = (near or settled) and started and not limited
    return a0, a1, az, e, integrate, (wx, wy, wz), drift_age_s + p.dt_s


def integrated(integral: tuple[float, float, float], e: tuple[float, float, float],
               ki_dt: float, top_mps2: float) -> tuple[float, float, float]:
    """The integral action k_i ∫e (m/s²) after one tick flown as asked, ``ki_dt`` = k_i × the
    control period: the position error enters only on a tick whose demand was flown as
    asked — neither limited by the tilt/vertical caps nor clipped by the allocation (a
    rotor at a bound: the wanted thrust or τ_q was not made; the callers decide) — and never
    past ``top_mps2`` per axis (MAX_INTEGRAL_G g), so a wrong integral costs at most that.
    Held as an acceleration, not as ∫e, what it has learnt stays what it is when the
    loop's pole moves (:func:`attack_omega`) or the four-rotor tick takes over. An attack
    near m g/2 leaves the side rotors almost nothing (f₁ + f₃ = u_f − 2A): an integral fed
    through that saturation winds up into a limit cycle metres wide. A non-finite error is
    left out."""
    e0, e1, e2 = e
    if math.isfinite(e0 + e1 + e2):          # a finite sum: all three finite
        i0, i1, i2 = integral
        i0, i1, i2 = i0 + e0 * ki_dt, i1 + e1 * ki_dt, i2 + e2 * ki_dt
        top = top_mps2
        integral = ((top if i0 > top else (-top if i0 < -top else i0)),
                    (top if i1 > top else (-top if i1 < -top else i1)),
                    (top if i2 > top else (-top if i2 < -top else i2)))
    return integral


def target(p: SafeParams, sigma2: Sigma2, lam: float, holding: bool,
           hold: tuple[float, float, float], y: tuple[float, float, float]) -> tuple[Any, ...]:
    """What the outer loop flies to: (found, λ, holding, the held point, the target
    point, unit tangent, curvature vector κN, path distance m — NaN when holding). The
    closest path point; a held point when told to hold or when the path is lost (then
    where the vehicle is)."""
    found, point, tangent, curvature, dist = False, hold, hold, hold, math.nan
    if p.has_path and not holding:
        found, lam, point, tangent, curvature, dist = closest_point(sigma2, lam, y)
        if not found:
            dist = math.nan
    if not found:
        if not holding:             # no path, or it was lost: hold where the vehicle is
            hold = (y[0], y[1], y[2])
            holding = True
        point = hold
    return found, lam, holding, hold, point, tangent, curvature, dist


def safe_tick(p: SafeParams, s: SafeState, inputs: tuple[Any, ...], sigma2: Sigma2
              ) -> tuple[SafeState, tuple[Any, ...]]:
    """One tick with a rotor attacked, on the path of ``sigma2``. ``inputs``: position m,
    velocity m/s, attitude (w, x, y, z; normalised here), body rates rad/s, the attacked
    rotor's thrust estimate N, the canonical frame's rotation rows 1-2, the canonical rotor
    of each physical one (0-3), the LQR gains (two rows of four).

    Returns the new state and (the thrusts of the physical rotors 1-4 N, tilt error rad,
    path distance m — NaN when holding —, u_f N, clamped per physical rotor: its
    unconstrained demand left [0, f_max])."""
    y, v, quat, rates, attack_n, rot, inverse, gains = inputs
    qw, qx, qy, qz = quat
    nq = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    q = (qw / nq, qx / nq, qy / nq, qz / nq)
    lam, holding, hold, integral, drift, drift_age, attack_lp = s
    g, fmax = p.model[2], p.model[4]
    found, lam, holding, hold, point, tangent, curvature, dist = target(p, sigma2, lam,
                                                                        holding, hold, y)
    # The most along b3: the two side rotors at f_max, the attacked one at its estimate and
    # the opposite one balancing it in roll (lost_rotor_step's f₄ = A + τ_p/l).
    an = 0.0 if attack_n < 0.0 else (fmax if attack_n > fmax else attack_n)
    # The pole follows the attack's level, not its steps: an intermittent attack switching
    # the gains at each step kicked the vehicle (0-5 N at 0.4 Hz: 21.6 mm on the slow pole,
    # 11.2 on the fast one, 29.5 switching between them).
    attack_lp = an if drift_age <= 0.0 else attack_lp + p.dt_s / ATTACK_TAU_S * (an - attack_lp)
    w = attack_omega(p.omega_p_radps, attack_lp, p.model[0] * g)
    a0, a1, a2, e, integrate, drift, drift_age = accel_demand(
        p, point, tangent, curvature, integral, drift, drift_age, y, v, g, found, w,
        2.0 * fmax + 2.0 * an if p.thrust_known else 0.0)
    tilt_err, uf, c0, c1, c2, c3, made, d0, d2, d3 = lost_rotor_step(
        (a0, a1, a2), (v[0], v[1], v[2]), q, rates, rot, (*gains[0], *gains[1]), p.model,
        attack_n)
    if made and integrate:
        integral = integrated(integral, e, w * w * w * p.dt_s, MAX_INTEGRAL_G * g)
    canon, req = (c0, c1, c2, c3), (d0, c1, d2, d3)
    hi = fmax + 1e-9
    f = tuple(canon[k] for k in inverse)
    clamped = tuple(not -1e-9 <= req[k] <= hi for k in inverse)
    return (SafeState(lam, holding, hold, integral, drift, drift_age, attack_lp),
            (f, tilt_err, dist, uf, clamped))


def healthy_tick(p: SafeParams, s: SafeState, inputs: tuple[Any, ...], sigma2: Sigma2
                 ) -> tuple[SafeState, tuple[Any, ...]]:
    """One tick with four healthy rotors (a take-over with no rotor attacked): the outer loop
    as :func:`safe_tick` flies it, the reduced attitude h = Rᵀ n by a PD on (−h₂, h₁) through
    τ_p, τ_q with the gyroscopic terms, a yaw-rate damper, and the nominal mixer (eq. (4)
    inverted, yaw given up first, each rotor within [0, f_max]). ``inputs``: position m,
    velocity m/s, attitude (w, x, y, z; normalised here), body rates rad/s.

    Returns the new state and (the thrusts of rotors 1-4 N, tilt error rad, path distance m
    — NaN when holding —, u_f N, clamped per rotor: its demand left [0, f_max])."""
    y, v, quat, rates = inputs
    qw, qx, qy, qz = quat
    nq = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    q = (qw / nq, qx / nq, qy / nq, qz / nq)
    lam, holding, hold, integral, drift, drift_age, attack_lp = s
    m, k_t, g, ell, fmax = p.model
    found, lam, holding, hold, point, tangent, curvature, dist = target(p, sigma2, lam,
                                                                        holding, hold, y)
    a0, a1, a2, e, integrate, drift, drift_age = accel_demand(
        p, point, tangent, curvature, integral, drift, drift_age, y, v, g, found,
        MIN_POS_OMEGA, 4.0 * fmax if p.thrust_known else 0.0)
    ix, iy, iz, k_r, d_m = p.airframe
    pr, qr, rr = rates
    tilt_err, uf, h0, h1, _h2 = thrust_direction((a0, a1, a2), v, q, m, k_t, g)
    tau_p = ix * (ATT_KP * -h1 - ATT_KD * pr) + (iz - iy) * qr * rr + k_r * pr
    tau_q = iy * (ATT_KP * h0 - ATT_KD * qr) + (ix - iz) * pr * rr + k_r * qr
    tau_r = -iz * YAW_DAMP * rr + k_r * rr
    req = allocate_nominal(uf, tau_p, tau_q, tau_r, ell, d_m)
    f = allocate_nominal(uf, tau_p, tau_q, tau_r, ell, d_m, fmax)
    clamped = tuple(not -1e-9 <= x <= fmax + 1e-9 for x in req)
    if integrate and not (clamped[0] or clamped[1] or clamped[2] or clamped[3]):
        ki_dt = MIN_POS_OMEGA * MIN_POS_OMEGA * MIN_POS_OMEGA * p.dt_s
        integral = integrated(integral, e, ki_dt, MAX_INTEGRAL_G * g)
    return (SafeState(lam, holding, hold, integral, drift, drift_age, attack_lp),
            (tuple(f), tilt_err, dist, uf, clamped))
