"""The law's one pure step (:mod:`tfl_mav.control.tfl.step`) flies the reference jets'
numbers, to rounding, on random states for every path kind; it falls back where the
reference does, for the same reason; and it is pure.

The reference is the same law on :class:`tracker.PathTracker` (``compiled_path=False``):
its virtual output, on jets, stands in for :func:`step.project` (the path's generated
kernels), so this holds the projection, π, α and Dφ of the step to the reference.
"""

from __future__ import annotations

import math
import random

import pytest

from tests.contract.test_compiled import PATHS, _normwise
from tfl_mav.control.path.paths import build_path
from tfl_mav.control.tfl import step
from tfl_mav.control.tfl.tfl_controller import TFLController
from tfl_mav.from_scenario import law_config, model_params
from tfl_mav.model.modes import Mode
from tfl_mav.model.state import State
from tfl_mav.scenario import load_scenario

_SC = load_scenario("paper")


def _pair(path, cfg=None):
    cfg = cfg or law_config(_SC)
    ref = TFLController(model_params(_SC), path, cfg, 0.001, compiled_path=False)
    fast = TFLController(model_params(_SC), path, cfg, 0.001)
    assert ref.core == "reference jets" and fast.core in ("python", "compiled")
    return ref, fast


def random_state(rng: random.Random, y0) -> State:
    """Near y0, moving, tilted up to ~15°, spinning (rates up to 3 rad/s about b1, b2 and up
    to 40 rad/s about b3, as under attack)."""
    ax = [rng.uniform(-1, 1) for _ in range(3)]
    n = math.sqrt(sum(a * a for a in ax)) or 1.0
    half = 0.5 * rng.uniform(0.0, 0.26)
    quat = (math.cos(half), *(math.sin(half) * a / n for a in ax))
    return State(tuple(c + rng.uniform(-0.05, 0.05) for c in y0),
                 tuple(rng.uniform(-0.6, 0.6) for _ in range(3)), quat,
                 (rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(-40, 40)))


def _same(a, b) -> None:
    assert a.mode == b.mode and a.reason == b.reason
    assert _normwise(a.rotor_thrust_n, b.rotor_thrust_n) <= 1e-9
    assert a.saturated == b.saturated
    for u, v in [*zip(a.xi, b.xi, strict=True), (a.eta[1:], b.eta[1:]),
                 ((a.cond_d, a.thrust_n), (b.cond_d, b.thrust_n))]:
        assert _normwise(u, v) <= 1e-9
    assert b.eta[0] == pytest.approx(a.eta[0], rel=0, abs=1e-12)
    assert b.lam == pytest.approx(a.lam, rel=0, abs=1e-12 * (1 + abs(a.lam)))


@pytest.mark.parametrize("name", sorted(PATHS))
def test_the_step_flies_the_reference_jets_numbers(name):
    kind, params, y0 = PATHS[name]
    path = build_path(kind, params)
    rng = random.Random(17)
    flown = 0
    for trial in range(25):
        ref, fast = _pair(path)
        rotor = (0, 0, 2, 3)[trial % 4]
        for ctrl in (ref, fast):
            ctrl.set_attack(rotor, 1.0 if rotor else 0.0)
        st = random_state(rng, y0)
        for tick in range(4):       # cold start (a global search), then warm-started ticks
            if tick:
                st = State(tuple(p + 1e-3 * v for p, v in zip(st.position_m,
                                                              st.velocity_mps, strict=True)),
                           st.velocity_mps, st.quaternion_wxyz, st.body_rates_radps)
            a, b = ref.update(st), fast.update(st)
            _same(a, b)
            flown += a.mode is not Mode.FALLBACK
    assert flown >= 50                  # most random states fly: the comparison is not empty


def test_fallbacks_are_the_references_with_the_same_reason():
    """With too little thrust, or far from the path, the step damps the rates, holds the
    thrust and says why, exactly as the reference does."""
    kind, params, y0 = PATHS["paper"]
    ref, fast = _pair(build_path(kind, params))
    st = State(y0, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    _same(ref.update(st), fast.update(st))
    for ctrl in (ref, fast):
        ctrl.x13 = 0.1                                   # below min_thrust_n
    a, b = ref.update(st), fast.update(st)
    _same(a, b)
    assert b.mode is Mode.FALLBACK and "too small" in b.reason
    assert fast.fallback_count == 1
    far = State((y0[0], y0[1] + 0.5, y0[2]), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0),
                (0.0, 0.0, 0.0))
    a, b = ref.update(far), fast.update(far)
    _same(a, b)
    assert b.mode is Mode.FALLBACK
    assert all(math.isfinite(f) for f in b.rotor_thrust_n)


def test_a_path_that_raises_is_a_fallback_that_says_so():
    """The path's code raising where the vehicle is (log of 0 at x = −1) is the projection
    lost, in words, as in the reference — never an exception out of the law."""
    path = build_path("expr", {"s": ["y + 0.001*log(x + 1)", "z - 2"],
                               "sigma": ["t", "-0.001*log(t + 1)", "2"], "t_range": [-0.5, 5]})
    ref, fast = _pair(path)
    outs = []
    for k in range(11):         # along the path from x = −0.9 to x = −1.0
        st = State((-0.9 - 0.01 * k, 0.0, 2.0), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0),
                   (0.0, 0.0, 0.0))
        a, b = ref.update(st), fast.update(st)
        assert a.mode == b.mode and a.rotor_thrust_n == b.rotor_thrust_n
        outs.append(b)
    assert all(o.mode is Mode.NOMINAL for o in outs[:-1])
    last = outs[-1]
    assert last.mode is Mode.FALLBACK
    assert last.reason.startswith("left the projection tube: path evaluation failed")
    assert all(math.isfinite(f) for f in last.rotor_thrust_n)


def test_the_step_is_pure():
    """The same (params, state, inputs) give the same (state, outputs), bit for bit; the
    state given is not changed (every piece of it is an immutable tuple)."""
    kind, params, y0 = PATHS["circle"]
    law = TFLController(model_params(_SC), build_path(kind, params), law_config(_SC), 0.001)
    law.set_attack(3, 1.2)
    rng = random.Random(2)
    for _ in range(5):
        law.update(random_state(rng, y0))
    params, s, u, kernels = law.step_arguments(State((2.5, 0.2, 4.5), (0.1, 0.2, 0.0),
                                                     (1.0, 0.0, 0.0, 0.0), (0.1, 0.2, 9.0)))
    assert u.attack_n == 1.2 and kernels is not None
    before = repr(s)
    first = step.tfl_step(params, s, u, kernels)
    second = step.tfl_step(params, s, u, kernels)
    assert repr(first) == repr(second) and repr(s) == before
    assert all(isinstance(x, tuple) for x in (s.mass, s.dob, s.path, s.pred, s.last_out))
