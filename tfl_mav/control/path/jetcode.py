"""Jets compiled to straight-line float code, once per path, at start-up.

The reference jets (:mod:`jets`) build tuples and objects for every operation of every
tick, yet a path is fixed for a flight. So the path's own code is run *once* on symbolic
jets (:class:`TJet`), whose coefficients are :class:`Sym` names on a :class:`Tape`: every
operation the reference would perform on floats is recorded as one assignment instead, and
the tape becomes the body of a Python function (:mod:`kernelgen` compiles it). The
recurrences are the very ones of :mod:`series` (the reference uses them too), so the
compiled code performs the reference's floating-point operations in the reference's order;
the tape only drops operations whose result is known exactly (``x·1``, ``x·0``, ``x + 0``)
and records an operation on the same operands once (common subexpressions, e.g. ``sin λ``
shared by all orders). Hence the compiled kernels agree with the jets bit for bit in
practice, and to rounding always.

A value-dependent branch (``abs``, ``min``, ``max``, ``clip``, ``step`` in a scenario
expression) becomes a run-time select on the value, exactly as the jets choose. Path code
that compares a traced value any other way raises :class:`TraceError`; the caller then keeps
the reference jets for that path.

Kernels made here (by :mod:`compiled`; ``c[j]`` = σ⁽ʲ⁾(λ)/j!, ``y[i][k]`` = the position's
Taylor coefficients):

* ``sigma2(λ)``, ``sigma5(λ)`` → σ's Taylor coefficients to order 2 (Newton) and 5
  (j-major), for the projection (§V (13));
* ``s4(y)`` → α1, α2 and their derivatives to order 4, and ∂s/∂y (§V (8), (14), (15));
* ``pi_rates(c, y, slope)`` → π̇ … π⁽⁴⁾ from the implicit projection condition (§V (13)),
  traced from the reference :func:`tracker.pi_rates`, path independent.

The generated source holds only temporaries, the kernel's inputs, float literals (``repr``),
arithmetic, comparisons and the whitelisted math functions: scenario text never reaches
:func:`compile` (expressions are parsed and checked by :mod:`tfl_mav.expr` and run here as
closures), which tests/contract/test_compiled.py checks.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from types import MappingProxyType
from typing import Any

from tfl_mav.control.path.jets import SymbolicJet
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

__all__ = ["TRACE_LIB", "Sym", "TJet", "Tape", "TraceError"]


class TraceError(ValueError):
    """The traced code did something that cannot become straight-line code."""


_FUNCS: dict[str, Callable[..., float]] = {
    "sin": math.sin, "cos": math.cos, "tan": math.tan, "exp": math.exp, "log": math.log,
    "sqrt": math.sqrt, "atan": math.atan, "tanh": math.tanh, "pow": math.pow, "abs": abs,
}


def _lit(x: Any) -> str:
    """Source text of a constant operand (ints become floats, as Python's mixed arithmetic)."""
    v = float(x)
    if not math.isfinite(v):
        raise TraceError(f"non-finite constant {v!r} in traced code")
    return f"({v!r})" if v < 0.0 or (v == 0.0 and math.copysign(1.0, v) < 0.0) else repr(v)




class Tape:
    """Straight-line code being recorded: one assignment per distinct operation."""

    def __init__(self, prefix: str = "t") -> None:
        self.prefix = prefix        # temporaries are named prefix0, prefix1, …
        self.lines: list[str] = []
        self._memo: dict[str, Sym] = {}
        self._negated: dict[str, Sym] = {}
        self._scaled: dict[str, tuple[Sym, float]] = {}   # name → (a, c): the value a · c

    def input(self, name: str) -> Sym:
        return Sym(self, name)

    def emit(self, expr: str) -> Sym:
        """The symbol holding ``expr``: recorded once, reused when met again."""
        sym = self._memo.get(expr)
        if sym is None:
            sym = Sym(self, f"{self.prefix}{len(self.lines)}")
            self.lines.append(f"    {sym.name} = {expr}")
            self._memo[expr] = sym
        return sym

    def negation_of(self, a: Sym) -> Sym | None:
        """The symbol ``a`` was recorded as the negation of (None: ``a`` is no negation)."""
        return self._negated.get(a.name)

    def neg(self, a: Sym) -> Sym:
        back = self._negated.get(a.name)
        if back is not None:
            return back
        scaled = self._scaled.get(a.name)
        # −(b·c) = b·(−c) exactly (IEEE rounding is symmetric): one operation, not two.
        out = (self.scale(scaled[0], -scaled[1]) if scaled is not None
               else self.emit(f"-{a.name}"))
        self._negated[out.name] = a
        return out

    def scale(self, a: Sym, c: float) -> Sym:
        """a · c for a constant c, folding a negated ``a`` into the constant:
        (−b)·c = b·(−c) exactly."""
        base = self._negated.get(a.name)
        if base is not None:
            a, c = base, -c
        out = self.emit(f"{a.name} * {_lit(c)}")
        self._scaled.setdefault(out.name, (a, c))
        return out

    def call(self, fn: str, *args: Any) -> Any:
        """fn(*args) at run time; folded now when every argument is a constant."""
        if not any(type(a) is Sym for a in args):
            return _constant_call(fn, *args)
        return self.emit(f"_{fn}({', '.join(_text(a) for a in args)})")

    def compare(self, op: str, a: Any, b: Any) -> Any:
        """``a op b`` as a run-time boolean (or a Python bool for two constants)."""
        if type(a) is not Sym and type(b) is not Sym:
            return {"<": a < b, "<=": a <= b, ">=": a >= b}[op]
        return self.emit(f"{_text(a)} {op} {_text(b)}")

    def select(self, cond: Any, a: Any, b: Any) -> Any:
        """``a if cond else b``, chosen at run time unless ``cond`` is a constant."""
        if type(cond) is bool:
            return a if cond else b
        if _text(a) == _text(b):
            return a
        return self.emit(f"{_text(a)} if {cond.name} else {_text(b)}")


def _power_of_two(c: Any) -> bool:
    """c = ±2ᵏ with 1/c a normal float (so x / c = x · (1/c) exactly)."""
    c = float(c)
    return (math.isfinite(c) and c != 0.0 and math.frexp(c)[0] in (0.5, -0.5)
            and abs(1.0 / c) >= 2.2250738585072014e-308 and math.isfinite(1.0 / c))


def _text(x: Any) -> str:
    return x.name if type(x) is Sym else _lit(x)


def _constant_call(fn: str, *args: Any) -> float:
    try:
        return float(_FUNCS[fn](*args))
    except (ValueError, ZeroDivisionError, OverflowError) as exc:
        raise TraceError(f"{fn}{args!r} fails on every call: {exc}") from None


class Sym:
    """A float known only at run time: the name of a local in the generated code."""

    __slots__ = ("name", "tape")

    def __init__(self, tape: Tape, name: str) -> None:
        self.tape = tape
        self.name = name

    def __repr__(self) -> str:
        return f"Sym({self.name})"

    # Only these folds are exact for every finite operand.
    # A negated operand is folded where that is exact: x + (−b) = x − b, x − (−b) = x + b,
    # (−b)·c = b·(−c), and x / 2ᵏ = x · 2⁻ᵏ (the same real number, so the same rounding).
    def __add__(self, o: Any) -> Any:
        if type(o) is TJet:
            return NotImplemented
        if type(o) is not Sym:
            if o == 0.0:
                return self
        else:
            base = self.tape.negation_of(o)
            if base is not None:
                return self.tape.emit(f"{self.name} - {base.name}")
            base = self.tape.negation_of(self)
            if base is not None:
                return self.tape.emit(f"{o.name} - {base.name}")
        return self.tape.emit(f"{self.name} + {_text(o)}")

    def __radd__(self, o: Any) -> Any:
        if o == 0.0:
            return self
        return self.tape.emit(f"{_lit(o)} + {self.name}")

    def __sub__(self, o: Any) -> Any:
        if type(o) is TJet:
            return NotImplemented
        if type(o) is not Sym:
            if o == 0.0:
                return self
        else:
            base = self.tape.negation_of(o)
            if base is not None:
                return self.tape.emit(f"{self.name} + {base.name}")
        return self.tape.emit(f"{self.name} - {_text(o)}")

    def __rsub__(self, o: Any) -> Any:
        if o == 0.0:
            return self.tape.neg(self)
        base = self.tape.negation_of(self)
        if base is not None:
            return self.tape.emit(f"{_lit(o)} + {base.name}")
        return self.tape.emit(f"{_lit(o)} - {self.name}")

    def __mul__(self, o: Any) -> Any:
        if type(o) is TJet:
            return NotImplemented
        if type(o) is not Sym:
            if o == 1.0:
                return self
            if o == 0.0:
                return 0.0
            if o == -1.0:
                return self.tape.neg(self)
            return self.tape.scale(self, float(o))
        return self.tape.emit(f"{self.name} * {_text(o)}")

    def __rmul__(self, o: Any) -> Any:
        if o == 1.0:
            return self
        if o == 0.0:
            return 0.0
        if o == -1.0:
            return self.tape.neg(self)
        return self.tape.scale(self, float(o))

    def __truediv__(self, o: Any) -> Any:
        if type(o) is TJet:
            return NotImplemented
        if type(o) is not Sym:
            if o == 1.0:
                return self
            if _power_of_two(o):
                return self.tape.scale(self, 1.0 / o)
            base = self.tape.negation_of(self)
            if base is not None:
                return self.tape.emit(f"{base.name} / {_lit(-o)}")
        return self.tape.emit(f"{self.name} / {_text(o)}")

    def __pow__(self, o: Any) -> Any:
        if type(o) is not int:
            return NotImplemented   # only x ** 2 and the like: float powers go through pow
        return self.tape.emit(f"{self.name} ** {o}")

    def __rtruediv__(self, o: Any) -> Any:
        return self.tape.emit(f"{_lit(o)} / {self.name}")

    def __neg__(self) -> Sym:
        return self.tape.neg(self)

    def __pos__(self) -> Sym:
        return self

    def _branch(self, *_: Any) -> bool:
        raise TraceError("the path code branches on a traced value; only abs/min/max/clip/"
                         "step in an expression can be compiled")

    __lt__ = __le__ = __gt__ = __ge__ = __bool__ = __float__ = _branch  # type: ignore[assignment]


def _tape_of(*xs: Any) -> Tape:
    for x in xs:
        if type(x) is Sym:
            return x.tape
        if type(x) is TJet:
            for c in x.c:
                if type(c) is Sym:
                    return c.tape
    raise TraceError("no traced value among the operands")


def _fn(name: str, x: Any) -> Any:
    """Value-level function of a constant or a symbol."""
    if type(x) is Sym:
        return x.tape.call(name, x)
    return _constant_call(name, x)


class TJet(SymbolicJet):
    """A jet whose coefficients are :class:`Sym` or constants; mirrors :class:`jets.Jet`."""

    __slots__ = ("c",)

    def __init__(self, c: Sequence[Any]) -> None:
        self.c = tuple(c)

    def __neg__(self) -> TJet:
        return TJet([-x for x in self.c])

    def __pos__(self) -> TJet:
        return self

    def __add__(self, o: Any) -> TJet:
        if type(o) is TJet:
            return TJet([a + b for a, b in zip(self.c, o.c, strict=False)])
        return TJet((self.c[0] + o, *self.c[1:]))

    __radd__ = __add__

    def __sub__(self, o: Any) -> TJet:
        if type(o) is TJet:
            return TJet([a - b for a, b in zip(self.c, o.c, strict=False)])
        return TJet((self.c[0] - o, *self.c[1:]))

    def __rsub__(self, o: Any) -> TJet:
        return TJet((o - self.c[0], *[-x for x in self.c[1:]]))

    def __mul__(self, o: Any) -> TJet:
        if type(o) is TJet:
            return TJet(mul(self.c, o.c))
        return TJet([x * o for x in self.c])

    __rmul__ = __mul__

    def __truediv__(self, o: Any) -> TJet:
        if type(o) is TJet:
            return TJet(div_series(self.c, o.c, 1.0 / o.c[0]))
        inv = 1.0 / o
        return TJet([x * inv for x in self.c])

    def __rtruediv__(self, o: Any) -> TJet:
        b = self.c
        return TJet(div_series((o,) + (0.0,) * (len(b) - 1), b, 1.0 / b[0]))

    def __pow__(self, p: Any) -> TJet:
        if type(p) is TJet:
            return (p * self.log()).exp()
        if type(p) is Sym:
            raise TraceError("a power with a run-time exponent")
        a = self.c
        if float(p).is_integer():
            ip = int(p)
            if ip == 0:
                return TJet((1.0,) + (0.0,) * (len(a) - 1))
            if ip > 0:   # repeated products: equal to the jets' recurrence to rounding
                out = a
                for _ in range(ip - 1):
                    out = mul(out, a)
                return TJet(out)
            return TJet(pow_series(a, p, _pow(a[0], p), 1.0 / a[0]))
        return TJet(pow_series(a, p, _pow(a[0], p), 1.0 / a[0]))

    def __rpow__(self, base: Any) -> TJet:
        if type(base) is Sym or base <= 0:
            raise TraceError(f"base ** jet needs a positive constant base, got {base!r}")
        return (self * math.log(base)).exp()

    def __abs__(self) -> TJet:
        a0 = self.c[0]
        if type(a0) is not Sym:
            return -self if a0 < 0.0 else self
        neg = a0.tape.compare("<", a0, 0.0)
        return TJet([a0.tape.select(neg, -x, x) for x in self.c])

    def sincos(self) -> tuple[TJet, TJet]:
        a = self.c
        s, c = sincos_series(a, _fn("sin", a[0]), _fn("cos", a[0]))
        return TJet(s), TJet(c)

    def sin(self) -> TJet:
        return self.sincos()[0]

    def cos(self) -> TJet:
        return self.sincos()[1]

    def tan(self) -> TJet:
        return TJet(tan_like_series(self.c, _fn("tan", self.c[0]), 1.0))

    def tanh(self) -> TJet:
        return TJet(tan_like_series(self.c, _fn("tanh", self.c[0]), -1.0))

    def exp(self) -> TJet:
        return TJet(exp_series(self.c, _fn("exp", self.c[0])))

    def log(self) -> TJet:   # math.log raises ValueError at run time for a value <= 0
        return TJet(log_series(self.c, _fn("log", self.c[0])))

    def sqrt(self) -> TJet:  # value < 0: ValueError; = 0: ZeroDivisionError (run time)
        return TJet(sqrt_series(self.c, _fn("sqrt", self.c[0])))

    def atan(self) -> TJet:
        return TJet(atan_series(self.c, _fn("atan", self.c[0])))


def _pow(x: Any, p: float) -> Any:
    if type(x) is Sym:
        return x.tape.call("pow", x, float(p))
    return _constant_call("pow", x, float(p))


# ----- the expression library on traced values (for kind = "expr") ------------------------
def _value(x: Any) -> Any:
    return x.c[0] if type(x) is TJet else x


def _coeffs(x: Any, n: int) -> tuple[Any, ...]:
    return x.c if type(x) is TJet else (x,) + (0.0,) * (n - 1)


def _pick(op: str, a: Any, b: Any) -> Any:
    """a if value(a) op value(b) else b, jets picked whole (as :func:`jets.min_`)."""
    if type(a) is not TJet and type(b) is not TJet:
        if type(a) is not Sym and type(b) is not Sym:
            return a if {"<=": a <= b, ">=": a >= b}[op] else b
        tape = _tape_of(a, b)
        return tape.select(tape.compare(op, a, b), a, b)
    tape = _tape_of(a, b)
    cond = tape.compare(op, _value(a), _value(b))
    if type(cond) is bool:
        return a if cond else b
    n = len(a.c) if type(a) is TJet else len(b.c)
    return TJet([tape.select(cond, x, y) for x, y in zip(_coeffs(a, n), _coeffs(b, n),
                                                          strict=True)])


def _smooth(name: str) -> Callable[[Any], Any]:
    def f(x: Any) -> Any:
        if type(x) is TJet:
            return getattr(x, name)()
        return _fn(name, x)
    f.__name__ = name
    return f


def _abs(x: Any) -> Any:
    if type(x) is TJet:
        return abs(x)
    if type(x) is Sym:
        return x.tape.select(x.tape.compare("<", x, 0.0), -x, x)
    return abs(x)


def _step(x: Any) -> Any:
    """1 for x ≥ 0 else 0, a constant of the traced pass (derivatives 0, as the jets)."""
    v = _value(x)
    if type(v) is not Sym:
        return 1.0 if v >= 0.0 else 0.0
    return v.tape.select(v.tape.compare(">=", v, 0.0), 1.0, 0.0)


#: :data:`jets.JET_LIB`'s functions on traced jets, symbols and constants.
TRACE_LIB: Mapping[str, Callable[..., Any]] = MappingProxyType({
    **{name: _smooth(name) for name in ("sin", "cos", "tan", "exp", "log", "sqrt", "atan",
                                        "tanh")},
    "abs": _abs,
    "min": lambda a, b: _pick("<=", a, b),
    "max": lambda a, b: _pick(">=", a, b),
    "clip": lambda x, lo, hi: _pick("<=", _pick(">=", x, lo), hi),
    "step": _step,
})
