"""The compiled path tracker against the reference jets: the same numbers to rounding.

Every path kind, random states inside the projection tube, first (cold) and warm-started
evaluations; the kernels themselves against jets; paths that cannot be traced fall back to
the jets; a path that fails to evaluate is reported, not raised; the law fed the same states
gives the same thrusts with either tracker.
"""

from __future__ import annotations

import math
import random
import re

import numpy as np
import pytest

from tfl_mav.control.path.compiled import (
    CompiledPathTracker,
    compile_path,
    make_tracker,
    pi_kernel,
)
from tfl_mav.control.path.jets import Jet, cos
from tfl_mav.control.path.paths import Path, PathTracker, build_path
from tfl_mav.control.path.tracker import grad_s
from tfl_mav.from_scenario import build_controller
from tfl_mav.model.state import State
from tfl_mav.scenario import load_scenario
from tfl_mav.sitl.simulator import Simulator

# Every function an expression may use, on a path that is its own zero set by construction
# (y = f(x), z = h(x)); t_range keeps it away from the kinks of abs/min/max/clip/step.
_F = "0.5*min({v}, 1) + 0.2*abs({v} - 0.3) + max({v}, -9)*0.01 + tanh({v})/(2 + cos({v}))"
_H = ("3 + 0.1*clip({v}, -5, 5)**2 + sqrt(exp({v}/10)) + step({v})*{v}**3*0.01"
      " + atan({v})*log(2 + {v}*{v}) + tan({v}/5) + (1.5 + sin({v}))**(0.5 + 0.1*cos({v}))")
PATHS = {
    "paper": ("paper", {}, (1.5, 0.3, 0.5)),
    "line": ("line", {"point_m": [0, 0, 2], "direction": [1, 1, 0.5]}, (1.0, 0.2, 1.5)),
    "circle": ("circle", {}, (2.5, 0.2, 4.5)),
    "helix": ("helix", {}, (2.3, 0.0, 0.6)),
    "lemniscate": ("lemniscate", {}, (0.2, 0.3, 4.6)),
    "expr": ("expr", {"s": ["y - cos(x)", "z - 8 + 4*cos(x)"],
                      "sigma": ["t", "cos(t)", "8 - 4*cos(t)"], "t_range": [-12, 12]},
             (1.5, 0.3, 0.5)),
    "expr-all-functions": ("expr", {"s": [f"y - ({_F.format(v='x')})",
                                          f"z - ({_H.format(v='x')})"],
                                    "sigma": ["t", _F.format(v="t"), _H.format(v="t")],
                                    "t_range": [0.4, 0.95]}, (0.7, 0.9, 5.5)),
}


def _normwise(a, b) -> float:
    """max |a − b| / max |a| over one output vector (its scale sets what rounding means)."""
    return max(abs(x - y) for x, y in zip(a, b, strict=True)) / max(max(abs(x) for x in a),
                                                                    1e-300)


def _random_rows(rng: random.Random, y0, t: float) -> list[list[float]]:
    """Taylor rows (y, ẏ, ÿ/2, y⃛/6, y⁽⁴⁾/24) of a random smooth motion through y0 + 0.1 t."""
    rows = []
    for i in range(3):
        rows.append([y0[i] + 0.1 * t * rng.uniform(-1, 1)]
                    + [rng.uniform(-1, 1) / math.factorial(k) for k in range(1, 5)])
    return rows


@pytest.mark.parametrize("name", sorted(PATHS))
def test_compiled_tracker_matches_the_jets_to_rounding(name):
    kind, params, y0 = PATHS[name]
    path = build_path(kind, params)
    kernels = compile_path(path)
    rng = random.Random(13)
    checked = 0
    for _ in range(60):
        ref, fast = PathTracker(path), CompiledPathTracker(path, kernels)
        rows = _random_rows(rng, y0, rng.uniform(-1, 1))
        for tick in range(3):    # cold start, then warm-started ticks moving along ẏ
            if tick:
                rows = [[r[0] + 1e-3 * r[1], *r[1:]] for r in rows]
            a, b = ref.virtual_output(rows), fast.virtual_output(rows)
            assert a.in_tube == b.in_tube, (a.reason, b.reason)
            if not a.in_tube:
                break
            for u, v in [(a.xi1, b.xi1), (a.xi2, b.xi2), (a.eta[1:], b.eta[1:]),
                         *zip(a.jacobian, b.jacobian, strict=True)]:
                assert _normwise(u, v) <= 1e-9
            assert b.lam == pytest.approx(a.lam, rel=0, abs=1e-12 * (1 + abs(a.lam)))
            assert b.eta[0] == pytest.approx(a.eta[0], rel=0, abs=1e-12)   # π (m)
            assert b.distance_m == pytest.approx(a.distance_m, rel=1e-9, abs=1e-12)
            checked += 1
    assert checked >= 60     # most random states are inside the tube


