"""The path tracker the law flies: the reference computation, compiled once per path.

:class:`CompiledPathTracker` does exactly what :class:`tracker.PathTracker` does — the same
warm-started Newton projection on σ's degree-5 Taylor polynomial (§V (13)), the same
implicit differentiation for π's derivatives, α = s(y) along the position's Taylor series
(§V (8), (14)) and the Jacobian rows Dφ (§V (15)) — but every piece of arithmetic runs as
straight-line float code that :mod:`jetcode` generated at start-up by tracing the
reference functions (σ, s and :func:`tracker.pi_rates`). The projection is Newton on σ
itself, warm-started from the last λ, rather than Newton on a degree-5 expansion that is
then re-expanded (the reference's two expansions and polynomial Newton per tick): the same
root to rounding, at a third of the cost. tests/contract/test_compiled.py holds the two trackers to
≤ 1e-9 relative on random states for every path kind.

Start-up: tracing and compiling takes a few milliseconds per path (``build_s``); the
path-independent kernels are made once per process.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from tfl_mav.control.path.jetcode import TRACE_LIB, Sym, TJet, TraceError
from tfl_mav.control.path.kernelgen import Kernel, compile_kernel
from tfl_mav.control.path.paths import Path
from tfl_mav.control.path.tracker import (
    MIN_TUBE_MARGIN,
    PathTracker,
    VirtualOutput,
    pi_rates,
)

__all__ = ["C_NAMES", "Y_NAMES", "CompiledPathTracker", "PathKernels", "compile_path",
           "make_tracker", "trace_pi", "traced_sqrt"]

_AXES = "xyz"
C_NAMES = [f"c{j}{a}" for j in range(6) for a in _AXES]          # σ⁽ʲ⁾/j!, j-major
Y_NAMES = [[f"{a}{k}" for k in range(5)] for a in _AXES]          # position Taylor rows
_FACT = (1.0, 1.0, 2.0, 6.0, 24.0)                                 # as Jet.derivatives
_NEWTON_ITERS = 20


@dataclass(frozen=True)
class PathKernels:
    """The compiled pieces of one path: σ's Taylor polynomial and s along y(t)."""

    sigma2: Kernel
    sigma5: Kernel
    s4: Kernel

    @property
    def build_s(self) -> float:
        return self.sigma2.build_s + self.sigma5.build_s + self.s4.build_s


def _rows(c: Sequence[Any]) -> list[tuple[Any, Any, Any]]:
    return [(c[3 * j], c[3 * j + 1], c[3 * j + 2]) for j in range(6)]


def _coeffs(x: Any, n: int) -> tuple[Any, ...]:
    """Coefficients of a traced result that may be a jet, a symbol or a constant."""
    return tuple(x.c) if type(x) is TJet else (x,) + (0.0,) * (n - 1)


def compile_path(path: Path, *, inline: bool = True) -> PathKernels:
    """Trace ``path`` into its kernels; :class:`TraceError` if its code cannot be traced.
    (``inline``: as :func:`kernelgen.compile_kernel`, False only to test that it changes
    nothing.)"""
    if path.source is not None:
        s_exprs, sig_exprs = path.source

        def s(x: Any, y: Any, z: Any) -> tuple[Any, ...]:
            env = {"x": x, "y": y, "z": z}
            return tuple(e(env, TRACE_LIB) for e in s_exprs)

        def sigma(lam: Any) -> tuple[Any, ...]:
            return tuple(e({"t": lam}, TRACE_LIB) for e in sig_exprs)
    else:
        s, sigma = path.s, path.sigma

    def trace_sigma(lam: list[Sym], order: int) -> list[Any]:
        comps = [_coeffs(v, order + 1)
                 for v in sigma(TJet((lam[0], 1.0) + (0.0,) * (order - 1)))]
        return [comps[i][j] for j in range(order + 1) for i in range(3)]

    def trace_s(x: list[Sym], y: list[Sym], z: list[Sym]) -> list[Any]:
        alpha = [_coeffs(a, 5) for a in s(TJet(x), TJet(y), TJet(z))]
        out = [a[k] * _FACT[k] for a in alpha for k in range(5)]
        y0 = (x[0], y[0], z[0])
        cols = []
        for axis in range(3):
            res = s(*(TJet((y0[i], 1.0 if i == axis else 0.0)) for i in range(3)))
            cols.append([_coeffs(r, 2)[1] for r in res])
        return out + [cols[axis][row] for row in range(2) for axis in range(3)]

    name = "".join(ch if ch.isalnum() else "_" for ch in path.kind)
    try:
        return PathKernels(
            compile_kernel(f"sigma2_{name}", [["lam"]], lambda lam: trace_sigma(lam, 2),
                           inline=inline),
            compile_kernel(f"sigma5_{name}", [["lam"]], lambda lam: trace_sigma(lam, 5),
                           inline=inline),
            compile_kernel(f"s4_{name}", Y_NAMES, trace_s, inline=inline))
    except (TraceError, ValueError, ZeroDivisionError, OverflowError, TypeError,
            AttributeError) as exc:
        raise TraceError(f"path kind {path.kind!r} cannot be compiled: {exc}") from exc


