"""Which law flies: the supervisor of the seam between TFL and the safe law, one pure step.

``supervise(params, state, inputs) -> (state, decision)`` is called once a control tick by
the flight computer, after the law that flew this tick reported. Its inputs are what the
laws and the attack estimate say (the TFL law's unbounded rotor demand and whether it found
an answer, the safe law's distance to the path, the attacked rotor's thrust with its
uncertainty) and what the state says (tilt, roll/pitch rate, speed); its decision says which
law flies, why (:class:`Why`), and how the law that takes over starts (:class:`Start`). It
writes into no law: the flight computer composes the steps and passes each law what it needs.

The rules, and the physics that sizes them (canonical frame of the attacked rotor,
:mod:`tfl_mav.control.allocation`; rotor 2 at thrust A, rotor 4 opposite, l the arm):

* **TFL flies wherever it holds the path.** Its roll torque comes from rotor 4 alone:
  f₄ = A + τ_p/l ∈ [0, f_max] makes τ_p ∈ [−lA, l(f_max − A)] and nothing else (eq. (6)).
  The test reads the law's *unbounded* demand (before the motor-lag inverse, which pins a
  lagging rotor's command at 0 or f_max on purpose and says nothing about authority).
  - **Floor** (f₄ asked below 0): τ_p of one sign is missing.
    The ξ chain absorbs a short shortfall; what it cannot absorb is a shortfall that lasts
    while A offers no torque of the other sign. So the vehicle is taken over when the
    floor has held on more than ``lost_share`` of the last ``window_s`` *and* the attack
    is small (A + 2σ_A < ``a_takeover_n``: the other sign is out of reach), or when the
    floor has held on more than ``persist_share`` of the longer ``persist_window_s``
    whatever A (the law is not getting what it asks for, and it is not a transient).
    A heavier airframe's saturated first climb pins f₄ for a few tenths of a second with
    A ≈ 0.5 N: TFL keeps it (it has τ_p of both signs).
  - **Thrust** (a side rotor asked above f_max on more than ``lost_share`` of the window):
    the law asks for more thrust than three rotors make; the safe law, whose demand is
    feasible by construction (tilt and vertical acceleration capped), flies until TFL's
    demand fits again.
  - **Ceiling** (f₄ asked above f_max, or a side rotor below 0) on more than
    ``lost_share`` of the window, or 2A > m g (the others cannot balance the attack at
    any thrust that keeps the altitude): the three-rotor law keeps the attitude.
  - **No answer** (the law fell back: it left the projection's tube, u_f too small, Dφ
    singular): the four- or three-rotor law levels the vehicle and holds its altitude.
* **Hand back as soon as TFL can hold it again**: the attack leaves a two-sided τ_p with
  margin (A − 2σ_A > ``a_handback_n`` and A + 2σ_A < m g/2 − ``a_handback_n``), the
  attitude is calm (tilt, roll/pitch rate), the vehicle is within TFL's region of attraction
  and following the path (not holding a point), all for ``handback_s``. The hysteresis
  between ``a_takeover_n`` and ``a_handback_n`` plus that hold time bounds an intermittent
  attack to one round trip per change of the attack.
* **The first tick**: a state TFL is not known to converge from (tilted, moving fast,
  rolling, beyond the region of attraction) goes to the safe law holding its altitude.
* **A rotor pinned high** (A − 2σ_A above m g/2 by ``spin_margin_n`` for ``spin_hold_s``):
  no attitude hold exists (the opposite rotor must match A, so u_f ≥ 2A > m g); the spin law
  (:mod:`tfl_mav.control.spin`, relaxed hover about a tilted axis) takes it from the safe law
  once its table is built, and gives it back when A + 2σ_A falls below m g/2 by
  max(``spin_margin_n``, ``a_handback_n``): where the safe law can hand on to TFL.
* **Modes**: ``"auto"`` flies the rules above; ``"tfl"`` flies the TFL law alone (no
  take-over at all: for research and comparison); ``"safe"`` flies the safe law alone.

Time in each law and the number of switches are part of the state: the honest mode report.
The flight computer flies this step compiled by the accelerator seam (the same decisions,
bit for bit and type for type: tests/contract/test_composition_seam.py).
"""

