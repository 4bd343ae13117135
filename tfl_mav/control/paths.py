"""Paths as zero sets, and the virtual output (α, π) with its time derivatives (paper §IV).

A path is the zero set of ``s: R³ → R²`` (§IV, eq. (7)) together with a regular
parameterisation ``σ(λ)``. Both are written once as ordinary code that works on floats,
numpy arrays and Taylor jets (:mod:`jets`), so every derivative the law needs comes from
evaluating the same code on jets: α = s(y) and its derivatives up to order 4 from one jet
evaluation on the position's Taylor series.

π (eq. (14)'s ϖ) is the arc length of the closest path point. Its time
derivatives come from implicitly differentiating the projection condition

    g(λ, y) = ⟨y − σ(λ), σ'(λ)⟩ = 0,

solved for the value by Newton (warm-started from the last λ) and then for the Taylor
coefficients of λ(t) one order at a time: coefficient k of g is linear in λ's coefficient k
with slope ∂g/∂λ = −|σ'|² + ⟨y − σ, σ''⟩, the same slope at every order. That slope also
measures how far the vehicle is from losing the projection: it vanishes where the distance
to the path reaches the radius of curvature (0.24 m at the paper path's bends), so
:class:`PathTracker` reports ``in_tube = False`` before the derivatives blow up instead of
returning NaN.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from tfl_mav.control.jets import JET_LIB, Jet, cos, sin
from tfl_mav.expr import ExprError, compile_expr

__all__ = ["PATH_KINDS", "Path", "PathError", "PathOutput", "PathTracker", "build_path"]

Fn3 = Callable[[Any, Any, Any], tuple[Any, Any]]
Curve = Callable[[Any], tuple[Any, Any, Any]]


class PathError(ValueError):
    """A path definition error naming the scenario key (``path.<key>``)."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field
        self.message = message


@dataclass(frozen=True)
class Path:
    """A regular curve as a zero set ``s(y) = 0`` and a parameterisation ``σ(λ)``.

    ``s`` and ``sigma`` accept floats, numpy arrays and jets. ``period`` is σ's period in λ
    for closed curves (None = open); ``lam_range`` is where the first projection searches.
    Coordinates are the paper frame (z up), metres.
    """

    kind: str
    s: Fn3
    sigma: Curve
    lam_range: tuple[float, float]
    period: float | None = None

    def sample(self, n: int) -> np.ndarray:
        """``n`` points (n × 3, metres) along ``lam_range``, for plots and scene markers."""
        lam = np.linspace(self.lam_range[0], self.lam_range[1], n)
        x, y, z = self.sigma(lam)
        return np.column_stack([x + 0 * lam, y + 0 * lam, z + 0 * lam])


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
_NEWTON_ITERS = 20
_NEWTON_TOL = 1e-12


def _taylor_curve(path: Path, lam0: float) -> list[tuple[float, float, float]]:
    """σ(λ0 + δ) = Σ_j c_j δʲ for j = 0..5: coefficients c_j = σ⁽ʲ⁾(λ0)/j! (vectors)."""
    jx, jy, jz = path.sigma(Jet.variable(lam0, order=5))
    cx = jx.c if isinstance(jx, Jet) else (float(jx),) + (0.0,) * 5
    cy = jy.c if isinstance(jy, Jet) else (float(jy),) + (0.0,) * 5
    cz = jz.c if isinstance(jz, Jet) else (float(jz),) + (0.0,) * 5
    return [(cx[j], cy[j], cz[j]) for j in range(6)]


