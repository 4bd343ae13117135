"""Where the ξ chain takes the vehicle from a state if nothing disturbs it: the largest
distance from the path on the way back, and the rate of the thrust the law starts from.

Under TFL each transverse coordinate α_i (i = 1, 2: the vehicle's offset across the path, m)
obeys the linear chain α_i⁽⁴⁾ = −k₀α_i − k₁α̇_i − k₂α̈_i − k₃α⃛_i (eqs. (22), (23)): from
x_i = (α_i, α̇_i, α̈_i, α⃛_i) its free response is α_i(t) = e₁ᵀ exp(A t) x_i with A the
chain's companion matrix. A state that is close to the path but not at rest on it (a safe
law mid-correction: accelerating, its thrust turning) comes back the long way — on the
fine poles (−4) a vehicle 1 mm off with 0.03 m/s² of acceleration across the path peaks at
2.4 mm — so a hand-back judged by the distance alone can cost more than the law it
replaces. The supervisor reads :func:`peak_distance_m` of the state TFL would resume from.

:class:`ThrustTrend` is the rate of the thrust another law applies, for the dynamic
extension's x14 = u̇_f (eq. (9)) at a hand-back: starting x14 at 0 while that law's thrust
was changing at 1 N/s is a jerk of (1 N/s)/m that the ξ chain then rings out (3.2 mm on the
fine poles for the paper vehicle, if all of it lies across the path; 5.1 mm flown on an
intermittent 0-2 N attack's hand-back, 1.9 mm with the rate carried over).
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import NamedTuple

import numpy as np

__all__ = [
    "TREND_TAU_S",
    "ThrustTrend",
    "peak_distance_m",
    "response_rows",
    "thrust_trend",
]

TREND_TAU_S = 0.02
"""The trend filter's time constant (s): long enough to average a noisy law's tick-to-tick
thrust, short against the half-second over which a correction's thrust changes."""

_SAMPLES = 240


@lru_cache(maxsize=16)
def response_rows(k_xi: tuple[float, float, float, float]) -> np.ndarray:
    """e₁ᵀ exp(A t_j), j over a grid of the response (``_SAMPLES`` × 4): the α of the free
    response at t_j is this row · x. The grid spans 10 time constants of the slowest pole,
    where a quadruple pole's response to any initial derivative is past its peak."""
    k0, k1, k2, k3 = (float(k) for k in k_xi)
    a = np.zeros((4, 4))
    a[0, 1] = a[1, 2] = a[2, 3] = 1.0
    a[3] = (-k0, -k1, -k2, -k3)
    poles = np.linalg.eigvals(a)
    slowest = float(np.max(poles.real))
    if not slowest < 0.0:
        raise ValueError(f"free response: the ξ chain is not stable (poles {poles})")
    horizon = 10.0 / -slowest
    step = _expm(a * (horizon / (_SAMPLES - 1)))
    rows = np.empty((_SAMPLES, 4))
    row = np.array([1.0, 0.0, 0.0, 0.0])
    for j in range(_SAMPLES):
        rows[j] = row
        row = row @ step
    return rows


def _expm(a: np.ndarray) -> np.ndarray:
    """exp(a) of a small matrix: scaled to a norm below 1/2, a Taylor series to 1e-17 there
    (18 terms), squared back (the runtime has numpy, not scipy)."""
    norm = float(np.max(np.sum(np.abs(a), axis=1)))
    squarings = max(0, math.ceil(math.log2(norm / 0.5))) if norm > 0.5 else 0
    x = a / (2.0 ** squarings)
    term = np.eye(a.shape[0])
    total = term.copy()
    for k in range(1, 19):
        term = term @ x / k
        total = total + term
    for _ in range(squarings):
        total = total @ total
    return total


def peak_distance_m(k_xi: tuple[float, ...], xi: tuple[tuple[float, ...], tuple[float, ...]]
                    ) -> float:
    """The largest |(α1, α2)| (m) of the ξ chain's free response from ``xi`` =
    ((α1, α̇1, α̈1, α⃛1), (α2, …)) in m, m/s, m/s², m/s³ under the gains ``k_xi``
    (k₀…k₃, eq. (23)); NaN for a non-finite state."""
    rows = response_rows(tuple(k_xi))
    x = np.array((xi[0][:4], xi[1][:4]), dtype=float).T        # 4 × 2
    if not np.isfinite(x).all():
        return math.nan
    e = rows @ x
    return float(math.sqrt(np.max(e[:, 0] * e[:, 0] + e[:, 1] * e[:, 1])))


class ThrustTrend(NamedTuple):
    """u_f (N) through two first-order low-passes in cascade (each y += dt/(τ + dt)·(u − y),
    the backward-Euler step of τ ẏ = u − y); on a ramp of rate r each lags the one before by
    exactly r τ whatever the tick, so (lp₁ − lp₂)/τ is r, its noise averaged over about 2τ."""

    lp1_n: float
    lp2_n: float
    ticks: int          # ticks since the trend started (0: not started)

    @property
    def rate_nps(self) -> float:
        """The thrust's rate of change (N/s); 0 before a second sample."""
        return (self.lp1_n - self.lp2_n) / TREND_TAU_S if self.ticks > 1 else 0.0


def thrust_trend(trend: ThrustTrend | None, thrust_n: float, dt_s: float) -> ThrustTrend:
    """The trend after a tick that applied the total thrust ``thrust_n`` (N) for ``dt_s``
    (s); ``trend`` None starts it at this thrust."""
    if trend is None or trend.ticks == 0:
        return ThrustTrend(thrust_n, thrust_n, 1)
    k = dt_s / (TREND_TAU_S + dt_s) if dt_s > 0.0 else 0.0
    lp1 = trend.lp1_n + k * (thrust_n - trend.lp1_n)
    lp2 = trend.lp2_n + k * (lp1 - trend.lp2_n)
    return ThrustTrend(lp1, lp2, trend.ticks + 1)
