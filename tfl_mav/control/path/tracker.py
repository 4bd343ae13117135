"""The virtual output (α, π) and its time derivatives along the position (paper §V), on jets.

With the path the zero set of s (§IV, eq. (7)), α = s(y) (eqs. (8), (14)) and its
derivatives up to order 4 come from one jet evaluation of ``s`` on the position's Taylor
series. π (eq. (14)'s ϖ, eq. (13)) is the arc length of the closest path point. Its time
derivatives come from implicitly differentiating the projection condition

    g(λ, y) = ⟨y − σ(λ), σ'(λ)⟩ = 0,

solved for the value by Newton (warm-started from the last λ) and then for the Taylor
coefficients of λ(t) one order at a time: coefficient k of g is linear in λ's coefficient k
with slope ∂g/∂λ = −|σ'|² + ⟨y − σ, σ''⟩, the same slope at every order. That slope also
measures how far the vehicle is from losing the projection: it vanishes where the distance
to the path reaches the radius of curvature (0.24 m at the paper path's bends), so
:class:`PathTracker` reports ``in_tube = False`` before the derivatives blow up instead of
returning NaN.

:class:`PathTracker` is the reference, written for clarity on :class:`jets.Jet`; the law
flies :class:`compiled.CompiledPathTracker`, the same computation compiled per path, which
is tested against this one. :func:`pi_rates` is written as plain arithmetic on its
arguments so that the compiled tracker can trace it (:mod:`jetcode`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from tfl_mav.control.path.jets import Jet
from tfl_mav.control.path.projection import Expansion, arc
from tfl_mav.control.path.series import sqrt_series

if TYPE_CHECKING:
    from tfl_mav.control.path.paths import Path

__all__ = ["MIN_TUBE_MARGIN", "NEWTON_ITERS", "PathOutput", "PathTracker", "VirtualOutput",
           "closest_lam", "global_closest_lam", "grad_s", "newton_closest_lam", "newton_on_poly",
           "pi_rates", "poly_g", "taylor_curve"]


@dataclass(slots=True)
class VirtualOutput:
    """What the law needs of the virtual output at one instant, as derivatives.

    ``xi1``, ``xi2``: (αᵢ, α̇ᵢ, α̈ᵢ, α⃛ᵢ, αᵢ⁽⁴⁾); ``eta``: (π, π̇, π̈, π⃛, π⁽⁴⁾) (eq. (17)'s ξ, η
    and their fourth derivatives); ``jacobian``: rows ∂α1/∂y, ∂α2/∂y, ∂π/∂y (Dφ, eq. (15));
    ``lam``, ``distance_m``, ``in_tube``, ``reason`` as in :class:`PathOutput`.
    """

    xi1: Sequence[float]
    xi2: Sequence[float]
    eta: Sequence[float]
    jacobian: Sequence[Sequence[float]]
    lam: float
    distance_m: float
    in_tube: bool
    reason: str = ""


@dataclass(frozen=True, slots=True)
class PathOutput:
    """The virtual output at one instant (see :meth:`PathTracker.evaluate`).

    ``alpha``: jets of α1, α2 (eq. (14)), ``pi``: jet of π (arc length, m);
    ``jacobian``: rows ∂α1/∂y, ∂α2/∂y, ∂π/∂y (3 × 3); ``lam``: λ of the closest point;
    ``distance_m``: |y − σ(λ)|; ``in_tube``: the projection is unique and well conditioned
    (else ``reason`` says why, and the derivatives must not be used).
    """

    alpha: tuple[Jet, Jet]
    pi: Jet
    jacobian: tuple[tuple[float, float, float], ...]
    lam: float
    distance_m: float
    in_tube: bool
    reason: str = ""


# The slope ∂g/∂λ relative to |σ'|² is 1 on the path and 0 where the projection stops being
# unique (distance = radius of curvature, on the concave side). Below this the law stops
# trusting π's derivatives: 1/margin amplifies them.
MIN_TUBE_MARGIN = 0.1
NEWTON_ITERS = 20
_NEWTON_TOL = 1e-12


def taylor_curve(path: Path, lam0: float) -> Expansion:
    """σ(λ0 + δ) = Σ_j c_j δʲ for j = 0..5: coefficients c_j = σ⁽ʲ⁾(λ0)/j! (vectors)."""
    jx, jy, jz = path.sigma(Jet.variable(lam0, order=5))
    cx = jx.c if isinstance(jx, Jet) else (float(jx),) + (0.0,) * 5
    cy = jy.c if isinstance(jy, Jet) else (float(jy),) + (0.0,) * 5
    cz = jz.c if isinstance(jz, Jet) else (float(jz),) + (0.0,) * 5
    return Expansion(*((cx[j], cy[j], cz[j]) for j in range(6)))


def global_closest_lam(path: Path, y: Sequence[float]) -> float:
    """The λ of the closest of 4001 points of σ over ``path.lam_range`` to ``y`` (m): the
    start of a projection with no λ to warm-start from."""
    lo, hi = path.lam_range
    lam = np.linspace(lo, hi, 4001)
    x, yy, z = path.sigma(lam)
    d2 = (x - y[0]) ** 2 + (yy - y[1]) ** 2 + (z - y[2]) ** 2
    return float(lam[int(np.argmin(d2))])


def newton_closest_lam(path: Path, y: Sequence[float], lam: float) -> tuple[float, bool]:
    """Solve g(λ, y) = (y − σ(λ))·σ'(λ) = 0 near ``lam`` on σ's jets; returns (λ, converged)."""
    sigma = path.sigma
    for _ in range(NEWTON_ITERS):
        sx, sy, sz = sigma(Jet.variable(lam, order=2))
        ex, ey, ez = y[0] - sx.c[0], y[1] - sy.c[0], y[2] - sz.c[0]
        d1 = (sx.c[1], sy.c[1], sz.c[1])
        d2 = (2.0 * sx.c[2], 2.0 * sy.c[2], 2.0 * sz.c[2])
        g = ex * d1[0] + ey * d1[1] + ez * d1[2]
        dg = -(d1[0] ** 2 + d1[1] ** 2 + d1[2] ** 2) + ex * d2[0] + ey * d2[1] + ez * d2[2]
        if dg >= 0.0 or not math.isfinite(dg):
            # Not a local minimum of the distance here: step towards one along −g.
            step = -0.1 * math.copysign(1.0, g) if g else 0.1
        else:
            step = -g / dg
            step = max(-0.5, min(0.5, step))
        lam += step
        if abs(step) < _NEWTON_TOL:
            return lam, True
    return lam, abs(step) < 1e-8


def closest_lam(path: Path, y: Sequence[float]) -> tuple[float, bool]:
    """The closest point's λ from scratch (the global search, then Newton): (λ, converged)."""
    return newton_closest_lam(path, y, global_closest_lam(path, y))