class PathTracker:
    """Keeps the closest-point parameter λ between calls and evaluates (α, π) on jets."""

    def __init__(self, path: Path, *, min_tube_margin: float = MIN_TUBE_MARGIN) -> None:
        self.path = path
        self.min_tube_margin = min_tube_margin
        self.lam: float | None = None
        self._arc_lam = 0.0       # λ of the first projection: π's origin
        self._arc_m = 0.0         # π: arc length from there to λ (m)

    # ------------------------------------------------------------------ projection
    def _global_lam(self, y: Sequence[float]) -> float:
        lo, hi = self.path.lam_range
        lam = np.linspace(lo, hi, 4001)
        x, yy, z = self.path.sigma(lam)
        d2 = (x - y[0]) ** 2 + (yy - y[1]) ** 2 + (z - y[2]) ** 2
        return float(lam[int(np.argmin(d2))])

    def _newton(self, y: Sequence[float], lam: float) -> tuple[float, bool]:
        """Solve g(λ, y) = 0 near ``lam``; returns (λ, converged)."""
        sigma = self.path.sigma
        for _ in range(_NEWTON_ITERS):
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

    def _project(self, y0: Sequence[float]) -> list[tuple[float, float, float]] | None:
        """Move λ to the closest point of ``y0``; returns σ's Taylor coefficients there.

        Newton runs on σ's degree-5 Taylor polynomial about the current λ (no calls into
        the path code), then σ is re-expanded at the new λ; from a warm start that is two
        evaluations of σ per tick. The arc length π is advanced on the same polynomial
        (Simpson's rule on |σ'|, exact to O(Δλ⁵)).
        """
        lam = self.lam
        assert lam is not None
        for _ in range(_NEWTON_ITERS):
            c = _taylor_curve(self.path, lam)
            delta = _poly_newton(c, y0)
            if delta is None:
                return None
            if abs(delta) < 1e-10:
                self.lam = lam
                return c
            self._arc_m += _poly_arc(c, delta)
            lam += delta
        return None

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, taylor: Sequence[Sequence[float]]) -> PathOutput:
        """(α, π) jets of order 4 along the position's Taylor series.

        ``taylor[i]`` = (yᵢ, ẏᵢ, ÿᵢ/2, y⃛ᵢ/6, yᵢ⁽⁴⁾/24) for i = x, y, z (paper frame, m).
        """
        y0 = (taylor[0][0], taylor[1][0], taylor[2][0])
        if not all(math.isfinite(c) for row in taylor for c in row):
            return self._lost(y0, "non-finite state")
        if self.lam is None:
            lam, ok = self._newton(y0, self._global_lam(y0))
            if not ok or not math.isfinite(lam):
                return self._lost(y0, "closest-point search did not converge")
            self.lam = self._arc_lam = lam
        c = self._project(y0)
        if c is None:
            return self._lost(y0, "closest-point search did not converge")
        lam = self.lam
        e0 = tuple(y0[i] - c[0][i] for i in range(3))
        s1sq = c[1][0] ** 2 + c[1][1] ** 2 + c[1][2] ** 2
        slope = -s1sq + 2.0 * (e0[0] * c[2][0] + e0[1] * c[2][1] + e0[2] * c[2][2])
        margin = -slope / s1sq if s1sq > 0.0 else 0.0
        distance = math.sqrt(e0[0] ** 2 + e0[1] ** 2 + e0[2] ** 2)
        if margin < self.min_tube_margin:
            return self._lost(y0, f"distance {distance:.3f} m near the radius of curvature "
                                  f"(projection margin {margin:.2f})", lam, distance)

        d1, d2, d3, d4 = _lambda_series(c, taylor, slope)
        # σ'(λ(t)) = Σ_j (j+1) c_{j+1} δʲ to order 3; π̇ = |σ'(λ(t))| λ̇(t), integrated once.
        p2_2, p2_3 = d1 * d1, 2.0 * d1 * d2
        p3_3 = d1 * p2_2
        speed2 = [0.0, 0.0, 0.0, 0.0]
        for i in range(3):
            c1, c2, c3, c4 = 1.0 * c[1][i], 2.0 * c[2][i], 3.0 * c[3][i], 4.0 * c[4][i]
            t0 = c1
            t1 = c2 * d1
            t2 = c2 * d2 + c3 * p2_2
            t3 = c2 * d3 + c3 * p2_3 + c4 * p3_3
            speed2[0] += t0 * t0
            speed2[1] += 2.0 * t0 * t1
            speed2[2] += 2.0 * t0 * t2 + t1 * t1
            speed2[3] += 2.0 * (t0 * t3 + t1 * t2)
        speed = Jet(tuple(speed2)).sqrt().c
        l1, l2, l3, l4 = d1, 2.0 * d2, 3.0 * d3, 4.0 * d4
        pidot = (speed[0] * l1,
                 speed[0] * l2 + speed[1] * l1,
                 speed[0] * l3 + speed[1] * l2 + speed[2] * l1,
                 speed[0] * l4 + speed[1] * l3 + speed[2] * l2 + speed[3] * l1)
        pi0 = self._arc_m
        pi = Jet((pi0, pidot[0], pidot[1] / 2.0, pidot[2] / 3.0, pidot[3] / 4.0))

        jx, jy, jz = (Jet(tuple(taylor[i][:5])) for i in range(3))
        a1, a2 = self.path.s(jx, jy, jz)
        grad = self._grad_s(y0)
        speed0 = math.sqrt(s1sq)
        k = speed0 / -slope
        grad_pi = (k * c[1][0], k * c[1][1], k * c[1][2])
        return PathOutput((_as_jet(a1), _as_jet(a2)), pi, (grad[0], grad[1], grad_pi), lam,
                          distance, True)

    def _grad_s(self, y0: Sequence[float]) -> tuple[tuple[float, float, float], ...]:
        """∂s/∂y at y0 (2 × 3) from three first-order jet evaluations."""
        cols = []
        for axis in range(3):
            args = [Jet((y0[i], 1.0 if i == axis else 0.0)) for i in range(3)]
            s1, s2 = self.path.s(*args)
            cols.append((_slope(s1), _slope(s2)))
        return ((cols[0][0], cols[1][0], cols[2][0]), (cols[0][1], cols[1][1], cols[2][1]))

    def _lost(self, y0: Sequence[float], reason: str, lam: float = math.nan,
              distance: float = math.nan) -> PathOutput:
        zero = Jet((0.0,) * 5)
        ident = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
        return PathOutput((zero, zero), zero, ident, lam, distance, False, reason)


