"""The steps the flight computer composes around the laws, compiled by the seam, return
what the Python steps return, bit for bit and type for type.

* The supervisor (the law, the reason and the start as ints, ``holding`` a bool, the state
  a :class:`SupervisorState`), over random and edge inputs in every mode — and along chains
  of ticks, where the hysteresis timers and the window shares build up.
* The TFL law's mass estimator fed a tick another law flew
  (:func:`~tfl_mav.control.tfl.tfl_controller.mass_observe`)."""

from __future__ import annotations

import math
import random
import struct

import pytest

from tfl_mav.accel import native
from tfl_mav.control.tfl.estimators import MassState, mass_model, mass_start
from tfl_mav.control.tfl.tfl_controller import mass_observe
from tfl_mav.controller.supervisor import (
    SupervisorInputs,
    SupervisorState,
    initial_state,
    supervise,
    supervisor_params,
)

pytestmark = pytest.mark.skipif(native.compiler() is None and not native.compiler_expected(),
                                reason="no C compiler, and none expected on this platform")

WEIGHT_N, FMAX_N = 0.75 * 9.81, 6.0


@pytest.fixture(scope="module")
def compiled():
    p = supervisor_params("auto", WEIGHT_N, FMAX_N, 1.0)
    u = SupervisorInputs(0.001, 0, math.nan, 0.0, False, False, (0.0,) * 4, math.nan,
                         (1.0, 0.0, 0.0, 0.0), (0.0,) * 3, (0.0,) * 3, math.nan, False)
    return native.build_function(supervise, (p, initial_state(), u))