def grad_s(path: Path, y0: Sequence[float]) -> tuple[tuple[float, float, float], ...]:
    """∂s/∂y at y0 (2 × 3) from three first-order jet evaluations of the path's s."""
    cols = []
    for axis in range(3):
        args = [Jet((y0[i], 1.0 if i == axis else 0.0)) for i in range(3)]
        s1, s2 = path.s(*args)
        cols.append((_slope(s1), _slope(s2)))
    return ((cols[0][0], cols[1][0], cols[2][0]), (cols[0][1], cols[1][1], cols[2][1]))


class PathTracker:
    """Keeps the closest-point parameter λ between calls and evaluates (α, π) on jets."""

    def __init__(self, path: Path, *, min_tube_margin: float = MIN_TUBE_MARGIN) -> None:
        self.path = path
        self.min_tube_margin = min_tube_margin
        self.lam: float | None = None
        self._arc_lam = 0.0       # λ of the first projection: π's origin
        self._arc_m = 0.0         # π: arc length from there to λ (m)

    # ------------------------------------------------------------------ projection
    def _project(self, y0: Sequence[float]) -> Expansion | None:
        """Move λ to the closest point of ``y0``; returns σ's expansion there.

        Newton runs on σ's degree-5 Taylor polynomial about the current λ (no calls into
        the path code), then σ is re-expanded at the new λ; from a warm start that is two
        evaluations of σ per tick. The arc length π is advanced over each step by
        :func:`projection.arc` on the expansions at the step's two ends — the flown
        projection's rule —, and only when the root is found (λ stays where it was if not).
        """
        lam = self.lam
        assert lam is not None
        arc_m = self._arc_m
        c = taylor_curve(self.path, lam)
        for _ in range(NEWTON_ITERS):
            delta = _poly_newton(c, y0)
            if delta is None:
                return None
            if abs(delta) < 1e-10:
                self.lam, self._arc_m = lam, arc_m
                return c
            lam += delta
            cn = taylor_curve(self.path, lam)
            arc_m += arc(c, cn, delta)
            c = cn
        return None

    # ------------------------------------------------------------------ evaluation
    def virtual_output(self, taylor: Sequence[Sequence[float]]) -> VirtualOutput:
        """:meth:`evaluate` as derivatives, the form the law consumes."""
        try:
            out = self.evaluate(taylor)
        except (ValueError, ZeroDivisionError, OverflowError) as exc:
            y0 = (taylor[0][0], taylor[1][0], taylor[2][0])
            out = self._lost(y0, f"path evaluation failed: {exc}")
        return VirtualOutput(out.alpha[0].derivatives(), out.alpha[1].derivatives(),
                             out.pi.derivatives(), out.jacobian, out.lam, out.distance_m,
                             out.in_tube, out.reason)

    def evaluate(self, taylor: Sequence[Sequence[float]]) -> PathOutput:
        """(α, π) jets of order 4 along the position's Taylor series.

        ``taylor[i]`` = (yᵢ, ẏᵢ, ÿᵢ/2, y⃛ᵢ/6, yᵢ⁽⁴⁾/24) for i = x, y, z (paper frame, m).
        """
        y0 = (taylor[0][0], taylor[1][0], taylor[2][0])
        if not all(math.isfinite(c) for row in taylor for c in row):
            return self._lost(y0, "non-finite state")
        if self.lam is None:
            lam, ok = closest_lam(self.path, y0)
            if not ok or not math.isfinite(lam):
                return self._lost(y0, "closest-point search did not converge")
            self.lam = self._arc_lam = lam
        c = self._project(y0)
        if c is None:
            return self._lost(y0, "closest-point search did not converge")
        lam = self.lam
        e0 = tuple(y0[i] - c.s0[i] for i in range(3))
        s1sq = c.s1[0] ** 2 + c.s1[1] ** 2 + c.s1[2] ** 2
        slope = -s1sq + 2.0 * (e0[0] * c.s2[0] + e0[1] * c.s2[1] + e0[2] * c.s2[2])
        margin = -slope / s1sq if s1sq > 0.0 else 0.0
        distance = math.sqrt(e0[0] ** 2 + e0[1] ** 2 + e0[2] ** 2)
        if margin < self.min_tube_margin:
            return self._lost(y0, f"distance {distance:.3f} m near the radius of curvature "
                                  f"(projection margin {margin:.2f})", lam, distance)

        pidot = pi_rates(c, taylor, slope)
        pi = Jet((self._arc_m, pidot[0], pidot[1] / 2.0, pidot[2] / 3.0, pidot[3] / 4.0))

        jx, jy, jz = (Jet(tuple(taylor[i][:5])) for i in range(3))
        a1, a2 = self.path.s(jx, jy, jz)
        grad = grad_s(self.path, y0)
        speed0 = math.sqrt(s1sq)
        k = speed0 / -slope
        grad_pi = (k * c.s1[0], k * c.s1[1], k * c.s1[2])
        return PathOutput((_as_jet(a1), _as_jet(a2)), pi, (grad[0], grad[1], grad_pi), lam,
                          distance, True)

    def _lost(self, y0: Sequence[float], reason: str, lam: float = math.nan,
              distance: float = math.nan) -> PathOutput:
        zero = Jet((0.0,) * 5)
        ident = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
        return PathOutput((zero, zero), zero, ident, lam, distance, False, reason)