def _poly_newton(c: Sequence[Sequence[float]], y0: Sequence[float],
                 max_step: float = 0.05) -> float | None:
    """δ with ⟨y0 − S(δ), S'(δ)⟩ = 0 for S(δ) = Σ c_j δʲ, |δ| ≤ ``max_step`` (where the
    degree-5 polynomial stands for σ to ~1e-8 relative); None if not found there."""
    delta = 0.0
    for _ in range(8):
        s = [0.0, 0.0, 0.0]
        ds = [0.0, 0.0, 0.0]
        dds = [0.0, 0.0, 0.0]
        for i in range(3):
            c0, c1, c2, c3, c4, c5 = (c[0][i], c[1][i], c[2][i], c[3][i], c[4][i], c[5][i])
            x = delta
            s[i] = c0 + x * (c1 + x * (c2 + x * (c3 + x * (c4 + x * c5))))
            ds[i] = c1 + x * (2 * c2 + x * (3 * c3 + x * (4 * c4 + x * 5 * c5)))
            dds[i] = 2 * c2 + x * (6 * c3 + x * (12 * c4 + x * 20 * c5))
        e = [y0[i] - s[i] for i in range(3)]
        g = e[0] * ds[0] + e[1] * ds[1] + e[2] * ds[2]
        dg = (e[0] * dds[0] + e[1] * dds[1] + e[2] * dds[2]
              - (ds[0] * ds[0] + ds[1] * ds[1] + ds[2] * ds[2]))
        if not dg < 0.0:
            return None
        step = -g / dg
        delta += step
        if abs(delta) > max_step or not math.isfinite(delta):
            return None
        if abs(step) < 1e-13:
            return delta
    return delta if abs(step) < 1e-9 else None


def _poly_arc(c: Sequence[Sequence[float]], delta: float) -> float:
    """∫₀^δ |S'(u)| du by Simpson's rule (signed: negative for δ < 0)."""
    def speed(x: float) -> float:
        acc = 0.0
        for i in range(3):
            d = c[1][i] + x * (2 * c[2][i] + x * (3 * c[3][i] + x * (4 * c[4][i]
                                                                   + x * 5 * c[5][i])))
            acc += d * d
        return math.sqrt(acc)

    return delta / 6.0 * (speed(0.0) + 4.0 * speed(0.5 * delta) + speed(delta))