from __future__ import annotations

import math
from enum import IntEnum
from typing import NamedTuple

__all__ = [
    "SUPERVISOR_MODES",
    "Law",
    "Start",
    "SupervisorInputs",
    "SupervisorParams",
    "SupervisorState",
    "Why",
    "attitude",
    "describe",
    "initial_state",
    "supervise",
    "supervisor_params",
]

SUPERVISOR_MODES = ("auto", "tfl", "safe")


class Law(IntEnum):
    """The law flying (the flight log's mode says the same in finer words)."""

    TFL = 0          # the TFL law: nominal (four rotors) or attacked (three, yaw internal)
    RECOVERY = 1     # the safe reduced-attitude law, levelling and holding or flying back
    LOST_ROTOR = 2   # the safe reduced-attitude law on three rotors, spinning
    SPIN = 3         # the spin law (relaxed hover about a tilted axis): a rotor pinned high


class Why(IntEnum):
    """Why the decision is what it is."""

    STAY = 0             # nothing changes
    START_NOT_BENIGN = 1   # first tick: a state TFL is not started from
    START_BEYOND_ROA = 2   # first tick: farther from the path than TFL converges from
    NO_ANSWER = 3        # TFL fell back (tube, thrust, condition, non-finite)
    FLOOR = 4            # TFL's τ_p of one sign is out of reach, and it lasts
    CEILING = 5          # the attack is more than the others balance at their limits
    HOPELESS = 6         # 2A > m g: no law keeps the altitude
    HANDBACK = 7         # TFL can hold the path again
    FOLLOW = 8           # the safe law stops holding a point and flies back to the path
    ONLY_SAFE = 9        # mode "safe": the safe law flies everything
    PINNED_HIGH = 10     # A > m g/2 with margin: only a spinning hover keeps the altitude
    RELENTED = 11        # the pinned rotor came down below m g/2: the safe law again


class Start(IntEnum):
    """How the law that takes over this tick starts (the flight computer does it)."""

    NONE = 0
    SAFE_HOLD = 1        # the safe law holds the position where it took over
    SAFE_PATH = 2        # the safe law flies the path from where it is
    TFL_RESUME = 3       # TFL resumes bumpless from the safe law's last command
    SPIN = 4             # the spin law starts from the vehicle's rates and the pinned thrust


class SupervisorParams(NamedTuple):
    """The supervisor's constants (SI units)."""

    mode: int                 # 0 auto, 1 tfl, 2 safe (SUPERVISOR_MODES' index)
    weight_n: float           # m g of the controller's model
    thrust_max_n: float       # f_max per rotor
    window_s: float           # the short averaging window of the pinned indicators (s)
    lost_share: float         # a share of the short window pinned that loses the authority
    persist_window_s: float   # the long window (s)
    persist_share: float      # … and its share: pinned whatever A
    a_takeover_n: float       # floor take-over only with A + 2σ below this (N)
    a_handback_n: float       # hand back with A − 2σ above this (N)
    handback_s: float         # the hand-back conditions hold this long (s)
    hold_before_path_s: float   # a take-over holding a point flies back after this (s)
    roa_m: float              # TFL's region of attraction: distance to the path (m)
    takeover_tilt_rad: float  # TFL is not started beyond these (tilt, |(p, q)|, speed)
    takeover_rate_radps: float
    takeover_speed_mps: float
    handback_tilt_rad: float  # the calmer attitude a hand-back needs
    spin_margin_n: float      # the spin law flies while A ± 2σ stays this far above m g/2
    spin_hold_s: float        # … held this long before a change (s)


class SupervisorState(NamedTuple):
    """What the supervisor remembers (time in s)."""

    law: int                  # Law
    holding: bool             # the safe law holds a point (not the path)
    since_s: float            # time in the current law
    good_s: float             # time the hand-back conditions have held
    floor_share: float        # the share of the short window TFL's demand was at a floor
    ceiling_share: float      # … at a ceiling
    top_share: float          # … a side rotor asked above f_max (the thrust it cannot make)
    persist_share: float      # … at a floor over the long window
    ticks: int
    switches: int             # law changes
    tfl_s: float              # time flown by each law
    recovery_s: float
    lost_rotor_s: float
    spin_s: float = 0.0
    high_s: float = 0.0       # time the attack has been pinned above m g/2 with margin


