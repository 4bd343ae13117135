"""Rotor allocation: from (u_f, τ_p, τ_q, τ_r) or the attacked law's inputs to rotor thrusts.

The paper derives the attacked law for rotor 2 (eq. (6)). Any other rotor maps onto that
case by relabelling the body axes by a multiple of 90° about b3 (docs/design.md, "The law"): in the
relabelled ("canonical") frame the attacked rotor sits on −b2' like rotor 2. Rotors 1 and 3
spin the other way from 2 and 4, so relabelling by an odd number of quarter turns also flips
the sign of the yaw reaction: the canonical frame then has d' = −d.

Rotor layout (paper frame, body FLU): rotor 1 on +b1, 2 on −b2, 3 on −b1, 4 on +b2.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

__all__ = ["Bounds", "RotorFrame", "allocate_attacked", "allocate_nominal", "canonical_frame",
           "permuted"]

Bounds = tuple[Sequence[float], Sequence[float]]
"""Per-rotor (lower, upper) thrust limits (N) for one control period."""


@dataclass(frozen=True)
class RotorFrame:
    """Canonical body frame for an attack on ``rotor``.

    ``rot`` is the 3×3 integer rotation (body → canonical body), ``perm[i]`` the physical
    rotor index (0-based) that plays canonical rotor i+1, ``d_sign`` the yaw-reaction sign.
    """

    rotor: int
    rot: tuple[tuple[int, int, int], ...]
    perm: tuple[int, int, int, int]
    d_sign: float
    swap_xy: bool  # canonical (Ix', Iy') = (Iy, Ix) after an odd quarter turn


def canonical_frame(rotor: int) -> RotorFrame:
    """The relabelling that puts physical ``rotor`` (1-4) in the place of rotor 2."""
    if rotor not in (1, 2, 3, 4):
        raise ValueError(f"rotor must be 1-4, got {rotor}")
    # Quarter turns k about b3 such that canonical b1' = Rz(−k·90°)… chosen so that the
    # physical rotor at angle −90°(rotor−1) appears at −90° in the canonical frame.
    k = (rotor - 2) % 4  # number of +90° turns of the labels
    # Canonical rotor i+1 is the physical rotor (i + k) mod 4 (+1).
    perm = tuple((i + k) % 4 for i in range(4))
    # Vector components in the canonical frame: v' = Rz(+90°·k)ᵀ-like integer map.
    rots = {
        0: ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
        1: ((0, -1, 0), (1, 0, 0), (0, 0, 1)),
        2: ((-1, 0, 0), (0, -1, 0), (0, 0, 1)),
        3: ((0, 1, 0), (-1, 0, 0), (0, 0, 1)),
    }
    return RotorFrame(rotor, rots[k], perm, -1.0 if k % 2 else 1.0, bool(k % 2))  # type: ignore[arg-type]


def permuted(values: Sequence[float], order: Sequence[int]) -> tuple[float, float, float, float]:
    """(values[order[0]], …, values[order[3]]): four rotors' numbers relabelled — physical
    to canonical with ``order`` = :attr:`RotorFrame.perm`, back with its inverse. (Written
    out: a generator costs four times as much, and this runs twice a tick.)"""
    return values[order[0]], values[order[1]], values[order[2]], values[order[3]]


def allocate_nominal(uf: float, tau_p: float, tau_q: float, tau_r: float,
                     arm_m: float, d_m: float, thrust_max_n: float = float("inf"),
                     bounds: Bounds | None = None) -> list[float]:
    """Invert eq. (4): rotor thrusts (N) for a wrench, all four healthy.

    With ``thrust_max_n`` the result is feasible: the yaw torque (the least important
    input: yaw does not move the position) is scaled down first, then each rotor is
    clipped to [0, f_max]. ``bounds`` = (lo, hi) per rotor (N) replaces [0, f_max] with
    what each rotor can reach this period (a lagging motor, see ``actuators``).
    """
    lo4, hi4 = bounds if bounds is not None else ((0.0,) * 4, (thrust_max_n,) * 4)
    a = uf / 4.0
    hp, hq = tau_p / (2.0 * arm_m), tau_q / (2.0 * arm_m)
    r = tau_r / (4.0 * d_m)
    base = (a - hq, a - hp, a + hq, a + hp)
    scale = 1.0
    for i in range(4):   # rotors 1, 3 react +d f (sign +1), 2, 4 −d f (sign −1)
        b, lo, hi = base[i], lo4[i], hi4[i]
        sr = r if i % 2 == 0 else -r
        f = b + sr
        if f < lo and sr < 0.0 and b > lo:
            scale = min(scale, (b - lo) / abs(r))
        elif f > hi and sr > 0.0 and b < hi:
            scale = min(scale, (hi - b) / abs(r))
    r *= scale
    return [_min(_max(base[i] + (r if i % 2 == 0 else -r), lo4[i]), hi4[i]) for i in range(4)]


def _max(a: float, b: float) -> float:
    """``max(a, b)`` (same result, NaN and ties included) without the call overhead."""
    return b if b > a else a


def _min(a: float, b: float) -> float:
    """``min(a, b)``, likewise."""
    return b if b < a else a


def allocate_attacked(uf: float, tau_q: float, tau_r: float, attack_n: float,
                      arm_m: float, d_m: float, thrust_max_n: float = float("inf"),
                      bounds: Bounds | None = None) -> list[float]:
    """Canonical rotor thrusts with rotor 2 forced to ``attack_n`` (eq. (6)'s mixer).

    With f2 = A the mixer gives f1 + f3 = (u_f + τ_r/d)/2, f3 − f1 = τ_q/l and
    f4 = (u_f − τ_r/d)/2 − A, so τ_p = (u_f − τ_r/d) l/2 − 2lA (eq. (6)) follows.

    With ``thrust_max_n`` the result is feasible, sacrificing inputs in reverse order of
    importance: τ_r (hence τ_p) first — f4 is clipped and f1 + f3 absorb the difference so
    that u_f is kept. When A ≈ 0 (the paper's attack while climbing) f4 ≥ A means τ_p ≥ 0
    only: the law's τ_p demand is then physically unreachable and this keeps the rest of
    the wrench exact. Then, where a side rotor would pass its top (f1 + f3 = 2m, f3 − f1 =
    τ_q/l, m + |τ_q|/2l > f_max), the collective goes before τ_q: m comes down to where
    both fit, as a multirotor mixer desaturates. τ_q is the one torque that turns b3 about
    the pitch axis; given up for thrust the rotors cannot make anyway, a saturated climb (a
    heavier airframe on two side rotors, the paper's start 3.85 m off) pitched the vehicle
    over within 0.3 s. At the bottom (a side rotor would go below 0: A near m g/2, the side
    rotors carrying little) τ_q still goes first: raising the collective to keep it climbs,
    unasked, with an attack that already lifts the vehicle. u_f goes last only when the two
    side rotors cannot carry it. ``bounds`` = (lo, hi) per canonical rotor (N) replaces
    [0, f_max] (rotor 2's entry is ignored).
    """
    lo, hi = bounds if bounds is not None else ((0.0,) * 4, (thrust_max_n,) * 4)
    lo1, lo3, lo4 = lo[0], lo[2], lo[3]
    hi1, hi3, hi4 = hi[0], hi[2], hi[3]
    # f4's range that leaves f1 + f3 = u_f − A − f4 within [lo1 + lo3, hi1 + hi3] if possible.
    rest = uf - attack_n
    # min/max written out (same results, NaN and ties included): this runs twice a tick.
    x = rest - (lo1 + lo3)
    x = lo4 if lo4 > x else x
    top = x if x < hi4 else hi4
    x = rest - (hi1 + hi3)
    x = lo4 if lo4 > x else x
    bottom = top if top < x else x
    x = 0.5 * (uf - tau_r / d_m) - attack_n
    x = bottom if bottom > x else x
    f4 = top if top < x else x
    x = rest - f4
    s_lo, s_hi = lo1 + lo3, hi1 + hi3
    x = s_lo if s_lo > x else x
    s13 = s_hi if s_hi < x else x
    half = 0.5 * tau_q / arm_m
    m = 0.5 * s13
    # The collective before τ_q at the top: m no higher than where f1 = m − half and
    # f3 = m + half both fit under their tops, where they also fit above their bottoms.
    a, b = hi3 - half, hi1 + half
    m_top = b if b < a else a
    a, b = lo1 + half, lo3 - half
    m_bottom = b if b > a else a
    if m_top < m and m_bottom <= m_top:
        m = m_top
    # Then keep f1 + f3 = 2m and reduce |f3 − f1| until both are within their bounds.
    a, b = m - hi1, lo3 - m
    lower = b if b > a else a
    a, b = m - lo1, hi3 - m
    upper = b if b < a else a
    upper = half if half < upper else upper
    half = upper if upper > lower else lower
    return [m - half, attack_n, m + half, f4]