def _lambda_series(c: Sequence[Sequence[float]], taylor: Sequence[Sequence[float]],
                   slope: float) -> tuple[float, float, float, float]:
    """Taylor coefficients d₁…d₄ of δ(t) = λ(t) − λ0 from g(t) = ⟨Y − σ(λ), σ'(λ)⟩ ≡ 0.

    Coefficient k of g is affine in d_k with slope ∂g/∂λ; computing it with d_k = 0 and
    solving gives d_k, one order at a time (k = 1…4). ``c[j]`` = σ⁽ʲ⁾(λ0)/j!, ``taylor[i]``
    = the position's Taylor coefficients. Unrolled: this runs every control tick.
    """
    inv = -1.0 / slope
    d = [0.0, 0.0, 0.0, 0.0, 0.0]
    for k in range(1, 5):
        d1, d2, d3 = d[1], d[2], d[3]
        # Powers of δ up to order k (δ has no constant term), with d_k still 0.
        p2 = (0.0, 0.0, d1 * d1, 2.0 * d1 * d2, 2.0 * d1 * d3 + d2 * d2)
        p3 = (0.0, 0.0, 0.0, d1 * d1 * d1, 3.0 * d1 * d1 * d2)
        p4 = (0.0, 0.0, 0.0, 0.0, d1 * d1 * d1 * d1)
        gk = 0.0
        for i in range(3):
            c0, c1, c2, c3, c4, c5 = (c[0][i], c[1][i], c[2][i], c[3][i], c[4][i], c[5][i])
            y = taylor[i]
            # E_n = Y_n − σ_n and T_n = σ'_n for n = 0..k.
            e = [y[0] - c0]
            t = [c1]
            for n in range(1, k + 1):
                e.append(y[n] - (c1 * d[n] + c2 * p2[n] + c3 * p3[n] + c4 * p4[n]))
                t.append(2.0 * c2 * d[n] + 3.0 * c3 * p2[n] + 4.0 * c4 * p3[n]
                         + 5.0 * c5 * p4[n])
            for a in range(k + 1):
                gk += e[a] * t[k - a]
        d[k] = gk * inv
    return d[1], d[2], d[3], d[4]


def _as_jet(x: Any) -> Jet:
    return x if isinstance(x, Jet) else Jet((float(x), 0.0, 0.0, 0.0, 0.0))


def _slope(x: Any) -> float:
    return x.c[1] if isinstance(x, Jet) else 0.0


_GAUSS5 = tuple(zip(
    (-0.9061798459386640, -0.5384693101056831, 0.0, 0.5384693101056831, 0.9061798459386640),
    (0.2369268850561891, 0.4786286704993665, 0.5688888888888889, 0.4786286704993665,
     0.2369268850561891), strict=True))


# ---------------------------------------------------------------------------- built-ins
def _vec3(params: Mapping[str, Any], key: str, default: Sequence[float]) -> tuple[float, ...]:
    value = params.get(key, default)
    if (not isinstance(value, (list, tuple)) or len(value) != 3
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                       and math.isfinite(v) for v in value)):
        raise PathError(f"path.{key}", f"expected 3 finite numbers, got {value!r}")
    return tuple(float(v) for v in value)


def _positive(params: Mapping[str, Any], key: str, default: float) -> float:
    value = params.get(key, default)
    if (not isinstance(value, (int, float)) or isinstance(value, bool)
            or not math.isfinite(value) or value <= 0):
        raise PathError(f"path.{key}", f"expected a positive number, got {value!r}")
    return float(value)


def _paper(params: Mapping[str, Any]) -> Path:
    """The paper's path {y2 = cos y1, y3 = 8 − 4 cos y1} (§VI), parameterised by y1."""
    def s(x: Any, y: Any, z: Any) -> tuple[Any, Any]:
        return y - cos(x), z - 8.0 + 4.0 * cos(x)

    def sigma(lam: Any) -> tuple[Any, Any, Any]:
        return lam, cos(lam), 8.0 - 4.0 * cos(lam)

    return Path("paper", s, sigma, (-4.0 * math.pi, 4.0 * math.pi))


def _line(params: Mapping[str, Any]) -> Path:
    """Straight line through ``point_m`` along ``direction``."""
    p = _vec3(params, "point_m", (0.0, 0.0, 2.0))
    d = np.array(_vec3(params, "direction", (1.0, 0.0, 0.0)))
    if np.linalg.norm(d) < 1e-9:
        raise PathError("path.direction", "must not be zero")
    d = d / np.linalg.norm(d)
    helper = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    n1 = np.cross(d, helper)
    n1 /= np.linalg.norm(n1)
    n2 = np.cross(d, n1)
    n1t, n2t, dt = tuple(map(float, n1)), tuple(map(float, n2)), tuple(map(float, d))
    length = _positive(params, "length_m", 100.0)

    def s(x: Any, y: Any, z: Any) -> tuple[Any, Any]:
        ex, ey, ez = x - p[0], y - p[1], z - p[2]
        return (n1t[0] * ex + n1t[1] * ey + n1t[2] * ez,
                n2t[0] * ex + n2t[1] * ey + n2t[2] * ez)

    def sigma(lam: Any) -> tuple[Any, Any, Any]:
        return p[0] + dt[0] * lam, p[1] + dt[1] * lam, p[2] + dt[2] * lam

    return Path("line", s, sigma, (-length / 2, length / 2))