class SupervisorInputs(NamedTuple):
    """What the laws, the attack estimate and the state report this tick (SI units)."""

    dt_s: float                 # the period this tick closes (s)
    rotor: int                  # the attacked rotor 1-4 (0: none known)
    attack_n: float             # its thrust estimate A (N; NaN: unknown)
    attack_std_n: float         # its standard deviation σ_A (N)
    tfl_flew: bool              # the TFL law was evaluated this tick
    tfl_answer: bool            # … and found an answer (no fallback)
    demand_n: tuple[float, float, float, float]   # TFL's unbounded rotor demand (N, physical)
    safe_distance_m: float      # the safe law's distance to the path (m; NaN: holding)
    quaternion_wxyz: tuple[float, float, float, float]   # attitude (body FLU → paper frame)
    body_rates_radps: tuple[float, float, float]         # (p, q, r)
    velocity_mps: tuple[float, float, float]             # paper frame
    path_distance_m: float      # first tick only: distance to the path (m; NaN: unknown)
    spin_ready: bool = False    # the spin law is built for the attacked rotor


_EPS_N = 1e-6   # a demand within this of a bound is at that bound (N)
_new = tuple.__new__
_TFL, _RECOVERY, _SPIN = int(Law.TFL), int(Law.RECOVERY), int(Law.SPIN)
_STAY, _NONE = int(Why.STAY), int(Start.NONE)


def supervisor_params(mode: str, weight_n: float, thrust_max_n: float, speed_mps: float, *,
                      window_s: float = 0.2, lost_share: float = 0.5,
                      persist_window_s: float = 1.0, persist_share: float = 0.8,
                      a_takeover_n: float = 0.35, a_handback_n: float = 0.6,
                      handback_s: float = 0.5, hold_before_path_s: float = 1.0,
                      roa_m: float = 4.0, spin_margin_n: float = 0.25,
                      spin_hold_s: float = 0.2) -> SupervisorParams:
    """The constants for a vehicle of weight ``weight_n`` flying a path at ``speed_mps``.

    TFL is started from hover in every scenario; the take-over limits are those with a
    margin: 30° of tilt, 2 rad/s of roll/pitch rate, max(0.5, 2 × path speed) m/s; a
    hand-back needs 20° of tilt. ``a_handback_n`` = 0.6 N is τ_p = −0.16 N m on the paper
    vehicle (80 rad/s² of roll acceleration); ``a_takeover_n`` sits below it so that an
    estimate's noise does not chatter between the two."""
    if mode not in SUPERVISOR_MODES:
        raise ValueError(f"supervisor: must be one of {', '.join(SUPERVISOR_MODES)}, "
                         f"got {mode!r}")
    if not (weight_n > 0.0 and thrust_max_n > 0.0 and 0.0 < window_s < persist_window_s
            and 0.0 < lost_share < 1.0 and 0.0 < persist_share < 1.0
            and 0.0 <= a_takeover_n <= a_handback_n):
        raise ValueError("supervisor: weight_n, thrust_max_n > 0, 0 < window_s < "
                         "persist_window_s, shares in (0, 1), 0 <= a_takeover_n <= "
                         "a_handback_n")
    return SupervisorParams(
        SUPERVISOR_MODES.index(mode), weight_n, thrust_max_n, window_s, lost_share,
        persist_window_s, persist_share, a_takeover_n, a_handback_n, handback_s,
        hold_before_path_s, roa_m, math.radians(30.0), 2.0, max(0.5, 2.0 * speed_mps),
        math.radians(20.0), spin_margin_n, spin_hold_s)


def initial_state(mode: str = "auto") -> SupervisorState:
    """Before the first tick: TFL flies (the safe law in mode ``"safe"``)."""
    law = Law.LOST_ROTOR if mode == "safe" else Law.TFL
    return SupervisorState(int(law), False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0, 0, 0.0, 0.0,
                           0.0, 0.0)


