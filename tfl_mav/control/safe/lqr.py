"""Discrete LQR in plain numpy: the safe law's gains without importing scipy.

The reduced-attitude law (:mod:`recovery`) designs its gain on the zero-order-hold model at
the control period, scheduled on the spin rate, so a gain is computed in flight the first
time a spin rate is met. scipy.linalg (expm, solve_discrete_are) did this, and importing it
costs a restarted daemon ~0.3 s before its first tick. Here:

* :func:`expm` — scaling and squaring on a Taylor series: scale by 2⁻ˢ until the 1-norm is
  ≤ 1/2, sum 18 terms (the remainder is < 0.5¹⁸/18! ≈ 6e-22 of the norm, far below
  rounding), square s times;
* :func:`solve_dare` — the structured doubling algorithm (Chu, Fan & Lin, "A structure-
  preserving doubling algorithm for continuous-time algebraic Riccati equations", 2005;
  its discrete form: Lin & Xu 2006): with G = B R⁻¹ Bᵀ, H = Q,
  A ← A (I + G H)⁻¹ A, G ← G + A (I + G H)⁻¹ G Aᵀ, H ← H + Aᵀ H (I + G H)⁻¹ A converges
  quadratically (error ~ ρ(A_cl)^(2ᵏ)) to the stabilizing solution X of
  X = Aᵀ X A − Aᵀ X B (R + Bᵀ X B)⁻¹ Bᵀ X A + Q. Deterministic: a fixed recipe, no
  random starts; iterations stop when H moves by ≤ 1e-15 of its norm (at most 64).

tests/unit/test_lqr.py holds the gains to scipy's (QZ-based) solution to ≤ 1e-10 relative.
"""

from __future__ import annotations

import numpy as np

__all__ = ["dlqr", "dlqr_zoh_many", "expm", "solve_dare", "zoh"]

_TAYLOR_TERMS = 18
_SDA_MAX_ITER = 64


def expm(m: np.ndarray) -> np.ndarray:
    """e^m of a square matrix (scaling and squaring, Taylor; see the module docstring)."""
    m = np.asarray(m, dtype=float)
    norm = float(np.max(np.sum(np.abs(m), axis=0))) if m.size else 0.0
    if not np.isfinite(norm):
        raise ValueError("expm: matrix not finite")
    s = max(0, int(np.ceil(np.log2(norm / 0.5)))) if norm > 0.5 else 0
    a = m / (2.0 ** s)
    n = m.shape[0]
    term = np.eye(n)
    out = np.eye(n)
    for k in range(1, _TAYLOR_TERMS + 1):
        term = term @ a / k
        out = out + term
    for _ in range(s):
        out = out @ out
    return out


