"""The path tracker the law flies: the reference computation, compiled once per path.

:func:`compile_path` traces a path's code (σ, s) and :func:`tracker.pi_rates` once at
start-up into straight-line float kernels (:mod:`jetcode`, :mod:`kernelgen`): σ, σ', σ''/2
at λ; σ's degree-5 expansion; α = s(y) to order 4 and its gradients along the position's
Taylor rows (§V (8), (14), (15)); π's rates. :class:`CompiledPathTracker` holds the state of
:func:`projection.project` on those kernels — Newton on σ itself, warm-started from the last
λ, rather than Newton on a degree-5 expansion that is then re-expanded (the reference's two
expansions and polynomial Newton per tick): the same root to rounding, at a third of the
cost. tests/contract/test_compiled.py holds it to :class:`tracker.PathTracker` to ≤ 1e-9
relative on random states for every path kind.

Start-up: tracing and compiling takes a few milliseconds per path (``build_s``); the
path-independent kernels are made once per process.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from tfl_mav.control.path.jetcode import TRACE_LIB, Sym, TJet, TraceError
from tfl_mav.control.path.kernelgen import Kernel, compile_kernel
from tfl_mav.control.path.paths import Path
from tfl_mav.control.path.projection import (
    PATH_START,
    VO,
    Kernels,
    expansion,
    lost_reason,
    project,
)
from tfl_mav.control.path.tracker import (
    MIN_TUBE_MARGIN,
    PathTracker,
    VirtualOutput,
    closest_lam,
    pi_rates,
)

__all__ = ["C_NAMES", "Y_NAMES", "CompiledPathTracker", "PathKernels", "compile_path",
           "make_tracker", "pi_kernel", "trace_pi", "traced_sqrt"]

_AXES = "xyz"
C_NAMES = [f"c{j}{a}" for j in range(6) for a in _AXES]          # σ⁽ʲ⁾/j!, j-major
Y_NAMES = [[f"{a}{k}" for k in range(5)] for a in _AXES]          # position Taylor rows
_FACT = (1.0, 1.0, 2.0, 6.0, 24.0)                                 # as Jet.derivatives


@dataclass(frozen=True)
class PathKernels:
    """The compiled pieces of one path: σ's Taylor polynomial and s along y(t)."""

    sigma2: Kernel
    sigma5: Kernel
    s4: Kernel

    @property
    def build_s(self) -> float:
        return self.sigma2.build_s + self.sigma5.build_s + self.s4.build_s


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
    p = pi_rates(expansion(c), [x, y, z], slope[0], traced_sqrt)
    # As Jet((π, p0, p1/2, p2/3, p3/4)).derivatives() in the reference.
    return [p[0], p[1] / 2.0 * 2.0, p[2] / 3.0 * 6.0, p[3] / 4.0 * 24.0]


@functools.cache
def pi_kernel(inline: bool = True) -> Kernel:
    """The kernel of π's rates (:func:`trace_pi`; path independent: made once a process);
    ``inline`` False: one line per operation."""
    return compile_kernel("pi_rates", [C_NAMES, *Y_NAMES, ["slope"]], trace_pi,
                          inline=inline)


class CompiledPathTracker(PathTracker):
    """:class:`PathTracker` with every per-tick computation compiled: the holder of
    :func:`projection.project`'s state on this path's kernels (see module doc)."""

    def __init__(self, path: Path, kernels: PathKernels | None = None, *,
                 min_tube_margin: float = MIN_TUBE_MARGIN) -> None:
        self.state = PATH_START
        super().__init__(path, min_tube_margin=min_tube_margin)
        self.kernels = kernels if kernels is not None else compile_path(path)
        k = self.kernels
        # What the projection step (and the law's step, which calls it) is given.
        self.projection_kernels = Kernels(k.sigma2.fn, k.sigma5.fn, k.s4.fn, pi_kernel().fn)
        self.failure = ""       # the path's last error, in words (VO.FAILED)

    @property   # type: ignore[override]
    def lam(self) -> float | None:
        """The path parameter of the closest point (None: none yet)."""
        return self.state.lam if self.state.has_lam else None

    @lam.setter
    def lam(self, value: float | None) -> None:
        self.state = (self.state._replace(has_lam=False) if value is None
                      else self.state._replace(has_lam=True, lam=float(value)))

    def start(self, y0: Sequence[float]) -> tuple[float, bool, bool]:
        """A global search for the closest point of ``y0`` (m), for a state without one:
        (λ, converged, the path raised — :attr:`failure` says what)."""
        try:
            lam, ok = closest_lam(self.path, y0)
        except (ValueError, ZeroDivisionError, OverflowError) as exc:
            self.failure = str(exc)
            return 0.0, False, True
        return lam, bool(ok), False

    def virtual_output(self, taylor: Sequence[Sequence[float]]) -> VirtualOutput:
        """(α, π) derivatives and Dφ along the position's Taylor rows (x, y, z), each
        (y, ẏ, ÿ/2, y⃛/6, y⁽⁴⁾/24) in the paper frame (m)."""
        rows = tuple(tuple(r) for r in taylor)
        lam_start, ok, failed = 0.0, False, False
        if not self.state.has_lam and math.isfinite(sum(rows[0]) + sum(rows[1])
                                                    + sum(rows[2])):
            lam_start, ok, failed = self.start((rows[0][0], rows[1][0], rows[2][0]))
        args = (self.projection_kernels, self.min_tube_margin, self.state, rows, lam_start, ok)
        try:
            vo, self.state = project(*args, failed)
        except (ValueError, ZeroDivisionError, OverflowError) as exc:
            self.failure = str(exc)
            vo, self.state = project(*args, True)
        code, xi1, xi2, eta, jac, lam, distance, margin = vo
        if code != VO.OK:
            return VirtualOutput(xi1, xi2, eta, jac, lam, distance, False,
                                 lost_reason(code, distance, margin, self.failure))
        return VirtualOutput(xi1, xi2, eta, jac, lam, distance, True)


def make_tracker(path: Path, compiled: bool = True) -> tuple[PathTracker, str]:
    """The tracker the law flies and a note: compiled when the path's code traces, else the
    reference jets (the note says why)."""
    if not compiled:
        return PathTracker(path), "reference jets"
    try:
        return CompiledPathTracker(path), "compiled"
    except TraceError as exc:
        return PathTracker(path), f"reference jets ({exc})"