def attitude(u: SupervisorInputs) -> tuple[float, float, float]:
    """(tilt of b3 from the vertical rad, |(p, q)| rad/s, |v| m/s) of the inputs' state:
    computed only where a rule reads them (not on the attacked TFL tick)."""
    w, x, y, z = u.quaternion_wxyz
    n = math.sqrt(w * w + x * x + y * y + z * z)     # R₂₂ of the normalised quaternion
    if n > 0.0:
        x, y = x / n, y / n
        r22 = 1 - 2 * (x * x + y * y)
        tilt = math.acos(max(-1.0, min(1.0, r22))) if r22 == r22 else math.nan
    else:
        tilt = math.nan
    p, q, _ = u.body_rates_radps
    vx, vy, vz = u.velocity_mps
    return tilt, math.hypot(p, q), math.sqrt(vx * vx + vy * vy + vz * vz)


def _not_benign(p: SupervisorParams, u: SupervisorInputs) -> bool:
    """A state TFL is not started from (or a NaN in it)."""
    tilt, pq, speed = attitude(u)
    return not (tilt <= p.takeover_tilt_rad and pq <= p.takeover_rate_radps
                and speed <= p.takeover_speed_mps)


def _switch(p: SupervisorParams, s: SupervisorState, law: Law, why: Why, start: Start,
            holding: bool) -> tuple[SupervisorState, tuple[int, int, int]]:
    changed = law != s.law
    return (s._replace(law=int(law), holding=holding, since_s=0.0, good_s=0.0,
                       floor_share=0.0, ceiling_share=0.0, top_share=0.0,
                       persist_share=0.0, high_s=0.0,
                       switches=s.switches + (1 if changed else 0)),
            (int(law), int(why), int(start)))


def _authority(p: SupervisorParams, s: SupervisorState, u: SupervisorInputs, dt: float,
               clock: tuple[float, int, float, float, float, float]
               ) -> tuple[SupervisorState, tuple[int, int, int]]:
    """TFL flies an attacked vehicle: the shares of the window its unbounded demand sat at
    a bound, and the take-over they call for (module doc). ``clock``: the state's time
    fields after this tick (since, ticks, tfl, recovery, lost_rotor, spin)."""
    a = u.attack_n
    sigma = u.attack_std_n if u.attack_std_n > 0.0 else 0.0
    known = math.isfinite(a)
    i = u.rotor - 1                   # physical index of the attacked rotor
    d = u.demand_n
    opposite, side1, side3 = d[(i + 2) % 4], d[(i + 1) % 4], d[(i + 3) % 4]
    # The demand is bounded below by 0 (the allocation's), not above, and not by the lag's
    # reach: f₄ at 0 is τ_p ≥ −lA asked for more.
    top = p.thrust_max_n - _EPS_N
    ceiling = opposite >= top or side1 <= _EPS_N or side3 <= _EPS_N
    floor = opposite <= _EPS_N
    thrust_top = side1 >= top or side3 >= top
    k = dt / p.window_s
    k = k if k < 1.0 else 1.0
    kl = dt / p.persist_window_s
    kl = kl if kl < 1.0 else 1.0
    fs = s.floor_share + k * ((1.0 if floor else 0.0) - s.floor_share)
    cs = s.ceiling_share + k * ((1.0 if ceiling else 0.0) - s.ceiling_share)
    ts = s.top_share + k * ((1.0 if thrust_top else 0.0) - s.top_share)
    ps = s.persist_share + kl * ((1.0 if floor else 0.0) - s.persist_share)
    since, ticks, tfl_s, rec_s, lost_s, spin_s = clock
    # One state built, positionally (a named tuple's _replace costs microseconds).
    s = _new(SupervisorState, (s.law, s.holding, since, s.good_s, fs, cs, ts, ps, ticks,
                               s.switches, tfl_s, rec_s, lost_s, spin_s, s.high_s))
    small = not known or a + 2.0 * sigma < p.a_takeover_n
    if (fs > p.lost_share and small) or ps > p.persist_share or ts > p.lost_share:
        return _switch(p, s, Law.LOST_ROTOR, Why.FLOOR, Start.SAFE_PATH, False)
    if cs > p.lost_share:
        return _switch(p, s, Law.LOST_ROTOR, Why.CEILING, Start.SAFE_PATH, False)
    return s, (s.law, _STAY, _NONE)


