"""The true distance to the path of every sample of a flight, for reading a log back.

:meth:`PathTracker.evaluate <tfl_mav.control.path.tracker.PathTracker.evaluate>` gives the
distance with the virtual output's jets to order 4 (what the law needs); a log reader needs
the distance only. :func:`path_distances` runs the same closest-point iteration (warm
started from the last sample, the global search on the first), stops where the distance
is known, and takes σ's Taylor coefficients from the path's compiled kernel
(:func:`~tfl_mav.control.path.compiled.compile_path`) where it reproduces the reference jets
(checked on the first samples; else the jets): the same distances to the bit, a small
part of the time (a 30 s flight: ~0.5 s instead of ~2.5 s).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

from tfl_mav.control.path.paths import Path
from tfl_mav.control.path.tracker import NEWTON_ITERS, closest_lam, newton_on_poly, poly_g

__all__ = ["path_distances"]

_CHECKED = 8                # samples on which the compiled σ must equal the jets

Coefficients = list[tuple[float, float, float]]


def _reference(path: Path) -> Callable[[float], Coefficients]:
    from tfl_mav.control.path.tracker import taylor_curve

    return lambda lam: taylor_curve(path, lam)


def _compiled(path: Path) -> Callable[[float], Coefficients] | None:
    from tfl_mav.control.path.compiled import compile_path
    from tfl_mav.control.path.jetcode import TraceError

    try:
        fn = compile_path(path).sigma5.fn
    except TraceError:
        return None

    def taylor(lam: float) -> Coefficients:
        c = fn((lam,))
        return [(c[0], c[1], c[2]), (c[3], c[4], c[5]), (c[6], c[7], c[8]),
                (c[9], c[10], c[11]), (c[12], c[13], c[14]), (c[15], c[16], c[17])]
    return taylor


def path_distances(path: Path, positions_m: Sequence[Sequence[float]], *,
                   compiled: bool = True) -> list[float]:
    """|y − σ(λ)| of each position (m, paper frame), in order, as successive
    ``PathTracker.evaluate`` calls give it (NaN where it loses the projection).
    ``compiled`` False: the reference jets throughout."""
    reference = _reference(path)
    fast = _compiled(path) if compiled else None
    out: list[float] = []
    sqrt, isfinite = math.sqrt, math.isfinite
    lam: float | None = None        # the closest point's λ, warm-started sample to sample
    for k, y in enumerate(positions_m):
        y0 = (float(y[0]), float(y[1]), float(y[2]))
        if not (isfinite(y0[0]) and isfinite(y0[1]) and isfinite(y0[2])):
            out.append(math.nan)
            continue
        if lam is None:
            found, ok = closest_lam(path, y0)
            if not ok or not isfinite(found):
                out.append(math.nan)
                continue
            lam = found
        taylor = fast if fast is not None else reference
        if fast is not None and k < _CHECKED and fast(lam) != reference(lam):
            fast = None                 # not the same bits: the reference from here on
            taylor = reference
        projected = _project(taylor, lam, y0)
        if projected is None:           # λ stays where it was
            out.append(math.nan)
            continue
        c, lam = projected
        ex, ey, ez = y0[0] - c[0][0], y0[1] - c[0][1], y0[2] - c[0][2]
        out.append(sqrt(ex ** 2 + ey ** 2 + ez ** 2))
    return out


def _project(taylor: Callable[[float], Coefficients], lam: float,
             y0: tuple[float, float, float]) -> tuple[Coefficients, float] | None:
    """The tracker's projection without the arc length: σ's coefficients at the closest
    point of ``y0`` and its λ, Newton from ``lam`` (None: no convergence)."""
    for _ in range(NEWTON_ITERS):
        c = taylor(lam)
        delta = newton_on_poly(lambda x, c=c: poly_g(c, y0, x))
        if delta is None:
            return None
        if abs(delta) < 1e-10:
            return c, lam
        lam += delta
    return None