def poly_g(c: Sequence[Sequence[Any]], y0: Sequence[Any], x: Any) -> tuple[Any, Any]:
    """g(x) = ⟨y0 − S(x), S'(x)⟩ and g'(x) for the polynomial S(x) = Σ_j c_j xʲ (j ≤ 5)."""
    s = [0.0, 0.0, 0.0]
    ds = [0.0, 0.0, 0.0]
    dds = [0.0, 0.0, 0.0]
    for i in range(3):
        c0, c1, c2, c3, c4, c5 = (c[0][i], c[1][i], c[2][i], c[3][i], c[4][i], c[5][i])
        s[i] = c0 + x * (c1 + x * (c2 + x * (c3 + x * (c4 + x * c5))))
        ds[i] = c1 + x * (2 * c2 + x * (3 * c3 + x * (4 * c4 + x * 5 * c5)))
        dds[i] = 2 * c2 + x * (6 * c3 + x * (12 * c4 + x * 20 * c5))
    e = [y0[i] - s[i] for i in range(3)]
    g = e[0] * ds[0] + e[1] * ds[1] + e[2] * ds[2]
    dg = (e[0] * dds[0] + e[1] * dds[1] + e[2] * dds[2]
          - (ds[0] * ds[0] + ds[1] * ds[1] + ds[2] * ds[2]))
    return g, dg


