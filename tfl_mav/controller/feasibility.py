"""What the vehicle can physically do, stated before a flight.

From the mixer (eq. (4)) and the per-rotor limits [0, f_max], in the canonical frame of an
attack on rotor 2 (:mod:`tfl_mav.control.allocation`): τ_p = l(f4 − A) must average zero
(no steady roll torque can be balanced at low body rates), so f4 = A, and the total thrust
u_f = 2A + f1 + f3 with f1, f3 ∈ [0, f_max]. Hence

* hover needs 2A ≤ m g ≤ 2A + 2 f_max, i.e. A ≤ m g / 2 (and A ≥ m g/2 − f_max), and the
  most thrust the path asks must be ≤ 2A + 2 f_max too (a heavier airframe with a dead rotor);
* along a path flown at speed s the thrust must supply m (s² κ N + g e3) + k_t v, so its
  smallest component along b3 — at the top of a bend curving down — must be ≥ 2A: the
  attack must stay below u_min / 2, and u_min > 0 for any vehicle (a rotor cannot push);
* the TFL attacked law makes τ_p ∈ [−lA, l(f_max − A)]: near A = 0 of one sign only. Where
  it keeps asking for the other (:mod:`tfl_mav.controller.supervisor`), the reduced-attitude
  law flies (:mod:`tfl_mav.control.safe.recovery`).

:func:`path_demand` computes the path's required acceleration from σ(λ) at the scenario's
speed (κN from σ' and σ''), :func:`check_scenario` turns all of it into one-line warnings.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tfl_mav.scenario import Scenario

__all__ = ["PathDemand", "attack_limit_n", "check_scenario", "feasible_speed_mps", "path_demand"]


@dataclass(frozen=True)
class PathDemand:
    """The path's demand at the scenario speed (paper frame, z up)."""

    max_accel_mps2: float       # max |s² κ| over the path
    min_vertical_mps2: float    # min of the required vertical acceleration (most downward)
    min_thrust_n: float         # min over the path of the total thrust needed (N)
    max_thrust_n: float         # max … (N)
    max_tilt_rad: float         # max angle of the needed thrust from vertical


def path_demand(sc: Scenario, n: int = 4001) -> PathDemand:
    """Required acceleration and thrust along the scenario's path at its speed."""
    from tfl_mav.from_scenario import scenario_path

    path = scenario_path(sc)
    lo, hi = path.lam_range
    lam = np.linspace(lo, hi, n)
    h = 1e-4

    def sig(x: np.ndarray) -> np.ndarray:
        return np.array([np.asarray(c, dtype=float) + 0 * x for c in path.sigma(x)])

    p0, pp, pm = sig(lam), sig(lam + h), sig(lam - h)
    d1 = (pp - pm) / (2 * h)
    d2 = (pp - 2 * p0 + pm) / (h * h)
    s1 = np.linalg.norm(d1, axis=0)
    t = d1 / s1
    kn = (d2 - np.sum(d2 * t, axis=0) * t) / s1 ** 2
    s = sc.path.speed_mps
    a = s * s * kn
    v = sc.vehicle
    m, g = v.mass_kg, v.gravity_mps2
    f = m * a + v.k_t * s * t
    f[2] += m * g
    fn = np.linalg.norm(f, axis=0)
    # A rotor cannot pull: where the needed force points down the thrust must be negative.
    u = np.where(f[2] > 0, fn, -fn)
    tilt = np.arccos(np.clip(f[2] / np.maximum(fn, 1e-12), -1.0, 1.0))
    return PathDemand(float(np.max(np.linalg.norm(a, axis=0))), float(np.min(a[2])),
                      float(np.min(u)), float(np.max(u)), float(np.max(tilt)))


# The margins a speed must leave to be flown (feasible_speed_mps): the least thrust along the
# path at least half the hover thrust (the law needs room to correct downward), the most at
# most 80 % of 4 f_max, the thrust at most 45° from vertical.
MIN_THRUST_HOVER_FRACTION = 0.5
MAX_THRUST_FRACTION = 0.8
MAX_TILT_RAD = math.radians(45.0)


def _speed_ok(sc: Scenario, d: PathDemand) -> bool:
    v = sc.vehicle
    mg = v.mass_kg * v.gravity_mps2
    return (d.min_thrust_n >= MIN_THRUST_HOVER_FRACTION * mg
            and d.max_thrust_n <= MAX_THRUST_FRACTION * 4.0 * v.thrust_max_n
            and d.max_tilt_rad <= MAX_TILT_RAD)