def supervise(p: SupervisorParams, s: SupervisorState, u: SupervisorInputs
              ) -> tuple[SupervisorState, tuple[int, int, int]]:
    """One tick: the new state and the decision (law, why, start) — :class:`Law`,
    :class:`Why`, :class:`Start` values. The law decided flies the *next* tick, except a
    take-over from TFL, which the flight computer flies on this very tick (TFL's command
    was not what the vehicle needs)."""
    dt = u.dt_s if u.dt_s > 0.0 else 0.0
    # The time flown by the law that flew this tick.
    law_now = s.law
    tfl_s, rec_s, lost_s, spin_s = s.tfl_s, s.recovery_s, s.lost_rotor_s, s.spin_s
    if law_now == _TFL:
        tfl_s += dt
    elif law_now == _RECOVERY:
        rec_s += dt
    elif law_now == _SPIN:
        spin_s += dt
    else:
        lost_s += dt
    ticks, since = s.ticks + 1, s.since_s + dt
    stay = (law_now, _STAY, _NONE)
    if law_now == _TFL and ticks > 1 and p.mode == 0 and u.tfl_flew and u.tfl_answer \
            and u.rotor and not (2.0 * u.attack_n > p.weight_n):
        # The tick that runs a thousand times a second: TFL flies an attacked vehicle.
        return _authority(p, s, u, dt, (since, ticks, tfl_s, rec_s, lost_s, spin_s))
    s = _new(SupervisorState, (law_now, s.holding, since, s.good_s, s.floor_share,
                               s.ceiling_share, s.top_share, s.persist_share, ticks,
                               s.switches, tfl_s, rec_s, lost_s, spin_s, s.high_s))
    if p.mode == 1:                       # "tfl": the TFL law alone
        return s, stay
    if p.mode == 2:                       # "safe": the safe law alone, never TFL
        law = Law.LOST_ROTOR if u.rotor else Law.RECOVERY
        if law != s.law or s.ticks == 1:
            return _switch(p, s, law, Why.ONLY_SAFE, Start.SAFE_PATH, False)
        return s, stay
    a = u.attack_n
    sigma = u.attack_std_n if u.attack_std_n > 0.0 else 0.0
    known = u.rotor != 0 and math.isfinite(a)
    if s.ticks == 1:
        if _not_benign(p, u):
            return _switch(p, s, Law.RECOVERY, Why.START_NOT_BENIGN, Start.SAFE_HOLD, True)
        if u.path_distance_m > p.roa_m:
            return _switch(p, s, Law.RECOVERY, Why.START_BEYOND_ROA, Start.SAFE_HOLD, True)
    if s.law == Law.TFL:
        if u.tfl_flew and not u.tfl_answer:
            law = Law.LOST_ROTOR if u.rotor else Law.RECOVERY
            return _switch(p, s, law, Why.NO_ANSWER, Start.SAFE_HOLD, True)
        if not u.rotor or not u.tfl_flew:
            return s, stay
        if known and 2.0 * a > p.weight_n:
            return _switch(p, s, Law.LOST_ROTOR, Why.HOPELESS, Start.SAFE_PATH, False)
        return _authority(p, s, u, dt, (s.since_s, s.ticks, s.tfl_s, s.recovery_s,
                                        s.lost_rotor_s, s.spin_s))
    half = p.weight_n / 2.0
    if s.law == Law.SPIN:
        # Back to the safe law once the pinned rotor has come down (or let go) for a while,
        # as far below m g/2 as the safe law needs to hand on to TFL (a two-sided τ_p with
        # a_handback_n of margin): between there and m g/2 the safe law can only climb or
        # barely hold (2A ≈ m g), while the spin still has its relaxed hover (its table spans
        # from m g/2 − 0.5 N). Leaving at m g/2 − spin_margin_n, an attack swinging about
        # m g/2 (the paper's 0.1 t + sin z near 55-62 s) cost a round trip of 2.7 m.
        down = not known or a + 2.0 * sigma < half - max(p.spin_margin_n, p.a_handback_n)
        good = s.good_s + dt if down else 0.0
        s = s._replace(good_s=good)
        if good >= p.spin_hold_s:
            law = Law.LOST_ROTOR if u.rotor else Law.RECOVERY
            return _switch(p, s, law, Why.RELENTED, Start.SAFE_PATH, False)
        return s, stay
    # A safe law flies; with the rotor pinned above m g/2 the spin law takes it, if built.
    if known and u.spin_ready and not s.holding:
        high = a - 2.0 * sigma > half + p.spin_margin_n
        high_s = s.high_s + dt if high else 0.0
        if high_s != s.high_s:
            s = s._replace(high_s=high_s)
        if high_s >= p.spin_hold_s:
            return _switch(p, s, Law.SPIN, Why.PINNED_HIGH, Start.SPIN, False)
    # A safe law flies.
    if p.mode == 0 and s.holding and s.since_s >= p.hold_before_path_s \
            and not _not_benign(p, u):
        s = s._replace(holding=False, good_s=0.0)
        return s, (s.law, int(Why.FOLLOW), int(Start.SAFE_PATH))
    law = Law.LOST_ROTOR if u.rotor else Law.RECOVERY
    if law != s.law:                      # an attack found or released mid-take-over
        s = s._replace(law=int(law))
    two_sided = not u.rotor or (known and a - 2.0 * sigma > p.a_handback_n
                                and a + 2.0 * sigma < p.weight_n / 2.0 - p.a_handback_n)
    ok = two_sided and not s.holding and u.safe_distance_m < p.roa_m
    if ok:
        tilt, pq, speed = attitude(u)
        ok = (tilt <= p.handback_tilt_rad and pq <= p.takeover_rate_radps
              and speed <= p.takeover_speed_mps)     # (the hand-back tilt is the stricter)
    good = s.good_s + dt if ok else 0.0
    if good != s.good_s:
        s = s._replace(good_s=good)
    if good >= p.handback_s:
        return _switch(p, s, Law.TFL, Why.HANDBACK, Start.TFL_RESUME, False)
    return s, (s.law, _STAY, _NONE)