def _circle(params: Mapping[str, Any]) -> Path:
    """Horizontal circle: ``center_m``, ``radius_m``; s = ((ρ² − r²)/2r, z − c_z)."""
    c = _vec3(params, "center_m", (0.0, 0.0, 5.0))
    r = _positive(params, "radius_m", 2.0)

    def s(x: Any, y: Any, z: Any) -> tuple[Any, Any]:
        ex, ey = x - c[0], y - c[1]
        return (ex * ex + ey * ey - r * r) * (0.5 / r), z - c[2]

    def sigma(lam: Any) -> tuple[Any, Any, Any]:
        return c[0] + r * cos(lam), c[1] + r * sin(lam), c[2] + 0.0 * lam

    return Path("circle", s, sigma, (0.0, 2.0 * math.pi), 2.0 * math.pi)


def _helix(params: Mapping[str, Any]) -> Path:
    """Helix about the vertical through ``center_m``: ``radius_m``, ``pitch_m`` rise per turn.

    s = (x − c_x − r cos kζ, y − c_y − r sin kζ) with ζ = z − c_z, k = 2π/pitch: the zero
    set is exactly one helix (a form with atan2 would be discontinuous).
    """
    c = _vec3(params, "center_m", (0.0, 0.0, 1.0))
    r = _positive(params, "radius_m", 2.0)
    pitch = _positive(params, "pitch_m", 1.0)
    turns = _positive(params, "turns", 20.0)
    k = 2.0 * math.pi / pitch

    def s(x: Any, y: Any, z: Any) -> tuple[Any, Any]:
        th = k * (z - c[2])
        return x - c[0] - r * cos(th), y - c[1] - r * sin(th)

    def sigma(lam: Any) -> tuple[Any, Any, Any]:
        return c[0] + r * cos(lam), c[1] + r * sin(lam), c[2] + lam / k

    return Path("helix", s, sigma, (-2.0 * math.pi, 2.0 * math.pi * turns))


def _lemniscate(params: Mapping[str, Any]) -> Path:
    """Figure-eight (Gerono lemniscate seen from above) on a saddle, so it never crosses.

    σ(λ) = c + (a cos λ, a sin λ cos λ, b sin λ) with ``size_m`` = a (half-width) and
    ``height_m`` = b: the two lobes' crossing point is split by 2b vertically, because a
    self-crossing curve cannot be the regular zero set of s (its Jacobian would be singular
    there). s = (y' − x' z'/b, x'²/a² + z'²/b² − 1) with primes relative to c.
    """
    c = _vec3(params, "center_m", (0.0, 0.0, 5.0))
    a = _positive(params, "size_m", 3.0)
    b = _positive(params, "height_m", 0.5)

    def s(x: Any, y: Any, z: Any) -> tuple[Any, Any]:
        ex, ey, ez = x - c[0], y - c[1], z - c[2]
        return ey - ex * ez / b, ex * ex / (a * a) + ez * ez / (b * b) - 1.0

    def sigma(lam: Any) -> tuple[Any, Any, Any]:
        sl = sin(lam)
        cl = cos(lam)
        return c[0] + a * cl, c[1] + a * sl * cl, c[2] + b * sl

    return Path("lemniscate", s, sigma, (0.0, 2.0 * math.pi), 2.0 * math.pi)


def _expr(params: Mapping[str, Any]) -> Path:
    """A path from expressions: ``s`` (2, in x, y, z), ``sigma`` (3, in t), optional
    ``period`` (closed curve) and ``t_range`` (search range of t, default [0, period] or
    [-10, 10]). Checked on samples: s(σ(t)) ≈ 0, σ'(t) ≠ 0, ∂s/∂y of rank 2."""
    s_text, sig_text = params.get("s"), params.get("sigma")
    if not (isinstance(s_text, list) and len(s_text) == 2
            and all(isinstance(t, str) for t in s_text)):
        raise PathError("path.s", 'expected two expressions in x, y, z, e.g. '
                                  '["y - cos(x)", "z - 8 + 4*cos(x)"]')
    if not (isinstance(sig_text, list) and len(sig_text) == 3
            and all(isinstance(t, str) for t in sig_text)):
        raise PathError("path.sigma", 'expected three expressions in t, e.g. '
                                      '["t", "cos(t)", "8 - 4*cos(t)"]')
    try:
        s_exprs = [compile_expr(t, ("x", "y", "z"), field=f"path.s[{i}]")
                   for i, t in enumerate(s_text)]
        sig_exprs = [compile_expr(t, ("t",), field=f"path.sigma[{i}]")
                     for i, t in enumerate(sig_text)]
    except ExprError as exc:
        raise PathError(exc.field, exc.message) from None
    period = params.get("period")
    if period is not None:
        period = _positive(params, "period", 1.0)
    t_range = params.get("t_range", [0.0, period] if period else [-10.0, 10.0])
    if (not isinstance(t_range, list) or len(t_range) != 2
            or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in t_range)
            or t_range[1] <= t_range[0]):
        raise PathError("path.t_range", f"expected [t_min, t_max] with t_min < t_max, "
                                        f"got {t_range!r}")

    def s(x: Any, y: Any, z: Any) -> tuple[Any, Any]:
        env = {"x": x, "y": y, "z": z}
        return s_exprs[0](env, JET_LIB), s_exprs[1](env, JET_LIB)

    def sigma(lam: Any) -> tuple[Any, Any, Any]:
        env = {"t": lam}
        return sig_exprs[0](env, JET_LIB), sig_exprs[1](env, JET_LIB), sig_exprs[2](env, JET_LIB)

    path = Path("expr", s, sigma, (float(t_range[0]), float(t_range[1])), period)
    _check_path(path)
    return path