def newton_on_poly(g_dg: Callable[[float], tuple[float, float]],
                   max_step: float = 0.05) -> float | None:
    """δ with g(δ) = 0 by Newton from 0, |δ| ≤ ``max_step`` (where the degree-5 polynomial
    stands for σ to ~1e-8 relative); None if not found there. ``g_dg(δ)`` = (g, g')."""
    delta = 0.0
    for _ in range(8):
        g, dg = g_dg(delta)
        if not dg < 0.0:
            return None
        step = -g / dg
        delta += step
        if abs(delta) > max_step or not math.isfinite(delta):
            return None
        if abs(step) < 1e-13:
            return delta
    return delta if abs(step) < 1e-9 else None


def _poly_newton(c: Sequence[Sequence[float]], y0: Sequence[float]) -> float | None:
    """δ with ⟨y0 − S(δ), S'(δ)⟩ = 0 for S(δ) = Σ c_j δʲ (see :func:`newton_on_poly`)."""
    return newton_on_poly(lambda x: poly_g(c, y0, x))


def _lambda_series(c: Sequence[Sequence[Any]], taylor: Sequence[Sequence[Any]],
                   slope: Any) -> tuple[tuple[Any, Any, Any, Any], list[list[Any]]]:
    """Taylor coefficients d₁…d₄ of δ(t) = λ(t) − λ0 from g(t) = ⟨Y − σ(λ), σ'(λ)⟩ ≡ 0,
    and the coefficients T₀…T₃ of σ'(λ(t)) (per axis) found on the way.

    With E = Y − σ(λ(t)) and T = σ'(λ(t)), g_k = Σ_{a+b=k} ⟨E_a, T_b⟩. Order k holds d_k
    only in E_k (−σ' d_k) and T_k (+σ'' d_k), so g_k = (∂g/∂λ) d_k + g_k⁰ with g_k⁰ the
    same sum at d_k = 0: d_k = −g_k⁰/(∂g/∂λ), one order at a time (k = 1…4). E_a, T_a of
    the lower orders are kept, not recomputed (the coefficient k of δᵐ, m ≥ 2, holds only
    d₁…d_{k−1}). ``c[j]`` = σ⁽ʲ⁾(λ0)/j!, ``taylor[i]`` = the position's Taylor
    coefficients. Plain arithmetic, so it can be traced (:mod:`jetcode`).
    """
    inv = -1.0 / slope
    ax = range(3)
    c1 = [c[1][i] for i in ax]
    c2 = [c[2][i] for i in ax]
    c3 = [c[3][i] for i in ax]
    c4 = [c[4][i] for i in ax]
    c5 = [c[5][i] for i in ax]
    dc2 = [2.0 * c2[i] for i in ax]           # σ''/1!, the slope of T in d_k
    tc3 = [3.0 * c3[i] for i in ax]
    fc4 = [4.0 * c4[i] for i in ax]
    E = [[taylor[i][0] - c[0][i] for i in ax]]
    T = [c1]
    # Order 1: E₁⁰ = Y₁, T₁⁰ = 0.
    d1 = (taylor[0][1] * c1[0] + taylor[1][1] * c1[1] + taylor[2][1] * c1[2]) * inv
    E.append([taylor[i][1] - c1[i] * d1 for i in ax])
    T.append([dc2[i] * d1 for i in ax])
    # Order 2: δ² = d₁² t² + …
    p2_2 = d1 * d1
    e0 = [taylor[i][2] - c2[i] * p2_2 for i in ax]
    t0 = [tc3[i] * p2_2 for i in ax]
    d2 = sum(E[0][i] * t0[i] + e0[i] * c1[i] + E[1][i] * T[1][i] for i in ax) * inv
    E.append([e0[i] - c1[i] * d2 for i in ax])
    T.append([t0[i] + dc2[i] * d2 for i in ax])
    # Order 3.
    p2_3 = 2.0 * d1 * d2
    p3_3 = p2_2 * d1
    e0 = [taylor[i][3] - (c2[i] * p2_3 + c3[i] * p3_3) for i in ax]
    t0 = [tc3[i] * p2_3 + fc4[i] * p3_3 for i in ax]
    d3 = sum(E[0][i] * t0[i] + e0[i] * c1[i] + E[1][i] * T[2][i] + E[2][i] * T[1][i]
             for i in ax) * inv
    E.append([e0[i] - c1[i] * d3 for i in ax])
    T.append([t0[i] + dc2[i] * d3 for i in ax])
    # Order 4 (E₄, T₄ themselves are not needed).
    p2_4 = 2.0 * d1 * d3 + d2 * d2
    p3_4 = 3.0 * p2_2 * d2
    p4_4 = p2_2 * p2_2
    e0 = [taylor[i][4] - (c2[i] * p2_4 + c3[i] * p3_4 + c4[i] * p4_4) for i in ax]
    t0 = [tc3[i] * p2_4 + fc4[i] * p3_4 + 5.0 * c5[i] * p4_4 for i in ax]
    d4 = sum(E[0][i] * t0[i] + e0[i] * c1[i] + E[1][i] * T[3][i] + E[2][i] * T[2][i]
             + E[3][i] * T[1][i] for i in ax) * inv
    return (d1, d2, d3, d4), T