def feasible_speed_mps(sc: Scenario) -> float:
    """The scenario's path speed if the vehicle can fly it with the margins above, else the
    highest speed (to 1 %) that it can: the path's acceleration grows as s² κ, so slowing
    down is the one way to make a too-tight bend flyable. Never above the asked speed."""
    s_req = sc.path.speed_mps
    if s_req <= 0.0 or _speed_ok(sc, path_demand(sc)):
        return s_req
    lo, hi = 0.0, s_req
    for _ in range(12):
        mid = 0.5 * (lo + hi)
        if _speed_ok(sc, path_demand(sc.replace(**{"path.speed_mps": mid}), n=1001)):
            lo = mid
        else:
            hi = mid
    return lo


def attack_limit_n(sc: Scenario, demand: PathDemand | None = None) -> float:
    """Largest constant attack thrust A (N) with which the path can still be flown."""
    d = demand or path_demand(sc)
    return max(0.0, min(d.min_thrust_n, sc.vehicle.mass_kg * sc.vehicle.gravity_mps2) / 2.0)


def _attack_range(sc: Scenario) -> tuple[float, float] | None:
    """The attack's (min, max) thrust when the signal fixes it, else None."""
    a = sc.attack
    fmax = sc.vehicle.thrust_max_n

    def clamp(x: float) -> float:
        return min(max(x, 0.0), fmax)

    if not a.rotor:
        return None
    if a.signal == "off":
        return 0.0, 0.0
    if a.signal == "constant":
        return clamp(a.value_n), clamp(a.value_n)
    if a.signal == "step":
        lo, hi = sorted((clamp(a.initial_n), clamp(a.value_n)))
        return lo, hi
    if a.signal in ("paper", "ramp"):
        end = sc.run.duration_s
        if a.signal == "paper":            # 0.1 t + sin z
            return 0.0, clamp(0.1 * end + 1.0)
        ends = (a.initial_n, a.initial_n + a.rate_nps * max(end - a.start_s, 0.0))
        return clamp(min(ends)), clamp(max(ends))
    if a.signal == "sine":
        return clamp(a.offset_n - abs(a.amplitude_n)), clamp(a.offset_n + abs(a.amplitude_n))
    return None


def check_scenario(sc: Scenario) -> list[str]:
    """One-line warnings for what the scenario asks beyond the physics (empty: feasible)."""
    from tfl_mav.control.safe.takeover import A_HANDBACK_N

    out: list[str] = []
    v = sc.vehicle
    mg = v.mass_kg * v.gravity_mps2
    try:
        with np.errstate(all="ignore"):    # said below in words, never as numpy warnings
            d = path_demand(sc)
    except Exception as exc:  # a bad path is reported by the path check itself
        return [f"path: cannot evaluate its demand ({exc})"]
    if not all(math.isfinite(x) for x in (d.min_thrust_n, d.max_thrust_n, d.max_tilt_rad)):
        return ["path: its demand (curvature, thrust) is not finite somewhere on its t range: "
                "check path.sigma there; no feasibility figures"]
    if d.min_thrust_n <= 0.0:
        out.append(f"path at {sc.path.speed_mps:g} m/s needs {-d.min_vertical_mps2:.1f} m/s^2 "
                   f"downward at its top bend (> g = {v.gravity_mps2:g}): rotors cannot pull, "
                   f"the path cannot be followed at that speed; it will be flown at "
                   f"{feasible_speed_mps(sc):.2f} m/s")
    elif d.max_tilt_rad > math.radians(60.0):
        out.append(f"path at {sc.path.speed_mps:g} m/s needs a {math.degrees(d.max_tilt_rad):.0f}"
                   " deg tilt: beyond what the controllers are made for")
    if d.max_thrust_n > 4.0 * v.thrust_max_n:
        out.append(f"path needs {d.max_thrust_n:.1f} N total thrust > 4 x f_max")
    rng = _attack_range(sc)
    if rng is not None:
        a_lo, a_hi = rng
        limit = attack_limit_n(sc, d)
        if a_hi > limit:
            out.append(f"attack on rotor {sc.attack.rotor} reaches {a_hi:.2f} N > "
                       f"{limit:.2f} N (half the least thrust the path needs, "
                       f"mg/2 = {mg / 2:.2f} N): no attitude hold exists there; the spin "
                       "law flies a relaxed hover about a tilted axis (docs/relaxed-hover.md) "
                       "and says so where no spin holds the weight either")
            out += _no_spin(sc, max(a_lo, mg / 2.0), a_hi)
        # With the attitude held the opposite rotor matches A, so the thrust is at most
        # 2A + 2 f_max: the two side rotors carry the rest of what the path asks.
        ceiling = 2.0 * a_lo + 2.0 * v.thrust_max_n
        if d.max_thrust_n > ceiling:
            out.append(f"attack on rotor {sc.attack.rotor} down to {a_lo:.2f} N: with the "
                       f"attitude held the rotors make at most 2A + 2 f_max = {ceiling:.1f} N "
                       f"and the path at {sc.path.speed_mps:g} m/s asks up to "
                       f"{d.max_thrust_n:.1f} N (weight {mg:.1f} N): the vehicle sinks off "
                       "the path where it asks more; fly it slower or lighter")
        if a_lo < A_HANDBACK_N:
            spin = v.drag_thrust_ratio_m * (mg - 4.0 * a_lo) / v.k_r
            out.append(f"attack on rotor {sc.attack.rotor} down to {a_lo:.2f} N: near 0 N the "
                       "TFL law can roll one way only; where it needs the other way for "
                       f"long, the reduced-attitude law flies (spinning at ~{spin:.0f} rad/s)")
    out += unread_attack_keys(sc)
    return out