def _check_path(path: Path, n: int = 64) -> None:
    """Say what is wrong with a user path instead of letting the law fail later."""
    lo, hi = path.lam_range
    scale = 1.0
    for i in range(n):
        lam = lo + (hi - lo) * (i + 0.5) / n
        try:
            sx, sy, sz = (_as_jet1(v) for v in path.sigma(Jet.variable(lam, order=1)))
            p = (sx.c[0], sy.c[0], sz.c[0])
            r = [_as_jet1(v) for v in path.s(*(Jet((v, 1.0)) for v in p))]
            grads = PathTracker(path)._grad_s(p)
        except (ValueError, ZeroDivisionError, OverflowError) as exc:
            raise PathError("path.sigma", f"cannot evaluate at t = {lam:.4g}: {exc}") from None
        speed = math.sqrt(sx.c[1] ** 2 + sy.c[1] ** 2 + sz.c[1] ** 2)
        if not math.isfinite(speed) or speed < 1e-6:
            raise PathError("path.sigma", f"sigma'(t) = 0 at t = {lam:.4g}: not regular")
        scale = max(scale, abs(p[0]), abs(p[1]), abs(p[2]))
        res = max(abs(r[0].c[0]), abs(r[1].c[0]))
        if not math.isfinite(res) or res > 1e-6 * scale:
            raise PathError("path.s", f"s(sigma(t)) = {res:.3g} != 0 at t = {lam:.4g}: "
                                      "sigma does not lie on the zero set of s")
        g = np.array(grads)
        sv = np.linalg.svd(g, compute_uv=False)
        if not np.all(np.isfinite(sv)) or sv[1] < 1e-6 * max(sv[0], 1e-12):
            raise PathError("path.s", f"ds/dy has rank < 2 at t = {lam:.4g}: not a regular "
                                      "zero set")


def _as_jet1(x: Any) -> Jet:
    return x if isinstance(x, Jet) else Jet((float(x), 0.0))


PATH_KINDS: dict[str, Callable[[Mapping[str, Any]], Path]] = {
    "paper": _paper,
    "line": _line,
    "circle": _circle,
    "helix": _helix,
    "lemniscate": _lemniscate,
    "expr": _expr,
}

_KNOWN_KEYS: dict[str, set[str]] = {
    "paper": set(),
    "line": {"point_m", "direction", "length_m"},
    "circle": {"center_m", "radius_m"},
    "helix": {"center_m", "radius_m", "pitch_m", "turns"},
    "lemniscate": {"center_m", "size_m", "height_m"},
    "expr": {"s", "sigma", "period", "t_range"},
}


def build_path(kind: str, params: Mapping[str, Any] | None = None) -> Path:
    """The path ``kind`` with its keys ``params`` (the ``[path]`` table minus kind/speed)."""
    params = dict(params or {})
    if kind not in PATH_KINDS:
        raise PathError("path.kind", f"unknown kind {kind!r} (known: {', '.join(PATH_KINDS)})")
    unknown = sorted(set(params) - _KNOWN_KEYS[kind])
    if unknown:
        known = ", ".join(sorted(_KNOWN_KEYS[kind])) or "none"
        raise PathError(f"path.{unknown[0]}", f"unknown key for kind {kind!r} (known: {known})")
    return PATH_KINDS[kind](params)