def _as_jet(x: Any) -> Jet:
    return x if isinstance(x, Jet) else Jet((float(x), 0.0, 0.0, 0.0, 0.0))


def _slope(x: Any) -> float:
    return x.c[1] if isinstance(x, Jet) else 0.0


def pi_rates(c: Sequence[Sequence[Any]], taylor: Sequence[Sequence[Any]], slope: Any,
             sqrt: Callable[[Any], Any] = math.sqrt) -> tuple[Any, Any, Any, Any]:
    """(π̇, π̈, π⃛, π⁽⁴⁾) from σ's Taylor coefficients ``c`` at the closest point, the
    position's ``taylor`` rows and the projection slope ∂g/∂λ (< 0 in the tube).

    π̇ = |σ'(λ(t))| λ̇(t), with σ'(λ(t)) = T₀ + T₁t + … and δ(t) from
    :func:`_lambda_series`. Plain arithmetic (``sqrt`` passed in), so it can be traced.
    """
    (d1, d2, d3, d4), T = _lambda_series(c, taylor, slope)
    t0, t1, t2, t3 = T
    speed2 = [0.0, 0.0, 0.0, 0.0]
    for i in range(3):
        speed2[0] += t0[i] * t0[i]
        speed2[1] += 2.0 * t0[i] * t1[i]
        speed2[2] += 2.0 * t0[i] * t2[i] + t1[i] * t1[i]
        speed2[3] += 2.0 * (t0[i] * t3[i] + t1[i] * t2[i])
    speed = sqrt_series(speed2, sqrt(speed2[0]))
    l1, l2, l3, l4 = d1, 2.0 * d2, 3.0 * d3, 4.0 * d4
    return (speed[0] * l1,
            speed[0] * l2 + speed[1] * l1,
            speed[0] * l3 + speed[1] * l2 + speed[2] * l1,
            speed[0] * l4 + speed[1] * l3 + speed[2] * l2 + speed[3] * l1)