def traced_sqrt(x: Any) -> Any:
    """math.sqrt on a float, a run-time call on a traced symbol."""
    return x.tape.call("sqrt", x) if type(x) is Sym else math.sqrt(x)


def trace_pi(c: list[Sym], x: list[Sym], y: list[Sym], z: list[Sym],
             slope: list[Sym]) -> list[Any]:
    """π̇ … π⁽⁴⁾ traced from :func:`tracker.pi_rates` (inputs as :data:`C_NAMES`, the
    position's Taylor rows, the slope)."""
    p = pi_rates(_rows(c), [x, y, z], slope[0], traced_sqrt)
    # As Jet((π, p0, p1/2, p2/3, p3/4)).derivatives() in the reference.
    return [p[0], p[1] / 2.0 * 2.0, p[2] / 3.0 * 6.0, p[3] / 4.0 * 24.0]


@functools.cache
def _pi_kernel(inline: bool = True) -> Kernel:
    """π's rates (path independent: made once a process)."""
    return compile_kernel("pi_rates", [C_NAMES, *Y_NAMES, ["slope"]], trace_pi,
                          inline=inline)


def _arc(cp: Sequence[Any], cn: Sequence[Any], delta: Any,
         sqrt: Callable[[Any], Any] = math.sqrt) -> Any:
    """∫|σ'| dλ over [λ, λ + δ] by Simpson's rule: |σ'| at both ends from the expansions
    ``cp`` (at λ) and ``cn`` (at λ + δ), at the middle from ``cp``'s polynomial."""
    h = 0.5 * delta
    mx = cp[3] + h * (2.0 * cp[6] + h * (3.0 * cp[9] + h * (4.0 * cp[12] + h * 5.0 * cp[15])))
    my = cp[4] + h * (2.0 * cp[7] + h * (3.0 * cp[10] + h * (4.0 * cp[13] + h * 5.0 * cp[16])))
    mz = cp[5] + h * (2.0 * cp[8] + h * (3.0 * cp[11] + h * (4.0 * cp[14] + h * 5.0 * cp[17])))
    return delta / 6.0 * (sqrt(cp[3] * cp[3] + cp[4] * cp[4] + cp[5] * cp[5])
                          + 4.0 * sqrt(mx * mx + my * my + mz * mz)
                          + sqrt(cn[3] * cn[3] + cn[4] * cn[4] + cn[5] * cn[5]))