def zoh(a: np.ndarray, b: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(A_d, B_d) of ẋ = a x + b u with u held over ``dt_s`` (the exponential of the
    augmented matrix [[a, b], [0, 0]] dt)."""
    n, m = b.shape
    big = np.zeros((n + m, n + m))
    big[:n, :n] = a * dt_s
    big[:n, n:] = b * dt_s
    e = expm(big)
    return e[:n, :n], e[:n, n:]


def solve_dare(a: np.ndarray, b: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Stabilizing solution X of the discrete algebraic Riccati equation (SDA, see the
    module docstring); raises ValueError when the doubling does not converge (the pair
    (a, b) not stabilizable or (a, q) not detectable)."""
    a_k = np.array(a, dtype=float)
    g_k = b @ np.linalg.solve(r, b.T)
    h_k = np.array(q, dtype=float)
    eye = np.eye(a_k.shape[0])
    with np.errstate(over="ignore", invalid="ignore"):   # divergence is checked below
        return _doubling(a_k, g_k, h_k, eye)


def _doubling(a_k: np.ndarray, g_k: np.ndarray, h_k: np.ndarray,
              eye: np.ndarray) -> np.ndarray:
    for _ in range(_SDA_MAX_ITER):
        w = eye + g_k @ h_k
        w_a = np.linalg.solve(w, a_k)                  # (I + G H)⁻¹ A
        w_g = np.linalg.solve(w, g_k)                  # (I + G H)⁻¹ G
        h_new = h_k + a_k.T @ h_k @ w_a
        g_k = g_k + a_k @ w_g @ a_k.T
        a_k = a_k @ w_a
        h_new = 0.5 * (h_new + h_new.T)                # symmetric by construction
        g_k = 0.5 * (g_k + g_k.T)
        done = np.linalg.norm(h_new - h_k, 1) <= 1e-15 * np.linalg.norm(h_new, 1)
        h_k = h_new
        if not np.all(np.isfinite(h_k)):
            break
        if done:
            return h_k
    raise ValueError("solve_dare: the doubling did not converge (not stabilizable?)")


def dlqr(a: np.ndarray, b: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """The discrete LQR gain K (u = −K x) for x⁺ = a x + b u and cost Σ xᵀ q x + uᵀ r u."""
    x = solve_dare(a, b, q, r)
    return np.linalg.solve(r + b.T @ x @ b, b.T @ x @ a)


# ----- many gains at once (the safe law's schedule, designed before the flight) -----------
def _expm_many(m: np.ndarray) -> np.ndarray:
    """:func:`expm` of a stack (N, n, n), item by item the same operations: items are
    grouped by their scaling power and each group runs the Taylor sum and squarings as
    stacked products (numpy multiplies a stack matrix by matrix, as one matrix)."""
    norms = np.max(np.sum(np.abs(m), axis=-2), axis=-1)
    if not np.all(np.isfinite(norms)):
        raise ValueError("expm: matrix not finite")
    powers = [max(0, int(np.ceil(np.log2(x / 0.5)))) if x > 0.5 else 0
              for x in norms.tolist()]
    out = np.empty_like(m)
    n = m.shape[-1]
    for s in sorted(set(powers)):
        idx = np.array([i for i, p in enumerate(powers) if p == s])
        a = m[idx] / (2.0 ** s)
        term = np.repeat(np.eye(n)[None], len(idx), axis=0)
        acc = term.copy()
        for k in range(1, _TAYLOR_TERMS + 1):
            term = term @ a / k
            acc = acc + term
        for _ in range(s):
            acc = acc @ acc
        out[idx] = acc
    return out


def dlqr_zoh_many(a: np.ndarray, b: np.ndarray, q: np.ndarray, r: np.ndarray,
                  dt_s: float) -> list[np.ndarray | None]:
    """``dlqr(*zoh(a[i], b[i], dt_s), q, r)`` for a stack of continuous systems, each
    item by the same floating-point operations as the one-at-a-time functions (so the
    same gains, bit for bit; tests/unit/test_lqr.py checks it), but as stacked numpy calls:
    a gain costs tens of µs instead of a millisecond. Each item's doubling stops at its own
    iteration, as :func:`solve_dare` would; an item that does not converge gives None."""
    num, n, m = b.shape
    big = np.zeros((num, n + m, n + m))
    big[:, :n, :n] = a * dt_s
    big[:, :n, n:] = b * dt_s
    e = _expm_many(big)
    ad, bd = e[:, :n, :n], e[:, :n, n:]
    out: list[np.ndarray | None] = [None] * num
    with np.errstate(over="ignore", invalid="ignore"):
        a_k = np.array(ad, dtype=float)
        g_k = bd @ np.linalg.solve(r, bd.swapaxes(-1, -2))
        h_k = np.repeat(np.array(q, dtype=float)[None], num, axis=0)
        eye = np.eye(n)
        active = np.arange(num)
        for _ in range(_SDA_MAX_ITER):
            w = eye + g_k @ h_k
            w_a = np.linalg.solve(w, a_k)
            w_g = np.linalg.solve(w, g_k)
            a_t = a_k.swapaxes(-1, -2)
            h_new = h_k + a_t @ h_k @ w_a
            g_k = g_k + a_k @ w_g @ a_t
            a_k = a_k @ w_a
            h_new = 0.5 * (h_new + h_new.swapaxes(-1, -2))
            g_k = 0.5 * (g_k + g_k.swapaxes(-1, -2))
            diff = np.max(np.sum(np.abs(h_new - h_k), axis=-2), axis=-1)
            done = diff <= 1e-15 * np.max(np.sum(np.abs(h_new), axis=-2), axis=-1)
            h_k = h_new
            finite = np.all(np.isfinite(h_k), axis=(-2, -1))
            fin = np.flatnonzero(done & finite)
            if len(fin):
                idx = active[fin]
                x, bi, ai = h_k[fin], bd[idx], ad[idx]
                bt = bi.swapaxes(-1, -2)
                k = np.linalg.solve(r + bt @ x @ bi, bt @ x @ ai)
                for j, i in enumerate(idx.tolist()):
                    out[i] = k[j]
            keep = ~done & finite
            if not keep.any():
                break
            active, a_k, g_k, h_k = active[keep], a_k[keep], g_k[keep], h_k[keep]
    return out
