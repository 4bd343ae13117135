"""The virtual output along the position (paper §V), as explicit state and one pure step.

:func:`project` is what the law needs of the path at one instant, on the path's generated
kernels (σ, σ', σ''/2; σ's degree-5 expansion; α = s(y) and its gradients along the
position's Taylor rows; π's rates — :mod:`compiled`), passed in as :class:`Kernels`:

* the closest point (eq. (13)): Newton on g(λ) = ⟨y − σ(λ), σ'(λ)⟩ with the exact σ, σ',
  σ'', from the last λ extrapolated by the one before; lost when g' ≥ 0 (not a closest
  point), when the root is more than 0.05 from the start, or when no step falls below 1e-9
  in NEWTON_ITERS (a step below 1e-9 leaves an error ~ step²: the root to rounding);
* π, the arc length of the closest point, advanced by Simpson's rule on |σ'| (:func:`arc`);
* the projection's margin −∂g/∂λ / |σ'|², which vanishes where the distance to the path
  reaches the radius of curvature: below ``tube_min`` the tube is left before the
  derivatives blow up;
* α's and π's derivatives to order 4 and the Jacobian rows Dφ (eqs. (8), (14), (15)).

It is the reference computation of :class:`tracker.PathTracker` (the jets) done in
straight-line float code: tests/contract/test_compiled.py holds the two to ≤ 1e-9 relative.
:class:`compiled.CompiledPathTracker` holds its state; the law's step
(:func:`tfl_mav.control.tfl.step.tfl_step`) calls it within its one pure step, so the
accelerator seam compiles it with the kernels inlined.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from enum import IntEnum
from typing import Any, NamedTuple

__all__ = ["NEWTON_ITERS", "PATH_START", "VO", "Expansion", "Kernels", "PathState", "Projected",
           "arc", "expansion", "lost_reason", "project"]

NEWTON_ITERS = 20       # Newton steps of the projection before it counts as lost


class VO(IntEnum):
    """What the projection found (:attr:`Projected.code`)."""

    OK = 0              # the closest point, inside the tube
    NONFINITE = 1       # the position's rows are not finite
    NO_ROOT = 2         # no closest point (Newton lost, or no λ to start from)
    MARGIN = 3          # the closest point, but the tube is left (the margin below tube_min)
    FAILED = 4          # evaluating the path raised
    REFERENCE = 5       # the reference tracker lost it (its own words; not this step's)

_ZERO5 = (0.0, 0.0, 0.0, 0.0, 0.0)
_IDENTITY = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


class PathState(NamedTuple):
    """What the projection remembers: λ, the last two λ (the warm start), π, and σ's degree-5
    expansion at λ."""

    has_lam: bool               # ``lam`` is set
    lam: float
    has_lam_prev: bool          # ``lam_prev`` is set
    lam_prev: float
    arc_m: float                # π: the arc length from the first projection (m)
    has_expansion: bool         # ``expansion`` is σ's at ``expansion_lam``
    expansion_lam: float
    expansion: tuple[float, ...]    # σ⁽ʲ⁾/j!, j = 0…5, x y z each: the 18 floats of the
    #                                 sigma5 kernel (:func:`expansion` names them)


PATH_START = PathState(False, 0.0, False, 0.0, 0.0, False, 0.0, (0.0,) * 18)

V5 = tuple[float, float, float, float, float]
V3 = tuple[float, float, float]


class Projected(NamedTuple):
    """The virtual output at one instant (:func:`project`)."""

    code: VO                    # what the projection found
    xi1: V5                     # α1 and its derivatives to order 4 (ξ1, eq. (14))
    xi2: V5                     # α2 likewise (ξ2)
    eta: V5                     # π likewise (η)
    jacobian: tuple[V3, V3, V3]     # Dφ's rows (eq. (15)); the identity when lost
    lam: float                  # λ of the closest point (NaN: none)
    distance_m: float           # to it (NaN: none)
    margin: float               # −∂g/∂λ / |σ'|² there (0: none)


class Kernels(NamedTuple):
    """One path's generated kernels (:func:`compiled.compile_path`, :func:`compiled.pi_kernel`),
    what :func:`project` evaluates the path with. The accelerator seam inlines them: a
    compiled projection is the projection on these kernels (bound when it is lowered)."""

    sigma2: Callable[[tuple[float]], tuple[float, ...]]
        # σ, σ', σ''/2 at λ (9 floats: x y z of each)
    sigma5: Callable[[tuple[float]], tuple[float, ...]]
        # σ⁽ʲ⁾/j! at λ, j = 0…5 (18 floats)
    s4: Callable[..., tuple[float, ...]]
        # α1, α2 to order 4 and their gradients along the position's rows x, y, z
    pi: Callable[..., tuple[float, ...]]
        # π̇ … π⁽⁴⁾ from σ's expansion, the rows and the slope ∂g/∂λ


class Expansion(NamedTuple):
    """σ's degree-5 expansion at λ: σ(λ + δ) = Σ_j s_j δʲ, s_j = σ⁽ʲ⁾(λ)/j! (x, y, z, m)."""

    s0: V3      # σ
    s1: V3      # σ'
    s2: V3      # σ''/2
    s3: V3      # σ⁽³⁾/6
    s4: V3      # σ⁽⁴⁾/24
    s5: V3      # σ⁽⁵⁾/120


