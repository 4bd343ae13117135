"""The rate of the thrust another law applies: where TFL's dynamic extension starts at a
hand-back (x13 = u_f, x14 = u̇_f, eq. (9)).

The safe law commands its thrust algebraically, tick by tick; TFL carries it as a state with
its rate. Starting x14 at 0 while the safe law's thrust was changing at 1 N/s is a jerk of
(1 N/s)/m that the ξ chain then rings out: for the 1.1 kg paper vehicle, if all of it lies
across the path, j (3/p)³ e⁻³/6 = 13 mm on the coarse poles (p = 2.5) and 0.4 mm on the fine
ones (p = 8). On an intermittent 0-2 N attack the hand-back after each step left 5.1 mm with
x14 = 0 and 1.9 mm with the rate carried over (fine poles at p = 4).

The rate comes from the thrust through two first-order low-passes in cascade: on a ramp of
rate r each lags the one before by exactly r τ, so (lp₁ − lp₂)/τ is r, with the noise of a
law's tick-to-tick thrust averaged over about 2τ.
"""

from __future__ import annotations

from typing import NamedTuple

__all__ = ["TREND_TAU_S", "ThrustTrend", "thrust_trend"]

TREND_TAU_S = 0.02
"""The filters' time constant (s): long enough to average a noisy law's tick-to-tick thrust,
short against the half-second over which a correction's thrust changes."""


class ThrustTrend(NamedTuple):
    """u_f (N) through two first-order low-passes in cascade (each y += dt/(τ + dt)·(u − y),
    the backward-Euler step of τ ẏ = u − y, so the lag on a ramp is r τ whatever the tick)."""

    lp1_n: float
    lp2_n: float
    ticks: int          # ticks since the trend started (0: not started)

    @property
    def rate_nps(self) -> float:
        """The thrust's rate of change (N/s); 0 before a second sample."""
        return (self.lp1_n - self.lp2_n) / TREND_TAU_S if self.ticks > 1 else 0.0


def thrust_trend(trend: ThrustTrend | None, thrust_n: float, dt_s: float) -> ThrustTrend:
    """The trend after a tick that applied the total thrust ``thrust_n`` (N) for ``dt_s``
    (s); ``trend`` None (or not started) starts it at this thrust."""
    if trend is None or trend.ticks == 0:
        return ThrustTrend(thrust_n, thrust_n, 1)
    k = dt_s / (TREND_TAU_S + dt_s) if dt_s > 0.0 else 0.0
    lp1 = trend.lp1_n + k * (thrust_n - trend.lp1_n)
    lp2 = trend.lp2_n + k * (lp1 - trend.lp2_n)
    return ThrustTrend(lp1, lp2, trend.ticks + 1)
