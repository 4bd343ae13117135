"""Paths and the virtual output: jets against finite differences, projection, tube, errors."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from tfl_mav.control.path.jets import Jet, cos, exp, sin, sqrt
from tfl_mav.control.path.paths import PathError, PathTracker, build_path
from tfl_mav.control.path.tracker import newton_closest_lam

PATHS = [
    ("paper", {}, (1.5, 0.3, 0.5)),
    ("line", {"point_m": [0, 0, 2], "direction": [1, 1, 0.5]}, (1.0, 0.2, 1.5)),
    ("circle", {}, (2.5, 0.2, 4.5)),
    ("helix", {}, (2.3, 0.0, 0.6)),
    ("lemniscate", {}, (0.2, 0.3, 4.6)),
    ("expr", {"s": ["y - cos(x)", "z - 8 + 4*cos(x)"],
              "sigma": ["t", "cos(t)", "8 - 4*cos(t)"], "t_range": [-12, 12]}, (1.5, 0.3, 0.5)),
]


def _trajectory(y0: tuple[float, float, float], t: float) -> list[list[float]]:
    """Taylor coefficients (value, d/dt, d²/2, d³/6, d⁴/24) of a smooth test trajectory."""
    w = (2.0, 1.3, 3.0)
    a = (0.1, 0.05, 0.1)
    v = (0.3, -0.2, 0.1)
    rows = []
    for i in range(3):
        s, c = math.sin(w[i] * t), math.cos(w[i] * t)
        d = [y0[i] + v[i] * t + a[i] * s, v[i] + a[i] * w[i] * c, -a[i] * w[i] ** 2 * s,
             -a[i] * w[i] ** 3 * c, a[i] * w[i] ** 4 * s]
        rows.append([d[k] / math.factorial(k) for k in range(5)])
    return rows


@pytest.mark.parametrize(("kind", "params", "y0"), PATHS, ids=[p[0] for p in PATHS])
def test_derivatives_match_finite_differences(kind, params, y0):
    """π's and α's jets agree with central differences of their values along y(t)."""
    path = build_path(kind, params)
    tracker = PathTracker(path)
    h = 1e-3
    outs = [tracker.evaluate(_trajectory(y0, 0.5 + k * h)) for k in range(-3, 4)]
    mid = outs[3]
    assert mid.in_tube, mid.reason
    for series, getter in (("pi", lambda o: o.pi), ("alpha1", lambda o: o.alpha[0]),
                           ("alpha2", lambda o: o.alpha[1])):
        v = np.array([getter(o).c[0] for o in outs])
        d = getter(mid).derivatives()
        fd1 = (v[4] - v[2]) / (2 * h)
        fd2 = (v[4] - 2 * v[3] + v[2]) / h**2
        fd3 = (v[5] - 2 * v[4] + 2 * v[2] - v[1]) / (2 * h**3)
        fd4 = (v[5] - 4 * v[4] + 6 * v[3] - 4 * v[2] + v[1]) / h**4
        scale = 1.0 + max(abs(x) for x in d[1:])
        # Central differences are O(h²) accurate; the 4th difference loses ~h⁻⁴·eps.
        assert d[1] == pytest.approx(fd1, abs=1e-5 * scale), series
        assert d[2] == pytest.approx(fd2, abs=1e-4 * scale), series
        assert d[3] == pytest.approx(fd3, abs=1e-3 * scale), series
        assert d[4] == pytest.approx(fd4, abs=5e-2 * scale), series


@pytest.mark.parametrize(("kind", "params", "y0"), PATHS, ids=[p[0] for p in PATHS])
def test_jacobian_matches_finite_differences(kind, params, y0):
    path = build_path(kind, params)
    tracker = PathTracker(path)
    base = tracker.evaluate(_trajectory(y0, 0.0))
    eps = 1e-5

    def moved(axis: int, step: float):
        rows = _trajectory(y0, 0.0)
        rows[axis][0] += step
        t = copy.copy(tracker)      # from the base's λ and π
        out = t.evaluate(rows)
        return (out.alpha[0].c[0], out.alpha[1].c[0], out.pi.c[0])

    for axis in range(3):
        hi, lo = moved(axis, eps), moved(axis, -eps)
        for row in range(3):
            fd = (hi[row] - lo[row]) / (2 * eps)   # central: O(eps²) truncation
            assert base.jacobian[row][axis] == pytest.approx(fd, abs=1e-6 * (1 + abs(fd)))


def test_projection_is_the_closest_point():
    path = build_path("paper")
    y = (0.4, 0.7, 4.1)
    out = PathTracker(path).evaluate([[c, 0, 0, 0, 0] for c in y])
    lam = np.linspace(-3, 3, 200001)
    d = np.sqrt((lam - y[0]) ** 2 + (np.cos(lam) - y[1]) ** 2 + (8 - 4 * np.cos(lam) - y[2]) ** 2)
    assert out.lam == pytest.approx(lam[np.argmin(d)], abs=1e-4)
    assert out.distance_m == pytest.approx(d.min(), abs=1e-9)


def test_arc_length_is_accumulated_along_the_path():
    """Walking along the circle by a quarter turn advances π by r·π/2."""
    path = build_path("circle", {"center_m": [0, 0, 5], "radius_m": 2.0})
    tracker = PathTracker(path)
    pis = []
    for lam in np.linspace(0.1, 0.1 + math.pi / 2, 400):
        y = (2.0 * math.cos(lam), 2.0 * math.sin(lam), 5.0)
        pis.append(tracker.evaluate([[c, 0, 0, 0, 0] for c in y]).pi.c[0])
    assert pis[-1] - pis[0] == pytest.approx(math.pi, rel=1e-9)


def test_leaving_the_tube_is_reported_not_nan():
    """The paper path's bend at y1 = 0 has radius of curvature 1/17 ≈ 0.06 m in y3 …
    well, the projection stops being unique on the concave side at the radius of
    curvature: there the tracker must say so instead of producing huge derivatives."""
    path = build_path("circle", {"center_m": [0, 0, 5], "radius_m": 1.0})
    tracker = PathTracker(path)
    ok = tracker.evaluate([[0.5, 0, 0, 0, 0], [0, 0, 0, 0, 0], [5, 0, 0, 0, 0]])
    assert ok.in_tube
    near_centre = tracker.evaluate([[0.05, 0, 0, 0, 0], [0, 0, 0, 0, 0], [5, 0, 0, 0, 0]])
    assert not near_centre.in_tube
    assert "radius of curvature" in near_centre.reason
    assert all(math.isfinite(x) for x in near_centre.pi.c + near_centre.alpha[0].c)


def test_non_finite_state_is_reported():
    out = PathTracker(build_path("paper")).evaluate(
        [[math.nan, 0, 0, 0, 0], [0, 0, 0, 0, 0], [4, 0, 0, 0, 0]])
    assert not out.in_tube and "non-finite" in out.reason


@pytest.mark.parametrize(("kind", "params", "field"), [
    ("spiral", {}, "path.kind"),
    ("circle", {"radius_m": -1}, "path.radius_m"),
    ("circle", {"radius": 1}, "path.radius"),
    ("helix", {"center_m": [0, 0]}, "path.center_m"),
    ("line", {"direction": [0, 0, 0]}, "path.direction"),
    ("expr", {"s": ["y", "z"], "sigma": ["t", "1", "0"]}, "path.s"),          # σ not on s = 0
    ("expr", {"s": ["y", "z"], "sigma": ["0", "0", "0"]}, "path.sigma"),      # σ' = 0
    ("expr", {"s": ["y", "2*y"], "sigma": ["t", "0", "0"]}, "path.s"),        # rank 1
    ("expr", {"s": ["__import__('os')", "z"], "sigma": ["t", "0", "0"]}, "path.s[0]"),
    ("expr", {"s": ["x.real", "z"], "sigma": ["t", "0", "0"]}, "path.s[0]"),
    ("expr", {"s": ["y"], "sigma": ["t", "0", "0"]}, "path.s"),
])
def test_bad_paths_name_the_key(kind, params, field):
    with pytest.raises(PathError) as err:
        build_path(kind, params)
    assert err.value.field == field
    assert field in str(err.value)


def test_expr_path_equals_builtin():
    expr = build_path("expr", PATHS[-1][1])
    builtin = build_path("paper")
    rows = _trajectory((1.5, 0.3, 0.5), 0.2)
    a, b = PathTracker(expr).evaluate(rows), PathTracker(builtin).evaluate(rows)
    assert a.pi.c[1:] == pytest.approx(b.pi.c[1:], rel=1e-12)
    assert a.alpha[0].c == pytest.approx(b.alpha[0].c, rel=1e-12)


def test_jet_elementary_functions_against_finite_differences():
    """Each jet function's derivatives agree with a 5-point stencil of the float function."""
    funcs = [(sin, math.sin), (cos, math.cos), (exp, math.exp), (sqrt, math.sqrt),
             (lambda x: x * x * x / (1.0 + x * x), lambda x: x**3 / (1 + x * x))]
    x0, h = 0.7, 1e-3
    for jf, ff in funcs:
        d = jf(Jet.variable(x0)).derivatives()
        v = [ff(x0 + k * h) for k in range(-2, 3)]
        assert d[0] == pytest.approx(ff(x0), rel=1e-14)
        assert d[1] == pytest.approx((v[3] - v[1]) / (2 * h), rel=1e-6)
        assert d[2] == pytest.approx((v[3] - 2 * v[2] + v[1]) / h**2, rel=1e-5, abs=1e-6)


def test_expr_path_with_a_constant_component_evaluates_as_jets_and_arrays():
    """A level path's height written as a plain number ("3.0") is a constant of λ: its jet
    has zero derivatives and an array of λ gives an array, so the tracker can fly it."""
    path = build_path("expr", {"s": ["y - sin(x)", "z - 3.0"],
                               "sigma": ["t", "sin(t)", "3.0"]})
    _, _, z = path.sigma(Jet.variable(0.4, order=3))
    assert z.c == (3.0, 0.0, 0.0, 0.0)
    zs = path.sigma(np.linspace(0.0, 1.0, 5))[2]
    assert zs.shape == (5,) and np.all(zs == 3.0)
    lam, converged = newton_closest_lam(path, (0.4, 0.5, 3.1), 0.3)
    assert converged and abs(path.sigma(lam)[1] - 0.5) < 0.1