@pytest.mark.parametrize("name", sorted(PATHS))
def test_kernels_run_the_jets_arithmetic(name):
    """σ's Taylor polynomial and α = s(y(t)) with ∂s/∂y from the kernels equal the jets'
    (the same operations in the same order: equal to a few ulp, bit for bit in practice)."""
    kind, params, y0 = PATHS[name]
    path = build_path(kind, params)
    k = compile_path(path)
    rng = random.Random(7)
    for _ in range(20):
        lam = rng.uniform(*path.lam_range)
        jets = path.sigma(Jet.variable(lam, order=5))
        ref = [j.c[jj] if isinstance(j, Jet) else (float(j) if jj == 0 else 0.0)
               for jj in range(6) for j in jets]
        assert _normwise(ref, k.sigma5.fn((lam,))) <= 1e-15
        rows = _random_rows(rng, y0, 1.0)
        out = k.s4.fn(*rows)
        a1, a2 = path.s(*(Jet(tuple(r)) for r in rows))
        assert _normwise(a1.derivatives(), out[0:5]) <= 1e-15
        assert _normwise(a2.derivatives(), out[5:10]) <= 1e-15
        grad = grad_s(path, [r[0] for r in rows])
        assert _normwise([*grad[0], *grad[1]], out[10:16]) <= 1e-15


def test_generated_source_holds_no_scenario_text():
    """Expression text is never pasted into the generated code: the kernels are made of
    temporaries, inputs, float literals, operators and the whitelisted math functions."""
    kind, params, _ = PATHS["expr-all-functions"]
    k = compile_path(build_path(kind, params))
    allowed = {"def", "return", "if", "else", "_sin", "_cos", "_tan", "_exp", "_log",
               "_sqrt", "_atan", "_tanh", "_pow", "_abs", "lam", "sigma2_expr",
               "sigma5_expr", "s4_expr"}
    for source in (k.sigma2.source, k.sigma5.source, k.s4.source):
        for word in re.findall(r"[A-Za-z_][A-Za-z_0-9]*", source):
            assert (word in allowed or re.fullmatch(r"t\d+|a\d+|[xyz]\d|e", word)), word


def test_untraceable_path_code_falls_back_to_the_jets():
    """A Python path that branches on a value cannot become straight-line code."""
    def s(x, y, z):
        return (y - cos(x), z - 5.0) if (x.c[0] if isinstance(x, Jet) else x) > -1e9 \
            else (y, z)

    def sigma(lam):
        return lam, cos(lam), 5.0 + 0.0 * lam

    path = Path("custom", s, sigma, (-3.0, 3.0))
    tracker, note = make_tracker(path)
    assert type(tracker) is PathTracker
    assert note.startswith("reference jets") and "cannot be compiled" in note


def test_a_path_that_cannot_be_evaluated_is_reported_not_raised():
    """log(x) off its domain: both trackers say so and the law falls back."""
    path = build_path("expr", {"s": ["y - log(x)", "z - 2"], "sigma": ["t", "log(t)", "2"],
                               "t_range": [0.5, 3.0]})
    rows = [[-0.2, 0, 0, 0, 0], [0.0, 0, 0, 0, 0], [2.0, 0, 0, 0, 0]]
    for tracker in (PathTracker(path), CompiledPathTracker(path)):
        tracker.lam = 0.5
        out = tracker.virtual_output(rows)
        assert not out.in_tube
        assert "path evaluation failed" in out.reason or "did not converge" in out.reason


@pytest.mark.parametrize(("scenario", "rotor"), [("paper", 0), ("paper", 3), ("circle", 0)])
def test_the_law_gives_the_same_thrusts_with_either_tracker(scenario, rotor):
    """The same recorded states into a law with the jets and one with the compiled tracker:
    the thrusts agree to rounding (1e-9 of f_max) tick by tick."""
    sc = load_scenario(scenario)
    if rotor:
        sc = sc.replace(**{"attack.rotor": rotor})
    sim, fast = Simulator(sc), build_controller(sc)
    ref = build_controller(sc)
    ref.tracker, ref.path_eval = make_tracker(ref.tracker.path, compiled=False)
    assert fast.path_eval == "compiled"
    fmax = sc.vehicle.thrust_max_n
    for _ in range(1500):
        m = sim.measured
        for ctrl in (ref, fast):
            if sim.attack.rotor:
                ctrl.set_attack(sim.attack.rotor, sim.attack.applied_n)
        st = State(m.position_m, m.velocity_mps, m.quaternion_wxyz, m.body_rates_radps)
        a, b = ref.update(st), fast.update(st)
        assert a.mode == b.mode and a.reason == b.reason
        assert np.allclose(a.rotor_thrust_n, b.rotor_thrust_n, rtol=0, atol=1e-9 * fmax)
        sim.set_command(b.rotor_thrust_n)
        sim.step_control_period()


@pytest.mark.parametrize("name", sorted(PATHS))
def test_inlined_kernels_equal_one_line_per_operation(name):
    """Writing single-use temporaries into their use keeps every operation and operand, so
    the kernels agree with the one-line-per-operation tape bit for bit (selects included)."""
    kind, params, y0 = PATHS[name]
    path = build_path(kind, params)
    fast, plain = compile_path(path), compile_path(path, inline=False)
    assert fast.s4.source.count("\n") < plain.s4.source.count("\n")
    pi_fast, pi_plain = pi_kernel().fn, pi_kernel(inline=False).fn
    rng = random.Random(3)
    for _ in range(50):
        lam = rng.uniform(*path.lam_range)
        assert fast.sigma2.fn((lam,)) == plain.sigma2.fn((lam,))
        c = fast.sigma5.fn((lam,))
        assert c == plain.sigma5.fn((lam,))
        rows = [tuple(r) for r in _random_rows(rng, y0, rng.uniform(-1, 1))]
        assert fast.s4.fn(*rows) == plain.s4.fn(*rows)
        slope = (-rng.uniform(0.1, 2.0),)
        assert pi_fast(c, *rows, slope) == pi_plain(c, *rows, slope)