def _same(a, b) -> bool:
    """Equal bits and types, leaf by leaf (any NaN equals any NaN: IEEE 754 leaves a NaN's
    sign and payload to the implementation)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float):
        return (a != a and b != b) or struct.pack("<d", a) == struct.pack("<d", b)
    return a == b


def _pick(rng: random.Random, *values: float) -> float:
    return rng.choice(values)


def _number(rng: random.Random, scale: float, *edges: float) -> float:
    """A value near a threshold, an edge (0, ±inf, NaN) or anywhere."""
    r = rng.random()
    if r < 0.15:
        return _pick(rng, 0.0, -0.0, math.nan, math.inf, -math.inf)
    if r < 0.5 and edges:
        return rng.choice(edges) + rng.choice((-1e-9, 0.0, 1e-9, rng.uniform(-0.3, 0.3)))
    return rng.uniform(-0.2 * scale, scale)


def _state(rng: random.Random) -> SupervisorState:
    law = rng.randrange(4)
    return SupervisorState(
        law, rng.random() < 0.5, _number(rng, 3.0, 1.0), _number(rng, 1.0, 0.5, 0.2),
        rng.random(), rng.random(), rng.random(), rng.random(),
        rng.choice((0, 1, 2, 3, 500, 20000)), rng.randrange(6), rng.uniform(0, 20),
        rng.uniform(0, 5), rng.uniform(0, 5), rng.uniform(0, 5), _number(rng, 0.5, 0.2))


def _inputs(rng: random.Random) -> SupervisorInputs:
    half = WEIGHT_N / 2.0
    a = _number(rng, 2 * FMAX_N, 0.35, 0.6, half, half + 0.25, half - 0.25, FMAX_N)
    demand = tuple(_number(rng, FMAX_N, 0.0, 1e-6, FMAX_N - 1e-6, FMAX_N) for _ in range(4))
    q = tuple(rng.gauss(0.0, 1.0) for _ in range(4)) if rng.random() < 0.8 else \
        rng.choice(((0.0,) * 4, (math.nan, 0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0)))
    tilt = rng.uniform(0.0, 0.8)
    if rng.random() < 0.3:              # near the take-over and hand-back tilts
        tilt = rng.choice((math.radians(20.0), math.radians(30.0))) + rng.uniform(-1e-3, 1e-3)
        q = (math.cos(tilt / 2), math.sin(tilt / 2), 0.0, 0.0)
    return SupervisorInputs(
        _number(rng, 0.01, 0.001, 0.0), rng.randrange(5), a, _number(rng, 0.5, 0.0),
        rng.random() < 0.8, rng.random() < 0.8, demand, _number(rng, 8.0, 4.0),
        q, tuple(_number(rng, 4.0, 2.0) for _ in range(3)),
        tuple(_number(rng, 3.0, 0.5, 2.0) for _ in range(3)), _number(rng, 8.0, 4.0),
        rng.random() < 0.5)


@pytest.mark.parametrize("mode", ["auto", "tfl", "safe"])
def test_the_compiled_supervisor_decides_as_the_python_one(compiled, mode):
    rng = random.Random(hash(mode) & 0xFFFF)
    for speed in (0.2, 1.0, 3.0):
        p = supervisor_params(mode, WEIGHT_N, FMAX_N, speed)
        for _ in range(4000):
            s, u = _state(rng), _inputs(rng)
            want, got = supervise(p, s, u), compiled(p, s, u)
            assert _same(got, want), (s, u, got, want)


@pytest.mark.parametrize("mode", ["auto", "tfl", "safe"])
def test_along_chains_of_ticks_the_timers_and_shares_agree(compiled, mode):
    """Each tick fed the state the Python step returned, the inputs drifting slowly (an
    attack ramping through the take-over, hand-back and pinned-high levels)."""
    rng = random.Random(7)
    p = supervisor_params(mode, WEIGHT_N, FMAX_N, 1.0)
    switches = 0
    for chain in range(60):
        s = initial_state(mode)
        u = _inputs(rng)._replace(dt_s=0.001, quaternion_wxyz=(1.0, 0.0, 0.0, 0.0),
                                  body_rates_radps=(0.0,) * 3, velocity_mps=(0.0,) * 3,
                                  path_distance_m=1.0, safe_distance_m=1.0,
                                  attack_std_n=0.05, rotor=chain % 5)
        for tick in range(600):
            a = 8.0 * tick / 600.0 if chain % 2 else 0.3 + 0.5 * math.sin(tick / 40.0)
            d = (u.demand_n[0] + rng.uniform(-0.5, 0.5), rng.uniform(-0.2, FMAX_N + 0.2),
                 rng.uniform(-0.2, 1.0), rng.uniform(FMAX_N - 1.0, FMAX_N + 0.2))
            u = u._replace(attack_n=a, demand_n=d, tfl_answer=rng.random() < 0.995,
                           spin_ready=tick > 100)
            want, got = supervise(p, s, u), compiled(p, s, u)
            assert _same(got, want), (chain, tick, s, u, got, want)
            s = want[0]
        switches += s.switches
    assert mode == "tfl" or switches > 0        # the chains reach the switching rules


def test_the_compiled_mass_observer_is_the_python_one():
    m = mass_model(0.75, 9.81, 0.1)
    example = (m, mass_start(0.75), 0.001, (1.0, 0.0, 0.0, 0.0), (0.0,) * 3, 1.0)
    compiled = native.build_function(mass_observe, example)
    rng = random.Random(2)
    s = mass_start(0.75)
    for k in range(20000):
        if k % 500 == 0:
            s = rng.choice((mass_start(rng.uniform(0.5, 1.0)), s))
        q = tuple(rng.gauss(0.0, 1.0) for _ in range(4)) if rng.random() < 0.97 else \
            rng.choice(((0.0,) * 4, (math.nan, 1.0, 0.0, 0.0), (math.inf, 0.0, 0.0, 0.0)))
        v = tuple(rng.gauss(0.0, 2.0) for _ in range(3))
        thrust = rng.choice((rng.uniform(0.0, 20.0), 0.0, math.nan))
        dt = rng.choice((0.001, 0.002, 0.0))
        try:
            want = mass_observe(m, s, dt, q, v, thrust)
        except (ZeroDivisionError, ValueError, OverflowError):
            want = None
        got = compiled(m, s, dt, q, v, thrust)
        assert (got is None) if want is None else _same(got, want), (s, dt, q, v, thrust)
        if want is not None and type(want) is MassState and want.mass_kg == want.mass_kg:
            s = want