def expansion(c: Sequence[Any]) -> Expansion:
    """The :class:`Expansion` of the 18 floats a ``sigma5`` kernel gives (j-major: x y z of
    σ⁽ʲ⁾/j!, j = 0…5; :data:`compiled.C_NAMES`)."""
    return Expansion((c[0], c[1], c[2]), (c[3], c[4], c[5]), (c[6], c[7], c[8]),
                     (c[9], c[10], c[11]), (c[12], c[13], c[14]), (c[15], c[16], c[17]))


def _norm(v: V3) -> Any:
    """|v|."""
    x, y, z = v
    return math.sqrt(x * x + y * y + z * z)


def arc(cp: Expansion, cn: Expansion, delta: Any) -> Any:
    """π's advance: ∫|σ'| dλ over [λ, λ + δ] by Simpson's rule (signed: negative for δ < 0),
    |σ'| at both ends from the expansions ``cp`` (at λ) and ``cn`` (at λ + δ), at the middle
    from ``cp``'s polynomial. The one rule of the flown projection and of the reference
    tracker (:class:`tracker.PathTracker`)."""
    h = 0.5 * delta
    s1, s2, s3, s4, s5 = cp.s1, cp.s2, cp.s3, cp.s4, cp.s5
    mid = [s1[i] + h * (2.0 * s2[i] + h * (3.0 * s3[i] + h * (4.0 * s4[i] + h * 5.0 * s5[i])))
           for i in range(3)]       # σ' at λ + δ/2
    return delta / 6.0 * (_norm(s1) + 4.0 * _norm(mid) + _norm(cn.s1))