def _no_spin(sc: Scenario, lo_n: float, hi_n: float) -> list[str]:
    """The attack's thrusts above m g/2 (every 0.5 N from ``lo_n`` to ``hi_n``) at which the
    airframe has no relaxed hover holding m g, in one line with the numbers: the coning
    hover (:mod:`tfl_mav.control.spin.cone`) flies there instead."""
    from tfl_mav.control.spin import equilibrium
    from tfl_mav.control.spin.cone import ROOM_N
    from tfl_mav.control.spin.law import equilibrium_or_closest

    v, c = sc.vehicle, sc.controller
    a = equilibrium.airframe_from_scenario(v, sc.attack.rotor, c.model_mass_scale,
                                           c.model_inertia_scale)
    mg = a.mass_kg * a.gravity_mps2
    none, short = [], []
    for f in np.unique(np.append(np.arange(lo_n, hi_n, 0.5), hi_n)):
        try:
            with np.errstate(all="ignore"):
                _, exists, w = equilibrium_or_closest(a, float(f))
        except ValueError:
            none.append(float(f))
            continue
        if not exists:
            short.append((float(f), (w - mg) / a.mass_kg))
    where = (f"for this airframe (yaw drag {v.drag_thrust_ratio_m:g} m, k_r {v.k_r:g} N m s, "
             f"J {list(v.inertia_kgm2)})")
    out = []
    bad = sorted([f for f, _ in short] + none)
    if bad:
        top = bad[-1]
        total = 2.0 * top + ROOM_N
        tilt = math.degrees(math.acos(min(1.0, mg / total)))
        out.append(f"attack on rotor {sc.attack.rotor}: no relaxed hover holds the weight at "
                   f"{', '.join(f'{f:.2f}' for f in bad)} N {where}: keeping the attitude "
                   f"takes >= {2 * top:.1f} N against a weight of {mg:.1f} N; a coning hover "
                   f"flies instead (the thrust, {total:.1f} N, tilted {tilt:.0f} deg so that "
                   "its vertical part is the weight, swung round the vertical)"
                   + ("; at f_max the opposite rotor has no roll torque of one sign left and "
                      "it may not hold" if top >= v.thrust_max_n - 1e-9 else ""))
    return out


# The [attack] keys each built-in signal reads (tfl_mav.sitl.attacker.Attacker._raw). A GCS's
# MAV_CMD_INJECT_FAILURE DRIFT flies "ramp" whatever the scenario's signal, so rate_nps and
# initial_n are read then too: a warning, not an error.
SIGNAL_KEYS: dict[str, frozenset[str]] = {
    "constant": frozenset({"value_n"}),
    "step": frozenset({"value_n", "initial_n", "step_after_s"}),
    "ramp": frozenset({"initial_n", "rate_nps"}),
    "sine": frozenset({"amplitude_n", "frequency_hz", "offset_n"}),
}
_SIGNAL_ONLY_KEYS = frozenset().union(*SIGNAL_KEYS.values())


def unread_attack_keys(sc: Scenario) -> list[str]:
    """Warnings for [attack] keys set away from their defaults that the scenario's signal
    never reads (``--set attack.rate_nps=0`` with the ``paper`` signal would otherwise be
    flown as if it had been taken)."""
    import dataclasses

    from tfl_mav.scenario import AttackConfig

    a = sc.attack
    if a.rotor == 0:
        return []
    read = SIGNAL_KEYS.get(a.signal, frozenset())
    defaults = AttackConfig()
    out = []
    for f in dataclasses.fields(a):
        name = f.name
        if name in _SIGNAL_ONLY_KEYS and name not in read \
                and getattr(a, name) != getattr(defaults, name):
            users = [sig for sig, keys in SIGNAL_KEYS.items() if name in keys]
            out.append(f"attack.{name} = {getattr(a, name):g} is not read by attack.signal "
                       f"{a.signal!r} (only by {', '.join(users)}"
                       + (", and a GCS's DRIFT failure injection" if name in
                          SIGNAL_KEYS["ramp"] else "") + "): it has no effect on this flight")
    return out
