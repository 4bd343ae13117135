"""Paths as zero sets of s: R³ → R² with a regular parameterisation σ (paper §IV, eq. (7)).

A path is written once as ordinary code that works on floats, numpy arrays and Taylor jets
(:mod:`jets`): the built-in kinds below, or a scenario's expressions (``kind = "expr"``).
From that one definition the reference tracker (:mod:`tracker`) gets every derivative the
law needs by evaluating it on jets, and the compiled tracker (:mod:`compiled`) traces it
once into straight-line code.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from tfl_mav.control.path.jets import JET_LIB, Jet, cos, sin
from tfl_mav.control.path.tracker import PathOutput, PathTracker, grad_s
from tfl_mav.expr import Expr, ExprError, compile_expr

__all__ = ["KNOWN_KEYS", "PATH_KINDS", "Path", "PathError", "PathOutput", "PathTracker",
           "build_path"]

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
    for closed curves (None = open); ``lam_range`` is where the first projection searches;
    ``source``: the (s, σ) expressions of ``kind = "expr"``, which the code generator
    evaluates on its own traced values.
    Coordinates are the paper frame (z up), metres.
    """

    kind: str
    s: Fn3
    sigma: Curve
    lam_range: tuple[float, float]
    period: float | None = None
    source: tuple[tuple[Expr, ...], tuple[Expr, ...]] | None = None

    def sample(self, n: int) -> np.ndarray:
        """``n`` points (n × 3, metres) along ``lam_range``, for plots and scene markers."""
        lam = np.linspace(self.lam_range[0], self.lam_range[1], n)
        x, y, z = self.sigma(lam)
        return np.column_stack([x + 0 * lam, y + 0 * lam, z + 0 * lam])


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
        return (_like(s_exprs[0](env, JET_LIB), x), _like(s_exprs[1](env, JET_LIB), x))

    def sigma(lam: Any) -> tuple[Any, Any, Any]:
        env = {"t": lam}
        return (_like(sig_exprs[0](env, JET_LIB), lam), _like(sig_exprs[1](env, JET_LIB), lam),
                _like(sig_exprs[2](env, JET_LIB), lam))

    path = Path("expr", s, sigma, (float(t_range[0]), float(t_range[1])), period,
                (tuple(s_exprs), tuple(sig_exprs)))
    _check_path(path)
    return path


def _like(value: Any, arg: Any) -> Any:
    """An expression's value in the form of its argument: a component that does not depend
    on the variable (``"3.0"``, a level path's height) evaluates to a plain number, which a
    jet or an array of λ must see as a constant jet or a constant array."""
    if isinstance(value, (int, float)):
        if isinstance(arg, Jet):
            return Jet.constant(float(value), order=len(arg.c) - 1)
        if isinstance(arg, np.ndarray):
            return np.full(arg.shape, float(value))
    return value


_GRID_N = 4001   # the grid of t the path's demand is read on (controller.feasibility)


def _check_path(path: Path, n: int = 64) -> None:
    """Say what is wrong with a user path instead of letting the law fail later."""
    lo, hi = path.lam_range
    # σ must be finite on the whole search range, end points included: a pole (``1/t``)
    # or a function outside its domain (``log(t)``, ``sqrt(t)``) at a t the projection or
    # the feasibility check reads would otherwise come out as NaN far from here.
    grid = np.linspace(lo, hi, _GRID_N)
    with np.errstate(all="ignore"):
        try:
            pts = np.array([np.asarray(_like(c, grid), dtype=float) + 0.0 * grid
                            for c in path.sigma(grid)])
        except (ValueError, ZeroDivisionError, OverflowError, TypeError) as exc:
            raise PathError("path.sigma", f"cannot evaluate on t in [{lo:g}, {hi:g}]: "
                                          f"{exc}") from None
    bad = ~np.all(np.isfinite(pts), axis=0)
    if np.any(bad):
        t_bad = float(grid[np.argmax(bad)])
        raise PathError("path.sigma", f"not finite at t = {t_bad:.4g} (a pole, or log/sqrt "
                                      f"of a negative number); choose path.t_range within "
                                      f"the domain (now [{lo:g}, {hi:g}])")
    # ... and regular there: a σ' = 0 at a grid point (t**3 at 0) has no tangent, and the
    # path's demand (curvature) there is 0/0
    h = 1e-4
    with np.errstate(all="ignore"):
        ahead = np.array([np.asarray(_like(c, grid), dtype=float) + 0.0 * grid
                          for c in path.sigma(grid + h)])
        behind = np.array([np.asarray(_like(c, grid), dtype=float) + 0.0 * grid
                           for c in path.sigma(grid - h)])
    speed = np.linalg.norm((ahead - behind) / (2 * h), axis=0)
    stalled = ~(speed > 1e-6)
    if np.any(stalled):
        t_bad = float(grid[np.argmax(stalled)])
        raise PathError("path.sigma", f"sigma'(t) = 0 at t = {t_bad:.4g}: not regular (no "
                                      "tangent there); reparametrise or choose path.t_range "
                                      "without it")
    scale = 1.0
    for i in range(n):
        lam = lo + (hi - lo) * (i + 0.5) / n
        try:
            sx, sy, sz = (_as_jet1(v) for v in path.sigma(Jet.variable(lam, order=1)))
            p = (sx.c[0], sy.c[0], sz.c[0])
            r = [_as_jet1(v) for v in path.s(*(Jet((v, 1.0)) for v in p))]
            grads = grad_s(path, p)
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

#: The keys of each path kind's ``[path]`` table (besides kind and speed_mps).
KNOWN_KEYS: dict[str, set[str]] = {
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
    unknown = sorted(set(params) - KNOWN_KEYS[kind])
    if unknown:
        known = ", ".join(sorted(KNOWN_KEYS[kind])) or "none"
        raise PathError(f"path.{unknown[0]}", f"unknown key for kind {kind!r} (known: {known})")
    return PATH_KINDS[kind](params)
