"""Coefficient-level recurrences of truncated Taylor series ("jets"), free of value functions.

Each kernel maps coefficient tuples ``c[k] = f⁽ᵏ⁾(t₀)/k!`` to the coefficients of a result,
given the value-level results it needs (``sin a₀``, ``exp a₀``, ``1/b₀`` …) as arguments.
Keeping the value functions and the domain checks out of the kernels is what lets the same
recurrences run twice: on floats inside :class:`tfl_mav.control.path.jets.Jet` (the reference),
and once at start-up on symbols in :mod:`tfl_mav.control.path.jetcode`, which turns them into
straight-line float code. Only ``+ − × ÷`` appear here, so both runs perform the same
floating-point operations in the same order.

Recurrences are the standard ones (Griewank & Walther, *Evaluating Derivatives*, ch. 13);
results have the smaller order of the operands (``zip``-style truncation).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

__all__ = ["atan_series", "div_series", "exp_series", "log_series", "mul", "pow_series",
           "sincos_series", "sqrt_series", "tan_like_series"]

Coeffs = Sequence[Any]


def mul(a: Coeffs, b: Coeffs) -> tuple[Any, ...]:
    """Cauchy product truncated to the shorter order (order 4 unrolled: it runs every tick)."""
    n = min(len(a), len(b))
    if n == 5:
        a0, a1, a2, a3, a4 = a[:5] if len(a) > 5 else a
        b0, b1, b2, b3, b4 = b[:5] if len(b) > 5 else b
        return (
            a0 * b0,
            a0 * b1 + a1 * b0,
            a0 * b2 + a1 * b1 + a2 * b0,
            a0 * b3 + a1 * b2 + a2 * b1 + a3 * b0,
            a0 * b4 + a1 * b3 + a2 * b2 + a3 * b1 + a4 * b0,
        )
    out = []
    for k in range(n):
        acc = 0.0
        for i in range(k + 1):
            acc += a[i] * b[k - i]
        out.append(acc)
    return tuple(out)


def div_series(a: Coeffs, b: Coeffs, inv_b0: Any) -> tuple[Any, ...]:
    """a/b with ``inv_b0`` = 1/b₀: q_k = (a_k − Σ_{j≥1} b_j q_{k−j}) / b₀."""
    n = min(len(a), len(b))
    q = [a[0] * inv_b0]
    for k in range(1, n):
        acc = a[k]
        for j in range(1, k + 1):
            acc -= b[j] * q[k - j]
        q.append(acc * inv_b0)
    return tuple(q)


def pow_series(a: Coeffs, p: float, b0: Any, inv_a0: Any) -> tuple[Any, ...]:
    """a**p for real p from a·b' = p·a'·b, given b₀ = a₀**p and 1/a₀ (a₀ ≠ 0)."""
    b = [b0]
    for k in range(1, len(a)):
        acc = 0.0
        for j in range(1, k + 1):
            acc += (p * j - (k - j)) * a[j] * b[k - j]
        b.append(acc * inv_a0 / k)
    return tuple(b)


def sincos_series(a: Coeffs, s0: Any, c0: Any) -> tuple[tuple[Any, ...], tuple[Any, ...]]:
    """(sin f, cos f) from s' = f'c, c' = −f's, given s₀ = sin a₀, c₀ = cos a₀."""
    n = len(a)
    if n == 2:
        return (s0, a[1] * c0), (c0, -a[1] * s0)
    if n == 5:
        _, a1, a2, a3, a4 = a
        b2 = 2.0 * a2
        b3 = 3.0 * a3
        b4 = 4.0 * a4
        s1 = a1 * c0
        c1 = -a1 * s0
        s2 = 0.5 * (a1 * c1 + b2 * c0)
        c2 = -0.5 * (a1 * s1 + b2 * s0)
        s3 = (a1 * c2 + b2 * c1 + b3 * c0) / 3.0
        c3 = -(a1 * s2 + b2 * s1 + b3 * s0) / 3.0
        s4 = 0.25 * (a1 * c3 + b2 * c2 + b3 * c1 + b4 * c0)
        c4 = -0.25 * (a1 * s3 + b2 * s2 + b3 * s1 + b4 * s0)
        return (s0, s1, s2, s3, s4), (c0, c1, c2, c3, c4)
    ja = [j * a[j] for j in range(n)]
    s = [s0]
    c = [c0]
    for k in range(1, n):
        ss = 0.0
        cc = 0.0
        for j in range(1, k + 1):
            ss += ja[j] * c[k - j]
            cc += ja[j] * s[k - j]
        s.append(ss / k)
        c.append(-cc / k)
    return tuple(s), tuple(c)


def tan_like_series(a: Coeffs, t0: Any, sign: float) -> tuple[Any, ...]:
    """Series of t with t' = a'·(1 + sign·t²): tan (sign +1) and tanh (sign −1)."""
    t = [t0]
    u = [1.0 + sign * t0 * t0]
    for k in range(1, len(a)):
        acc = 0.0
        for j in range(1, k + 1):
            acc += j * a[j] * u[k - j]
        t.append(acc / k)
        sq = 0.0
        for i in range(k + 1):
            sq += t[i] * t[k - i]
        u.append(sign * sq)
    return tuple(t)


def exp_series(a: Coeffs, b0: Any) -> tuple[Any, ...]:
    """exp f from b' = f'b, given b₀ = exp a₀."""
    b = [b0]
    for k in range(1, len(a)):
        acc = 0.0
        for j in range(1, k + 1):
            acc += j * a[j] * b[k - j]
        b.append(acc / k)
    return tuple(b)


def log_series(a: Coeffs, b0: Any) -> tuple[Any, ...]:
    """log f from f·b' = f', given b₀ = log a₀ (a₀ > 0)."""
    a0 = a[0]
    b = [b0]
    for k in range(1, len(a)):
        acc = 0.0
        for j in range(1, k):
            acc += j * b[j] * a[k - j]
        b.append((a[k] - acc / k) / a0)
    return tuple(b)


def sqrt_series(a: Coeffs, b0: Any) -> tuple[Any, ...]:
    """sqrt f from b² = f, given b₀ = sqrt a₀ (a₀ > 0)."""
    inv = 0.5 / b0
    b = [b0]
    for k in range(1, len(a)):
        acc = 0.0
        for j in range(1, k):
            acc += b[j] * b[k - j]
        b.append((a[k] - acc) * inv)
    return tuple(b)


def atan_series(a: Coeffs, b0: Any) -> tuple[Any, ...]:
    """atan f from b'·(1 + f²) = f', given b₀ = atan a₀."""
    w = mul(a, a)
    w0 = 1.0 + w[0]
    b = [b0]
    for k in range(1, len(a)):
        acc = 0.0
        for j in range(1, k):
            acc += j * b[j] * w[k - j]
        b.append((a[k] - acc / k) / w0)
    return tuple(b)