def project(k: Kernels, tube_min: float, ps: PathState, rows: tuple[Any, ...],
            lam_start: float, lam_start_ok: bool, path_failed: bool
            ) -> tuple[Projected, PathState]:
    """The virtual output along the position's Taylor ``rows`` (x, y, z, each (y, ẏ, ÿ/2,
    y⃛/6, y⁽⁴⁾/24), m) on the path of kernels ``k``, and the state after it.

    ``lam_start``/``lam_start_ok``: a global search's λ for a state without one (the
    holder's, :meth:`compiled.CompiledPathTracker.start`); ``path_failed``: evaluating the
    path raised (VO.FAILED, nothing moves). Lost (any code but VO.OK): ξ, η zero, Dφ the
    identity; λ and the distance NaN unless the closest point was found (VO.MARGIN)."""
    tx, ty, tz = rows
    yx, yy, yz = tx[0], ty[0], tz[0]
    code = VO.OK
    xi1 = xi2 = eta = _ZERO5
    jac = _IDENTITY
    lam_out, distance, margin = math.nan, math.nan, 0.0
    has_lam, lam0 = ps.has_lam, ps.lam
    if not math.isfinite((tx[0] + tx[1] + tx[2] + tx[3] + tx[4])
                         + (ty[0] + ty[1] + ty[2] + ty[3] + ty[4])
                         + (tz[0] + tz[1] + tz[2] + tz[3] + tz[4])):
        code = VO.NONFINITE
    elif path_failed:
        code = VO.FAILED
    elif not has_lam:
        if lam_start_ok and math.isfinite(lam_start):
            has_lam, lam0 = True, lam_start
        else:
            code = VO.NO_ROOT
    ps = PathState(has_lam, lam0, ps.has_lam_prev, ps.lam_prev, ps.arc_m, ps.has_expansion,
                   ps.expansion_lam, ps.expansion)
    if code == VO.OK:
        fresh = ps.has_expansion and ps.expansion_lam == lam0   # λ not moved from outside
        lam = 2.0 * lam0 - ps.lam_prev if fresh and ps.has_lam_prev else lam0
        found = False
        for _ in range(NEWTON_ITERS):
            c0x, c0y, c0z, c1x, c1y, c1z, c2x, c2y, c2z = k.sigma2((lam,))
            ex, ey, ez = yx - c0x, yy - c0y, yz - c0z
            dg = 2.0 * (ex * c2x + ey * c2y + ez * c2z) - (c1x * c1x + c1y * c1y + c1z * c1z)
            if not dg < 0.0:
                break
            step = -(ex * c1x + ey * c1y + ez * c1z) / dg
            lam += step
            if not abs(lam - lam0) <= 0.05:
                break
            if abs(step) < 1e-9:
                found = True
                break
        if found:
            cp = ps.expansion
            if not fresh:
                cp = k.sigma5((lam0,))
            c = k.sigma5((lam,))
            sig = expansion(c)
            ps = PathState(True, lam, True, lam0,
                           ps.arc_m + arc(expansion(cp), sig, lam - lam0), True, lam, c)
            lam_out = lam
            (sx, sy, sz), (c1x, c1y, c1z), (c2x, c2y, c2z) = sig.s0, sig.s1, sig.s2
            e0x, e0y, e0z = yx - sx, yy - sy, yz - sz
            s1sq = c1x ** 2 + c1y ** 2 + c1z ** 2
            slope = -s1sq + 2.0 * (e0x * c2x + e0y * c2y + e0z * c2z)
            margin = -slope / s1sq if s1sq > 0.0 else 0.0
            distance = math.sqrt(e0x ** 2 + e0y ** 2 + e0z ** 2)
            if margin < tube_min:
                code = VO.MARGIN
            else:
                p1, p2, p3, p4 = k.pi(c, tx, ty, tz, (slope,))
                a = k.s4(tx, ty, tz)
                kn = math.sqrt(s1sq) / -slope
                xi1, xi2, eta = a[0:5], a[5:10], (ps.arc_m, p1, p2, p3, p4)
                jac = (a[10:13], a[13:16], (kn * c1x, kn * c1y, kn * c1z))
        else:
            code = VO.NO_ROOT
    if code != VO.OK and code != VO.MARGIN:     # no closest point to speak of
        lam_out, distance = math.nan, math.nan
    return Projected(code, xi1, xi2, eta, jac, lam_out, distance, margin), ps


# What a lost projection's code says (str.format fields: distance_m, margin, failure); a
# code not here: the closest-point search did not converge. A table read once rather than
# a chain of ``code == VO.X``: on Python 3.11 each ``VO.X`` is a class attribute read
# through ``EnumType.__getattr__``, 0.1 µs, and a replayed tick that falls back read four.
_LOST_WORDS: dict[VO, str] = {
    VO.NONFINITE: "non-finite state",
    VO.MARGIN: ("distance {distance_m:.3f} m near the radius of curvature "
                "(projection margin {margin:.2f})"),
    VO.FAILED: "path evaluation failed: {failure}",
    VO.REFERENCE: "{failure}",
}


def lost_reason(code: VO, distance_m: float, margin: float, failure: str) -> str:
    """Why the projection was lost (a code other than VO.OK), in words; ``failure``: the
    words of what lost it — the path's own error (VO.FAILED), the reference tracker's
    reason (VO.REFERENCE)."""
    words = _LOST_WORDS.get(code)
    if words is None:
        return "closest-point search did not converge"
    return words.format(distance_m=distance_m, margin=margin, failure=failure)