class CompiledPathTracker(PathTracker):
    """:class:`PathTracker` with every per-tick computation compiled (see module doc)."""

    def __init__(self, path: Path, kernels: PathKernels | None = None, *,
                 min_tube_margin: float = MIN_TUBE_MARGIN) -> None:
        super().__init__(path, min_tube_margin=min_tube_margin)
        self.kernels = kernels if kernels is not None else compile_path(path)
        self._sigma2 = self.kernels.sigma2.fn
        self._sigma5 = self.kernels.sigma5.fn
        self._s4 = self.kernels.s4.fn
        self._pi = _pi_kernel().fn
        self._expansion: tuple[float, tuple[float, ...]] | None = None   # (λ, σ5(λ))
        self._lam_prev: float | None = None       # the λ before, for the warm start

    def _project_compiled(self, y0: tuple[float, float, float]) -> tuple[float, ...] | None:
        """Move λ to the closest point of ``y0`` (eq. (13)); σ's coefficients there.

        Newton on g(λ) = ⟨y − σ(λ), σ'(λ)⟩ with the compiled σ, σ', σ'' (a few dozen
        operations a step), warm-started from the last two λ. As in the reference, the
        projection is lost when g' ≥ 0 (not a closest point) or the root is more than 0.05
        from the warm start. A step below 1e-9 leaves an error ~ step² (quadratic
        convergence): the root to rounding. π advances by Simpson's rule on |σ'|.
        """
        lam0 = self.lam
        assert lam0 is not None
        prev = self._expansion
        # Warm start extrapolated from the last two solutions: saves a Newton step.
        fresh = prev is not None and prev[0] == lam0   # λ not moved from outside
        lam = 2.0 * lam0 - self._lam_prev if fresh and self._lam_prev is not None else lam0
        yx, yy, yz = y0
        sigma2 = self._sigma2
        for _ in range(_NEWTON_ITERS):
            c0x, c0y, c0z, c1x, c1y, c1z, c2x, c2y, c2z = sigma2((lam,))
            ex, ey, ez = yx - c0x, yy - c0y, yz - c0z
            dg = 2.0 * (ex * c2x + ey * c2y + ez * c2z) - (c1x * c1x + c1y * c1y + c1z * c1z)
            if not dg < 0.0:
                return None
            step = -(ex * c1x + ey * c1y + ez * c1z) / dg
            lam += step
            if not abs(lam - lam0) <= 0.05:
                return None
            if abs(step) < 1e-9:
                break
        else:
            return None
        cp = prev[1] if fresh else self._sigma5((lam0,))
        c = self._sigma5((lam,))
        self._arc_m += _arc(cp, c, lam - lam0)
        self._lam_prev = lam0
        self.lam = lam
        self._expansion = (lam, c)
        return c

    def virtual_output(self, taylor: Sequence[Sequence[float]]) -> VirtualOutput:
        """(α, π) derivatives and Dφ along the position's Taylor rows (x, y, z), each
        (y, ẏ, ÿ/2, y⃛/6, y⁽⁴⁾/24) in the paper frame (m)."""
        tx, ty, tz = taylor
        y0 = (tx[0], ty[0], tz[0])
        if not math.isfinite(sum(tx) + sum(ty) + sum(tz)):
            return self._lost_vo(y0, "non-finite state")
        try:
            if self.lam is None:
                lam, ok = self._newton(y0, self._global_lam(y0))
                if not ok or not math.isfinite(lam):
                    return self._lost_vo(y0, "closest-point search did not converge")
                self.lam = self._arc_lam = lam
            c = self._project_compiled(y0)
            if c is None:
                return self._lost_vo(y0, "closest-point search did not converge")
            e0x, e0y, e0z = y0[0] - c[0], y0[1] - c[1], y0[2] - c[2]
            c1x, c1y, c1z = c[3], c[4], c[5]
            s1sq = c1x ** 2 + c1y ** 2 + c1z ** 2
            slope = -s1sq + 2.0 * (e0x * c[6] + e0y * c[7] + e0z * c[8])
            margin = -slope / s1sq if s1sq > 0.0 else 0.0
            distance = math.sqrt(e0x ** 2 + e0y ** 2 + e0z ** 2)
            if margin < self.min_tube_margin:
                return self._lost_vo(
                    y0, f"distance {distance:.3f} m near the radius of curvature "
                        f"(projection margin {margin:.2f})", self.lam, distance)
            p1, p2, p3, p4 = self._pi(c, tx, ty, tz, (slope,))
            a = self._s4(tx, ty, tz)
        except (ValueError, ZeroDivisionError, OverflowError) as exc:
            return self._lost_vo(y0, f"path evaluation failed: {exc}")
        k = math.sqrt(s1sq) / -slope
        return VirtualOutput(a[0:5], a[5:10], (self._arc_m, p1, p2, p3, p4),
                             (a[10:13], a[13:16], (k * c1x, k * c1y, k * c1z)),
                             self.lam, distance, True)

    def _lost_vo(self, y0: Sequence[float], reason: str, lam: float = math.nan,
                 distance: float = math.nan) -> VirtualOutput:
        zero = (0.0, 0.0, 0.0, 0.0, 0.0)
        ident = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
        return VirtualOutput(zero, zero, zero, ident, lam, distance, False, reason)


def make_tracker(path: Path, compiled: bool = True) -> tuple[PathTracker, str]:
    """The tracker the law flies and a note: compiled when the path's code traces, else the
    reference jets (the note says why)."""
    if not compiled:
        return PathTracker(path), "reference jets"
    try:
        return CompiledPathTracker(path), "compiled"
    except TraceError as exc:
        return PathTracker(path), f"reference jets ({exc})"
