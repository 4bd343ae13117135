"""Truncated Taylor arithmetic ("jets") for the TFL virtual output and its derivatives.

The TFL law needs φ(y(t)) and its time derivatives up to order 4 for any path written as
ordinary code (``s``, ``σ``) or as a scenario expression. Evaluating that code on jets
instead of floats gives all derivatives exactly (to rounding) in one pass: a jet of order N
holds the Taylor coefficients ``c[k] = f⁽ᵏ⁾(t₀)/k!`` for k = 0..N, and every operation below
is the truncated power-series version of the float one (standard recurrences, e.g. Griewank
& Walther, *Evaluating Derivatives*, ch. 13).

These jets are the *reference*: the law's fast path (:mod:`tfl_mav.control.path.jetcode`) runs
the same recurrences (:mod:`series`) once at start-up on symbols and compiles them to
straight-line float code, and is tested against this class. Coefficients are plain float
tuples (numpy is slower for 5 elements), the class has ``__slots__`` and nothing is validated
per operation. Jets of different orders combine to the smaller order (``zip`` truncation).

Functions (``sin``, ``cos``, ..., ``step``) accept jets, plain floats (via :mod:`math`) and
numpy arrays (via numpy, for vectorised sampling of paths); :data:`JET_LIB` maps exactly the
names of :data:`tfl_mav.expr.FUNCTION_NAMES` to them so a compiled expression runs on jets:
``expr({"x": jx, "y": jy, "z": jz}, JET_LIB)``. Piecewise functions (``abs``, ``min``,
``max``, ``clip``, ``step``) follow the branch selected by the value ``c[0]``.

Domain errors mirror :mod:`math`: ``ValueError`` (log of a non-positive value, sqrt at or
below 0, fractional power of a negative base), ``ZeroDivisionError`` (division by a jet whose
value is 0). Functions also hand a :class:`SymbolicJet` to its own method.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Callable, Iterable, Mapping, Sequence
from types import MappingProxyType
from typing import Any

import numpy as np

from tfl_mav.control.path.series import (
    atan_series,
    div_series,
    exp_series,
    log_series,
    mul,
    pow_series,
    sincos_series,
    sqrt_series,
    tan_like_series,
)

__all__ = [
    "JET_LIB",
    "Jet",
    "SymbolicJet",
    "abs_",
    "atan",
    "clip",
    "cos",
    "exp",
    "log",
    "max_",
    "min_",
    "sin",
    "sqrt",
    "step",
    "tan",
    "tanh",
    "value_of",
]

_add = operator.add
_sub = operator.sub
_REAL = (int, float)
_mul = mul


class Jet:
    """Truncated Taylor series of order N: ``c[k] = f⁽ᵏ⁾(t₀)/k!`` for k = 0..N.

    ``c`` is a tuple of floats of length N+1. Build one with :meth:`variable` (the identity
    t ↦ x₀ + (t − t₀)), :meth:`constant`, :meth:`from_derivatives`, or ``Jet(coefficients)``.
    """

    __slots__ = ("c",)

    c: tuple[float, ...]

    def __init__(self, c: tuple[float, ...]) -> None:
        self.c = c

    # ----- construction and inspection -------------------------------------------------
    @classmethod
    def variable(cls, x0: float, order: int = 4) -> Jet:
        """The independent variable at ``x0``: coefficients (x0, 1, 0, ..., 0)."""
        return cls((float(x0), 1.0) + (0.0,) * (order - 1)) if order >= 1 else cls((x0,))

    @classmethod
    def constant(cls, value: float, order: int = 4) -> Jet:
        """A constant: coefficients (value, 0, ..., 0)."""
        return cls((float(value),) + (0.0,) * order)

    @classmethod
    def from_derivatives(cls, derivatives: Sequence[float]) -> Jet:
        """From ``[f, f', f'', ...]`` (derivatives, not Taylor coefficients)."""
        return cls(tuple(float(d) / math.factorial(k) for k, d in enumerate(derivatives)))

    @classmethod
    def from_coefficients(cls, coefficients: Iterable[float]) -> Jet:
        """From Taylor coefficients ``[f, f', f''/2, f'''/6, ...]`` (converted to floats)."""
        return cls(tuple(float(x) for x in coefficients))

    @property
    def order(self) -> int:
        return len(self.c) - 1

    @property
    def value(self) -> float:
        """f(t₀) = c[0]."""
        return self.c[0]

    def derivatives(self) -> list[float]:
        """``[f, f', f'', ...]`` at t₀, i.e. ``c[k]·k!``."""
        out = []
        fact = 1.0
        for k, ck in enumerate(self.c):
            if k > 1:
                fact *= k
            out.append(ck * fact)
        return out

    def __repr__(self) -> str:
        return "Jet(" + ", ".join(f"{x:.6g}" for x in self.c) + ")"

    # ----- arithmetic -------------------------------------------------------------------
    def __neg__(self) -> Jet:
        return Jet(tuple([-x for x in self.c]))

    def __pos__(self) -> Jet:
        return self

    def __add__(self, o: Any) -> Jet:
        if type(o) is Jet:
            return Jet(tuple(map(_add, self.c, o.c)))
        c = self.c
        return Jet((c[0] + o, *c[1:]))

    __radd__ = __add__

    def __sub__(self, o: Any) -> Jet:
        if type(o) is Jet:
            return Jet(tuple(map(_sub, self.c, o.c)))
        c = self.c
        return Jet((c[0] - o, *c[1:]))

    def __rsub__(self, o: Any) -> Jet:
        c = self.c
        return Jet((o - c[0], *[-x for x in c[1:]]))

    def __mul__(self, o: Any) -> Jet:
        if type(o) is Jet:
            return Jet(_mul(self.c, o.c))
        return Jet(tuple([x * o for x in self.c]))

    __rmul__ = __mul__

    def __truediv__(self, o: Any) -> Jet:
        if type(o) is Jet:
            return Jet(_div(self.c, o.c))
        inv = 1.0 / o
        return Jet(tuple([x * inv for x in self.c]))

    def __rtruediv__(self, o: Any) -> Jet:
        b = self.c
        return Jet(_div((o,) + (0.0,) * (len(b) - 1), b))

    def __pow__(self, p: Any) -> Jet:
        if type(p) is Jet:
            return (p * self.log()).exp()
        return Jet(_pow(self.c, p))

    def __rpow__(self, base: Any) -> Jet:
        if base <= 0:
            raise ValueError(f"base ** jet needs a positive base, got {base!r}")
        return (self * math.log(base)).exp()

    def __abs__(self) -> Jet:
        return -self if self.c[0] < 0.0 else self

    # ----- elementary functions (value by math, coefficients by series) ----------------
    def sincos(self) -> tuple[Jet, Jet]:
        """(sin f, cos f) by the coupled recurrence s' = f'c, c' = −f's."""
        a = self.c
        s, c = sincos_series(a, math.sin(a[0]), math.cos(a[0]))
        return Jet(s), Jet(c)

    def sin(self) -> Jet:
        return self.sincos()[0]

    def cos(self) -> Jet:
        return self.sincos()[1]

    def tan(self) -> Jet:
        """tan f from t' = f'(1 + t²)."""
        return Jet(tan_like_series(self.c, math.tan(self.c[0]), 1.0))

    def tanh(self) -> Jet:
        """tanh f from t' = f'(1 − t²)."""
        return Jet(tan_like_series(self.c, math.tanh(self.c[0]), -1.0))

    def exp(self) -> Jet:
        """exp f from b' = f'b."""
        return Jet(exp_series(self.c, math.exp(self.c[0])))

    def log(self) -> Jet:
        """log f from f·b' = f'; needs f(t₀) > 0."""
        a0 = self.c[0]
        if not a0 > 0.0:
            raise ValueError(f"log of a jet with value {a0!r} <= 0")
        return Jet(log_series(self.c, math.log(a0)))

    def sqrt(self) -> Jet:
        """sqrt f from b² = f; needs f(t₀) > 0 (derivatives are unbounded at 0)."""
        a = self.c
        a0 = a[0]
        if not a0 > 0.0:
            if a0 == 0.0 and len(a) == 1:
                return Jet((0.0,))
            raise ValueError(f"sqrt of a jet with value {a0!r} <= 0 has no derivatives")
        return Jet(sqrt_series(a, math.sqrt(a0)))

    def atan(self) -> Jet:
        """atan f from b'·(1 + f²) = f'."""
        return Jet(atan_series(self.c, math.atan(self.c[0])))


# ----- coefficient-level kernels with domain checks (tuples in, tuple out) -----------------
def _div(a: tuple[float, ...], b: tuple[float, ...]) -> tuple[float, ...]:
    """Quotient a/b; b₀ must not be 0."""
    b0 = b[0]
    if b0 == 0.0:
        raise ZeroDivisionError("division by a jet whose value is 0")
    return div_series(a, b, 1.0 / b0)


def _pow(a: tuple[float, ...], p: float) -> tuple[float, ...]:
    """a**p for a real exponent p.

    Uses the recurrence from a·b' = p·a'·b when a₀ ≠ 0, and repeated products for
    non-negative integer p when a₀ = 0 (e.g. ``x**2`` at x = 0, common in expressions where
    constants arrive as floats).
    """
    n = len(a)
    a0 = a[0]
    integral = float(p).is_integer()
    if integral:
        ip = int(p)
        if ip == 0:
            return (1.0,) + (0.0,) * (n - 1)
        if ip == 1:
            return a
        if ip == 2:
            return _mul(a, a)
        if a0 == 0.0:
            if ip < 0:
                raise ZeroDivisionError("negative power of a jet whose value is 0")
            result = a
            for _ in range(ip - 1):
                result = _mul(result, a)
            return result
    elif a0 <= 0.0:
        raise ValueError(f"jet ** {p!r} needs a positive value, got {a0!r}")
    return pow_series(a, p, a0**p if integral else math.pow(a0, p), 1.0 / a0)


# ----- functions on Jet | float | ndarray --------------------------------------------------
class SymbolicJet:
    """Base of jets whose coefficients are symbols, not floats (:mod:`jetcode` traces paths
    with them); the smooth functions below and ``abs_`` hand such a jet to its own method."""

    __slots__ = ()


Number = Jet | float


def value_of(x: Any) -> Any:
    """The value of a jet (``c[0]``) or the number itself."""
    return x.c[0] if type(x) is Jet else x


def sin(x: Any) -> Any:
    if type(x) is Jet:
        return x.sincos()[0]
    if isinstance(x, _REAL):
        return math.sin(x)
    if isinstance(x, SymbolicJet):
        return x.sin()
    return np.sin(x)


def cos(x: Any) -> Any:
    if type(x) is Jet:
        return x.sincos()[1]
    if isinstance(x, _REAL):
        return math.cos(x)
    if isinstance(x, SymbolicJet):
        return x.cos()
    return np.cos(x)


def tan(x: Any) -> Any:
    if type(x) is Jet:
        return x.tan()
    if isinstance(x, _REAL):
        return math.tan(x)
    if isinstance(x, SymbolicJet):
        return x.tan()
    return np.tan(x)


def exp(x: Any) -> Any:
    if type(x) is Jet:
        return x.exp()
    if isinstance(x, _REAL):
        return math.exp(x)
    if isinstance(x, SymbolicJet):
        return x.exp()
    return np.exp(x)


def log(x: Any) -> Any:
    if type(x) is Jet:
        return x.log()
    if isinstance(x, _REAL):
        return math.log(x)
    if isinstance(x, SymbolicJet):
        return x.log()
    return np.log(x)


def sqrt(x: Any) -> Any:
    if type(x) is Jet:
        return x.sqrt()
    if isinstance(x, _REAL):
        return math.sqrt(x)
    if isinstance(x, SymbolicJet):
        return x.sqrt()
    return np.sqrt(x)


def atan(x: Any) -> Any:
    if type(x) is Jet:
        return x.atan()
    if isinstance(x, _REAL):
        return math.atan(x)
    if isinstance(x, SymbolicJet):
        return x.atan()
    return np.arctan(x)


def tanh(x: Any) -> Any:
    if type(x) is Jet:
        return x.tanh()
    if isinstance(x, _REAL):
        return math.tanh(x)
    if isinstance(x, SymbolicJet):
        return x.tanh()
    return np.tanh(x)


def abs_(x: Any) -> Any:
    """|x|; a jet at exactly 0 keeps its own derivatives (right-hand branch)."""
    if type(x) is Jet:
        return -x if x.c[0] < 0.0 else x
    if isinstance(x, _REAL):
        return abs(x)
    if isinstance(x, SymbolicJet):
        return abs(x)
    return np.abs(x)


def min_(a: Any, b: Any) -> Any:
    """The argument with the smaller value (a on ties), derivatives included."""
    if type(a) is Jet or type(b) is Jet:
        return a if value_of(a) <= value_of(b) else b
    if isinstance(a, _REAL) and isinstance(b, _REAL):
        return a if a <= b else b
    return np.minimum(a, b)


def max_(a: Any, b: Any) -> Any:
    """The argument with the larger value (a on ties), derivatives included."""
    if type(a) is Jet or type(b) is Jet:
        return a if value_of(a) >= value_of(b) else b
    if isinstance(a, _REAL) and isinstance(b, _REAL):
        return a if a >= b else b
    return np.maximum(a, b)


def clip(x: Any, lo: Any, hi: Any) -> Any:
    """min(max(x, lo), hi), branch chosen by values."""
    return min_(max_(x, lo), hi)


def step(x: Any) -> Any:
    """Heaviside step (1 for x ≥ 0, else 0) as a constant: its derivatives are 0."""
    if type(x) is Jet:
        return 1.0 if x.c[0] >= 0.0 else 0.0
    if isinstance(x, _REAL):
        return 1.0 if x >= 0.0 else 0.0
    return np.where(np.asarray(x) >= 0.0, 1.0, 0.0)


#: Function library for :class:`tfl_mav.expr.Expr` on jets (also floats and numpy arrays).
JET_LIB: Mapping[str, Callable[..., Any]] = MappingProxyType(
    {
        "sin": sin,
        "cos": cos,
        "tan": tan,
        "exp": exp,
        "log": log,
        "sqrt": sqrt,
        "atan": atan,
        "tanh": tanh,
        "abs": abs_,
        "min": min_,
        "max": max_,
        "clip": clip,
        "step": step,
    }
)