def describe(why: int, law: int, *, rotor: int, attack_n: float, inputs: SupervisorInputs,
             since_s: float, distance_m: float) -> str:
    """The decision in words (the holder's, for events and STATUSTEXT)."""
    a_text = f"{attack_n:.2f} N" if math.isfinite(attack_n) else "unknown thrust"
    opposite = (rotor + 1) % 4 + 1 if rotor else 0
    if why == Why.START_NOT_BENIGN:
        tilt, pq, speed = attitude(inputs)
        return (f"recovery: take-over: tilted {math.degrees(tilt):.0f} deg, |v| {speed:.1f} "
                f"m/s, |(p, q)| {pq:.1f} rad/s: beyond what TFL starts from; level, hold "
                "altitude")
    if why == Why.START_BEYOND_ROA:
        return (f"recovery: take-over: {inputs.path_distance_m:.1f} m from the path "
                "(beyond TFL's region of attraction); level, hold altitude")
    if why == Why.NO_ANSWER:
        return f"{Law(law).name.lower()}: TFL has no answer; level, hold altitude"
    if why == Why.FLOOR:
        return (f"lost_rotor: rotor {rotor} at {a_text}: rotor {opposite} pinned at 0 N, "
                "no roll authority; reduced-attitude law")
    if why in (Why.CEILING, Why.HOPELESS):
        return (f"lost_rotor: rotor {rotor} at {a_text}: more than the three others can "
                "balance (pinned at their limits); keeping attitude, cannot hold the path")
    if why == Why.HANDBACK:
        return (f"tfl: handed back after {since_s:.1f} s ({distance_m * 1000:.0f} mm from "
                "the path)")
    if why == Why.FOLLOW:
        return "recovery: level and calm: flying back to the path"
    if why == Why.PINNED_HIGH:
        return (f"spin: rotor {rotor} pinned at {a_text}, above m g/2: no attitude hold "
                "exists; relaxed hover about a tilted axis, the mean axis steered along the path")
    if why == Why.RELENTED:
        return (f"{Law(law).name.lower()}: rotor {rotor} down to {a_text}: the spin ends, "
                "reduced-attitude law")
    if why == Why.ONLY_SAFE:
        return f"{Law(law).name.lower()}: the safe law alone (controller.supervisor = safe)"
    return ""
