"""The law's compiled core (:mod:`tfl_mav.accel.native`) is the Python core bit for bit.

The C is translated from the Python core's own source; these tests hold the translation to
CPython's semantics operation by operation (values *and* where Python raises, which the
compiled core answers with ``None``), then whole controllers on random states for every
path kind, then whole flights against the golden results. Builds go to the session's kernel
cache (tests/conftest.py).
"""

from __future__ import annotations

import logging
import math
import os
import random
import struct
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.contract.test_accel import _bits as _tuple_bits
from tests.contract.test_compiled import PATHS
from tests.contract.test_step import random_state as _random_state
from tests.golden.test_golden import _LOCKSTEP, _OFFLINE
from tfl_mav.accel import native
from tfl_mav.control.path.kernelgen import compile_source
from tfl_mav.control.path.paths import build_path
from tfl_mav.control.tfl import step
from tfl_mav.control.tfl.tfl_controller import TFLController
from tfl_mav.from_scenario import law_config, model_params
from tfl_mav.model.state import State
from tfl_mav.scenario import load_scenario
from tfl_mav.sitl import physics
from tfl_mav.sitl.physics import RigidBodyParams, rk4_step, rk4_stepper
from tfl_mav.tools.harness.golden import (
    LOCKSTEP_CASES,
    OFFLINE_CASES,
    fly_lockstep,
    fly_offline_case,
)

# Where a compiler is expected (Linux: CI and every user machine we build for, or
# TFL_MAV_EXPECT_COMPILER=1), a missing one fails these contract tests instead of skipping
# them, so "compiled = Python, bit for bit" is never silently untested.
pytestmark = pytest.mark.skipif(native.compiler() is None and not native.compiler_expected(),
                                reason="no C compiler, and none expected on this platform")

# One function holding every operation the translation knows, chosen by k: one build.
_OPS = [
    "a / b", "a ** 2", "a ** 3", "a ** -1", "a ** -2", "_sqrt(a)", "_sin(a)", "_cos(a)",
    "_tan(a)", "_exp(a)", "_log(a)", "_atan(a)", "_tanh(a)", "_pow(a, b)", "abs(a)",
    "a if a < b else b", "1.0 if a <= b <= 2.0 else 0.0", "(-a) * b + a - b",
    "1.0 if not (a > b or a == 0.5) else 0.0", "1.0 if _isfinite(a) and a != b else 0.0",
    "_atan2(a, b)", "_copysign(a, b)", "_acos(a)", "_hypot(a, b)", "_asin(a)",
    "_remainder(a, b)",
]
_OPS_SOURCE = "def ops(k, a, b):\n    r = 0.0\n" + "".join(
    f"    if k == {i}:\n        r = {op}\n" for i, op in enumerate(_OPS)) + "    return (r,)\n"
_LOOP_SOURCE = """def loop(a, n):
    s = 0.0
    for _ in range(5):
        s += a
        if s >= n:
            break
    else:
        return None
    a += 1.0
    return (s, a)
"""
_SPECIAL = [-math.nan, 0.0, -0.0, 1.0, -1.0, 0.5, -2.5, 3.0, 2.0, 1e-320, -1e-320, 1e300, -1e300,
            1e154, 710.0, -746.0, math.pi, math.inf, -math.inf, math.nan, 1e22, 7.0e-9]


def _bits(x: float) -> bytes:
    return struct.pack("<d", x)


def _python(fn, *args):
    try:
        return fn(*args)
    except (ValueError, ZeroDivisionError, OverflowError):
        return None


def _same_bits(a, b) -> bool:
    """Equal to the bit, or both NaN: IEEE 754 leaves a NaN result's sign and payload
    unspecified, and a C compiler may swap the operands of a commutative operation."""
    return all(_bits(x) == _bits(y) or (math.isnan(x) and math.isnan(y))
               for x, y in zip(a, b, strict=True))


@pytest.fixture(scope="module")
def ops():
    py = compile_source("ops", _OPS_SOURCE, {"_isfinite": math.isfinite, "_atan2": math.atan2,
                                             "_copysign": math.copysign, "_acos": math.acos,
                                             "_hypot": math.hypot, "_asin": math.asin,
                                             "_remainder": math.remainder})
    return py, native.build(_OPS_SOURCE)


def test_every_operation_gives_pythons_bits_or_bails_where_python_raises(ops):
    py, c = ops
    for k, op in enumerate(_OPS):
        for a in _SPECIAL:
            for b in _SPECIAL:
                want, got = _python(py, float(k), a, b), c(float(k), a, b)
                if want is None:            # Python raises: the compiled core says None
                    assert got is None, (op, a, b, got)
                elif got is None:
                    # Only math.pow with a non-finite operand is declined on purpose
                    # (CPython special-cases those before calling libm's pow).
                    assert op == "_pow(a, b)" and not (math.isfinite(a) and math.isfinite(b)), \
                        (op, a, b, want)
                else:
                    assert _same_bits(want, got), (op, a, b, want, got)


def test_random_operands_agree_bit_for_bit(ops):
    py, c = ops
    rng = random.Random(5)
    for _ in range(4000):
        k = rng.randrange(len(_OPS))
        a, b = (rng.choice([rng.uniform(-10, 10), rng.gauss(0, 1e3), rng.uniform(0, 1e-3)])
                for _ in range(2))
        want, got = _python(py, float(k), a, b), c(float(k), a, b)
        assert (want is None and got is None) or _same_bits(want, got), (_OPS[k], a, b)


def test_loop_break_and_else_and_arguments_that_are_not_numbers():
    py = compile_source("loop", _LOOP_SOURCE)
    c = native.build(_LOOP_SOURCE)
    for a, n in [(1.0, 3.0), (0.5, 10.0), (2.0, 2.0), (math.nan, 1.0), (-1.0, -0.5)]:
        assert py(a, n) == c(a, n) or (py(a, n) is None and c(a, n) is None), (a, n)
    assert c(1, 2) == py(1, 2)          # ints convert as Python's mixed arithmetic does
    assert c("1.0", 2.0) is None        # not a number: declined, no exception
    with pytest.raises(TypeError, match="takes 2 arguments"):
        c(1.0)


_SEQ_SOURCE = """def seqs(a, p, q):
    x = 0.0
    if p is not None:
        (u, v), w = p
        x = u * v - w
    if q is None:
        return None
    i, j, k = q
    return (x, (i, (j, k)), a)
"""


def test_sequences_nested_unpacking_none_and_nested_results():
    py = compile_source("seqs", _SEQ_SOURCE)
    c = native.build(_SEQ_SOURCE)
    q3 = [(1.0, 2.0, 3.0), [1.0, 2.0, 3.0], np.array([1.0, 2.0, 3.0]), range(1, 4),
          (1, True, 3.0)]
    for p in [None, ((2.0, 3.0), 0.5), [[2.0, 3.0], 0.5], (np.array([2.0, 3.0]), 0.5)]:
        for q in q3:
            want = py(0.25, p, q)
            assert c(0.25, p, q) == want, (p, q)
        assert c(0.25, p, None) is None
    # what the Python core would reject, the compiled one declines (None), never raises
    for bad in [(1.0, 2.0), (1.0, 2.0, 3.0, 4.0), ("a", 2.0, 3.0), np.array([1.0, 2.0]),
                np.array([1, 2, 3], dtype=np.float32), np.arange(6.0)[::2], 5.0]:
        assert c(0.25, None, bad) is None, bad
    assert c(0.25, ((1.0,), 2.0), (1.0, 2.0, 3.0)) is None


def test_an_argument_passed_again_is_read_again_unless_it_cannot_change():
    """The compiled function remembers the numbers of an argument passed again as the same
    object only where they cannot change (tuples of numbers): a list, an array or a tuple
    holding a list changed in place between two calls gives the new numbers."""
    py = compile_source("seqs", _SEQ_SOURCE)
    c = native.build(_SEQ_SOURCE)
    frozen = ((2.0, 3.0), 0.5)
    for _ in range(3):                  # seen, checked, then read from the module's copy
        assert c(0.25, frozen, (1.0, 2.0, 3.0)) == py(0.25, frozen, (1.0, 2.0, 3.0))
    assert c(0.25, ((4.0, 3.0), 0.5), (1.0, 2.0, 3.0))[0] == 11.5    # another object
    inner, outer, arr = [2.0, 3.0], [[2.0, 3.0], 0.5], np.array([2.0, 3.0])
    for p, change in [((inner, 0.5), lambda: inner.__setitem__(0, inner[0] + 1.0)),
                      (outer, lambda: outer.__setitem__(1, outer[1] + 1.0)),
                      ((arr, 0.5), lambda: arr.__setitem__(1, arr[1] * 2.0))]:
        for _ in range(4):
            assert c(0.25, p, (1.0, 2.0, 3.0)) == py(0.25, p, (1.0, 2.0, 3.0)), p
            change()
    q = [1.0, 2.0, 3.0]
    for _ in range(3):
        assert c(0.25, None, q)[1] == (q[0], (q[1], q[2]))
        q[2] += 1.0


@pytest.mark.parametrize("src, match", [
    ("def f(a):\n    b = a.x\n    return (b,)\n", "cannot translate"),
    ("def f(a):\n    return (b,)\n", "never set"),
    ("def f(a):\n    b = a ** a\n    return (b,)\n", "int literal"),
    ("def f(a):\n    b = _erf(a)\n    return (b,)\n", "call of '_erf'"),
    ("def f(a):\n    b = a + 'x'\n    return (b,)\n", "not a number"),
])
def test_what_cannot_be_translated_is_refused_by_name(src, match):
    with pytest.raises(native.NativeError, match=match):
        native.translate(src, "_m")


def _controllers(path) -> TFLController:
    sc = load_scenario("paper")
    return TFLController(model_params(sc), path, law_config(sc), 0.001)


def _pair(path, monkeypatch):
    monkeypatch.setenv("TFL_MAV_NATIVE", "off")
    py = _controllers(path)
    monkeypatch.setenv("TFL_MAV_NATIVE", "sync")
    c = _controllers(path)
    assert py.core == "python" and c.core == "compiled"
    return py, c


def _paths_under_test():
    fast = {"paper", "expr-all-functions"}
    return [pytest.param(n, marks=() if n in fast else pytest.mark.slow) for n in sorted(PATHS)]


@pytest.mark.parametrize("name", _paths_under_test())
def test_compiled_core_flies_the_python_cores_bits_on_random_states(name, monkeypatch):
    kind, params, y0 = PATHS[name]
    path = build_path(kind, params)
    rng = random.Random(23)
    py, c = _pair(path, monkeypatch)
    for trial in range(40):
        rotor = (0, 0, 2, 3)[trial % 4]
        for ctrl in (py, c):
            ctrl.set_attack(rotor, 1.0 if rotor else 0.0)
        st = _random_state(rng, y0)
        for tick in range(3):
            if tick:
                st = State(tuple(p + 1e-3 * v for p, v in zip(st.position_m, st.velocity_mps,
                                                              strict=True)),
                           st.velocity_mps, st.quaternion_wxyz, st.body_rates_radps)
            if trial % 2:       # the daemon's and the simulator's states are numpy arrays
                # (float64, read in place by the compiled step; float32 too, as floats)
                dtype = np.float32 if trial % 4 == 3 else float
                st = State(*(np.array(f, dtype=dtype) for f in (
                    st.position_m, st.velocity_mps, st.quaternion_wxyz, st.body_rates_radps)))
            assert repr(py.update(st)) == repr(c.update(st))


def _leaves(x):
    if isinstance(x, (tuple, list)):
        for v in x:
            yield from _leaves(v)
    else:
        yield x


def test_the_lowered_step_run_as_python_is_the_step(monkeypatch):
    """What the seam's front end makes of the step (calls inlined, loops unrolled, tuples
    scalar-replaced), run as Python with no C at all, gives the step's bits: the lowering
    itself is exact, before the translation to C."""
    from tfl_mav.accel import frontend
    from tfl_mav.accel.lowering_values import INTRINSICS

    monkeypatch.setenv("TFL_MAV_NATIVE", "off")
    law = _controllers(build_path("paper", {}))
    example = law.step_arguments(State((0.0,) * 3, (0.0,) * 3, (1.0, 0.0, 0.0, 0.0), (0.0,) * 3))
    namespace = {name: fn for fn, name in INTRINSICS.items()} | {
        "_inf": math.inf, "_nan": math.nan, "_int": int,
        "_index": lambda k, *items: items[k]}     # the rotor permutation's variable index
    exec(compile(frontend.lower(step.tfl_step, example), "<lowered tfl_step>", "exec"),
         namespace)
    lowered = namespace["tfl_step"]
    rng = random.Random(11)
    for trial in range(30):
        rotor = (0, 0, 2, 3)[trial % 4]
        law.set_attack(rotor, 1.0 if rotor else 0.0)
        st = _random_state(rng, PATHS["paper"][2])
        for _ in range(3):
            args = law.step_arguments(st, 0.3, True, False)
            want = step.tfl_step(*args)
            got = lowered(*args)
            assert [_bits(float(x)) for x in _leaves(got)] == \
                [_bits(float(x)) for x in _leaves(want)]
            law.update(st)


@pytest.mark.parametrize("name", sorted(OFFLINE_CASES))
def test_offline_golden_flights_are_bit_identical_compiled(name, monkeypatch):
    monkeypatch.setenv("TFL_MAV_NATIVE", "sync")
    assert fly_offline_case(*OFFLINE_CASES[name]) == _OFFLINE[name]


@pytest.mark.slow
@pytest.mark.parametrize("name", ["paper", "lag20ms"])
def test_lockstep_golden_flights_are_bit_identical_compiled(name, tmp_path, monkeypatch):
    monkeypatch.setenv("TFL_MAV_NATIVE", "sync")    # the daemon subprocess inherits it
    assert fly_lockstep(*LOCKSTEP_CASES[name], out=tmp_path) == _LOCKSTEP[name]


@pytest.mark.slow
def test_auto_switches_to_the_compiled_core_mid_flight_without_changing_a_bit(
        tmp_path, monkeypatch):
    """A cold cache: the controller flies the Python core while the compiler runs in the
    background, then switches; the outputs are those of a Python-only controller."""
    monkeypatch.setenv("TFL_MAV_KERNEL_CACHE", str(tmp_path / "cold"))
    native.forget()                                 # as a new process: nothing loaded yet
    path = build_path("paper", {})
    monkeypatch.setenv("TFL_MAV_NATIVE", "off")
    py = _controllers(path)
    monkeypatch.setenv("TFL_MAV_NATIVE", "auto")
    c = _controllers(path)
    assert c.core == "python"
    rng = random.Random(3)
    st = _random_state(rng, PATHS["paper"][2])
    deadline = time.monotonic() + 120.0     # a compile of ~1 s, on a loaded 2-core box
    ticks_before = 0
    while c.core == "python" and time.monotonic() < deadline:
        assert repr(py.update(st)) == repr(c.update(st))
        ticks_before += 1
        time.sleep(0.001)
    assert c.core == "compiled", "the background build never completed"
    assert ticks_before > 0
    for _ in range(50):
        assert repr(py.update(st)) == repr(c.update(st))


def test_no_compiler_leaves_the_python_core_flying_with_one_warning(monkeypatch, caplog,
                                                                    tmp_path):
    monkeypatch.setenv("TFL_MAV_KERNEL_CACHE", str(tmp_path / "empty"))
    native.forget()                                 # as a new process: nothing warned yet
    monkeypatch.setenv("CC", str(tmp_path / "no-such-cc"))
    monkeypatch.setenv("TFL_MAV_NATIVE", "sync")
    path = build_path("paper", {})
    with caplog.at_level(logging.WARNING, logger="tfl_mav.accel.native"):
        a = _controllers(path)
        b = _controllers(path)
    assert a.core == b.core == "python"
    warnings = [r for r in caplog.records if "no C compiler" in r.getMessage()]
    assert len(warnings) == 1


def test_a_bad_mode_is_named_and_means_off(monkeypatch, caplog):
    monkeypatch.setenv("TFL_MAV_NATIVE", "fast")
    with caplog.at_level(logging.WARNING, logger="tfl_mav.accel.native"):
        assert native.mode() == "off"
    assert "TFL_MAV_NATIVE='fast'" in caplog.text


@pytest.mark.parametrize("tau_s", [0.0, 0.03])
def test_detector_compiled_step_gives_the_python_steps_verdicts(tau_s, monkeypatch):
    """The detector's pure step compiled through the seam (detector_step) against the
    Python step: the same outputs and state, bit for bit, through noise, an attack that
    starts and moves, NaN and out-of-range rpm samples, non-finite commands, time glitches
    and the motors stopped a while."""
    from tfl_mav.control.detect.detector import AttackDetector

    def make(mode):
        monkeypatch.setenv("TFL_MAV_NATIVE", mode)
        return AttackDetector(1.2e-5, 8.0, tau_s, 0.001)

    py, c = make("off"), make("sync")
    assert not py.compiled and c.compiled
    rng = random.Random(7)
    hover = 1.2 * 9.81 / 4.0
    t = 0.0
    for tick in range(3000):
        t += 0.001 if tick % 97 else rng.choice([0.001, math.nan, -0.5, 0.0005])
        cmd = [hover + rng.gauss(0, 0.3) for _ in range(4)]
        if tick % 211 == 0:
            cmd[rng.randrange(4)] = rng.choice([math.nan, math.inf, -1.0, 9.0])
        rpm = [60.0 / (2 * math.pi) * math.sqrt(max(min(f, 8.0), 0.0) / 1.2e-5)
               + rng.gauss(0, 20.0) if f == f and abs(f) != math.inf else 0.0 for f in cmd]
        attacked = 1 + (tick // 1000) % 4
        if tick > 500:
            rpm[attacked - 1] *= 1.3
        if tick % 173 == 0:
            rpm[rng.randrange(4)] = rng.choice([math.nan, 2e6, -math.inf])
        if tick in (1500, 1600):
            for d in (py, c):
                d.set_motors_off(tick == 1500)
        a, b = py.update(t, rpm, cmd), c.update(t, rpm, cmd)
        assert repr(a) == repr(b), tick
    assert py.detected_rotor and py.rejected_samples > 0 and py.moves and py.paused_ticks
    def plain(x):
        return tuple(plain(v) for v in x) if isinstance(x, tuple) else x

    assert repr(plain(py.state)) == repr(plain(c.state))


_STATE = st.one_of(st.floats(-5.0, 5.0), st.floats(allow_nan=True, allow_infinity=True))
_AIRFRAME = st.builds(
    RigidBodyParams, st.floats(0.0, 50.0), st.tuples(*[st.floats(0.0, 1.0)] * 3),
    st.floats(0.05, 1.0), st.floats(0.0, 0.1), st.floats(0.0, 1.0), st.floats(0.0, 0.1),
    st.floats(0.0, 20.0))


@pytest.fixture(scope="module")
def rk4_core():
    return native.build_function(rk4_step, physics.RK4_STEP_EXAMPLE)


@settings(max_examples=500, deadline=None)
@given(p=_AIRFRAME, x=st.tuples(*[_STATE] * 13),
       wrench=st.tuples(st.floats(0.0, 40.0), *[st.floats(-1.0, 1.0)] * 3),
       h=st.one_of(st.sampled_from([1e-3, 5e-4, 1e-2]), st.floats(0.0, 0.1)))
def test_the_compiled_rk4_step_is_the_python_one_bit_for_bit(rk4_core, p, x, wrench, h):
    """physics.rk4_step compiled through the seam (one build for every airframe: the
    constants are an argument) gives the Python step's bits, on any airframe, state and
    wrench; where the Python step raises (a zero mass, inertia or quaternion norm, ``**``
    overflowing) it declines with None."""
    try:
        want = rk4_step(p, x, wrench, h)
    except (ZeroDivisionError, OverflowError):
        want = None
    got = rk4_core(p, x, wrench, h)
    if want is None:
        assert got is None
    else:
        assert got is not None and _tuple_bits(got) == _tuple_bits(want)


def test_the_simulators_rk4_step_flies_compiled_and_python_decides_otherwise(monkeypatch):
    """The simulator's step (physics.rk4_stepper) runs the compiled rk4_step once it is
    built — one core for every airframe — and gives the Python step's bits (repr: -0.0 and
    0.0 differ); a diverging state still takes the Python path (which raises for the
    simulator's numpy fallback), and so does a state of numpy scalars."""
    monkeypatch.setenv("TFL_MAV_NATIVE", "sync")
    rng = random.Random(4)
    cores = set()
    for mass, inertia in ((1.2, (0.011, 0.013, 0.021)), (0.6, (0.002, 0.0021, 0.004))):
        p = RigidBodyParams(mass_kg=mass, inertia_kgm2=inertia, k_t=0.05, k_r=0.00275,
                            gravity_mps2=9.81, arm_m=0.2656, drag_thrust_ratio_m=0.02)
        py, c = rk4_stepper(p, compiled=False), rk4_stepper(p)
        assert physics.compiled_rk4_step() is not None
        cores.add(id(physics.compiled_rk4_step()))
        for _ in range(2000):
            x = [rng.uniform(-5, 5) for _ in range(13)]
            w = (rng.uniform(0, 30), rng.gauss(0, 1), rng.gauss(0, 1), rng.gauss(0, 0.1))
            h = rng.choice([1e-3, 5e-4, 1e-2])
            assert repr(py(x, w, h)) == repr(c(x, w, h))
    assert len(cores) == 1
    huge = [0.0] * 6 + [1e160, 0.0, 0.0, 0.0] + [0.0] * 3     # |q|² overflows
    with pytest.raises(OverflowError):
        py(huge, (10.0, 0.0, 0.0, 0.0), 1e-3)
    with pytest.raises(OverflowError):
        c(huge, (10.0, 0.0, 0.0, 0.0), 1e-3)
    scalars = [np.float64(v) for v in x]
    with np.errstate(all="ignore"):
        b = c(scalars, w, h)
        assert type(b[0]) is np.float64 and repr(py(scalars, w, h)) == repr(b)


@pytest.mark.slow
def test_one_build_per_source_and_a_cache_that_cannot_be_written(tmp_path, monkeypatch, caplog):
    """Many asks for one source in auto mode queue one build, and every asker gets the
    core; a cache directory that cannot be created is a warning, not an error."""
    monkeypatch.setenv("TFL_MAV_KERNEL_CACHE", str(tmp_path / "cold"))
    monkeypatch.setenv("TFL_MAV_NATIVE", "auto")
    native.forget()
    got: list = []
    source = _LOOP_SOURCE.replace("loop", "loop_once")
    for _ in range(5):
        assert native.obtain(source, got.append) is None
    assert native.waiting(source) == 5
    deadline = time.monotonic() + 120.0
    while len(got) < 5 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert len(got) == 5 and len({id(c) for c in got}) == 1
    assert native.obtain(source, got.append) is got[0]      # loaded: at once, no rebuild
    blocker = tmp_path / "file"
    blocker.write_text("")
    monkeypatch.setenv("TFL_MAV_KERNEL_CACHE", str(blocker / "kernels"))
    monkeypatch.setenv("TFL_MAV_NATIVE", "sync")
    with caplog.at_level(logging.WARNING, logger="tfl_mav.accel.native"):
        assert native.obtain(source.replace("loop_once", "loop_ro"), got.append) is None
    assert "not available" in caplog.text


def test_a_build_left_behind_by_an_exited_process_is_swept(tmp_path, monkeypatch):
    """Builds run in the cache directory; one older than an hour (its process exited
    mid-build) is removed by the next build, a fresh one (a build under way) is not."""
    cache = tmp_path / "kernels"
    cache.mkdir()
    monkeypatch.setenv("TFL_MAV_KERNEL_CACHE", str(cache))
    native.forget()
    old, fresh = cache / ".build-old", cache / ".build-fresh"
    for d in (old, fresh):
        d.mkdir()
        (d / "k.c").write_text("int x;")
    two_hours_ago = time.time() - 7200
    os.utime(old, (two_hours_ago, two_hours_ago))
    native.build(_LOOP_SOURCE.replace("loop", "loop_swept"))
    assert not old.exists() and fresh.exists()
    assert not [p for p in cache.iterdir() if p.name.startswith(".build-") and p != fresh]


def test_safe_law_three_rotor_step_compiled_is_the_python_step():
    """lost_rotor.lost_rotor_step compiled from its own source (thrust_direction inlined, no
    hand-written twin) against the Python function on random inputs: the same floats, bit
    for bit."""
    from tfl_mav.control.safe import lost_rotor
    compiled = native.build_function(lost_rotor.lost_rotor_step, lost_rotor.STEP_EXAMPLE)
    rng = random.Random(11)
    rots = [(1, 0, 0, 0, 1, 0), (0, -1, 0, 1, 0, 0), (-1, 0, 0, 0, -1, 0), (0, 1, 0, -1, 0, 0)]
    for trial in range(500):
        q = [rng.uniform(-1, 1) for _ in range(4)]
        n = math.sqrt(sum(c * c for c in q))
        args = (tuple(rng.uniform(-8, 8) for _ in range(3)),
                tuple(rng.uniform(-3, 3) for _ in range(3)), tuple(c / n for c in q),
                (rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-80, 80)),
                rots[trial % 4], tuple(rng.uniform(-2, 2) for _ in range(8)),
                (1.1, 0.05, 9.81, 0.2656, 8.0), rng.choice([0.0, 0.3, 2.0, -1.0, 9.0]))
        assert repr(compiled(*args)) == repr(lost_rotor.lost_rotor_step(*args))


def _spin_law_paper():
    from tfl_mav.control.spin import law as spin_law
    sc = load_scenario("paper")
    params = spin_law.build(sc.vehicle, 2, sc.run.control_dt_s)
    return params, (params, spin_law.initial_state(params), spin_law.STEP_INPUTS_EXAMPLE)


def test_spin_law_step_lowers():
    """The seam's front end lowers spin_step whole (no construct it declines): what the
    compiled == Python test below builds, without the ~15 s of compiler."""
    from tfl_mav.control.spin.step import spin_step
    _, example = _spin_law_paper()
    assert "def spin_step(" in native.lowered(spin_step, example)


@pytest.mark.slow       # a 2 MB kernel (the table's rows picked by index): ~15 s of compiler
def test_spin_law_step_compiled_is_the_python_step():
    """spin_step compiled from its own source (the table's rows picked by the measured
    f_stuck, the gains by ρ, the allocation's clipping) against the Python function, tick by
    tick from random states and measurements: f_stuck across the table and beyond its
    ends, fast and slow spins, the mean's circle removed or not; the same floats, bit for
    bit. A SpinLaw flies the compiled step once it is built."""
    from tfl_mav.control.spin import law as spin_law
    from tfl_mav.control.spin.step import SpinInputs, SpinState, spin_step
    params, example = _spin_law_paper()
    compiled = native.build_function(spin_step, example)
    held = spin_law.SpinLaw(params)     # built now: it finds the build in the cache
    assert held.compiled
    lo, hi = params.table[0].hover.f_stuck_n, params.table[-1].hover.f_stuck_n
    rng = random.Random(17)
    state = spin_law.initial_state(params)
    clipped = 0
    for trial in range(3000):
        q = [rng.gauss(0, 0.3) + (1.0 if k == 0 else 0.0) for k in range(4)]
        n = math.sqrt(sum(c * c for c in q))
        f = rng.choice([lo, hi, params.table[3].hover.f_stuck_n, rng.uniform(lo - 1, hi + 1),
                        rng.uniform(lo, hi)])
        u = SpinInputs(tuple(rng.uniform(-3, 3) for _ in range(3)),
                       tuple(rng.gauss(0, 2) for _ in range(3)), tuple(c / n for c in q),
                       (rng.gauss(0, 5), rng.gauss(0, 5), rng.uniform(-70, 70)), f,
                       tuple(rng.uniform(-3, 3) for _ in range(3)),
                       tuple(rng.gauss(0, 1) for _ in range(3)),
                       tuple(rng.gauss(0, 1) for _ in range(3)))
        if trial % 7 == 0:
            state = SpinState(tuple(rng.uniform(-1, 1) for _ in range(3)), rng.uniform(0, 3),
                              rng.uniform(0, 30))
        a, b = compiled(params, state, u), spin_step(params, state, u)
        assert repr(a) == repr(b), trial
        assert repr(held.step(state, u)) == repr(b), trial
        state = b[0]
        clipped += b[1].clipped
    assert 0 < clipped < 3000       # both sides of the allocation's limits were flown


def test_coning_hover_step_compiled_is_the_python_step():
    """cone_step compiled from its own source against the Python function, for each
    attacked rotor's frame, tick by tick from random states and measurements: tilted and
    spinning bodies, a pinned thrust from none to past f_max/2 (the allocation clipping
    both ways, the anti-windup frozen), the phase carried round past ±π; the same floats,
    bit for bit. A ConeLaw flies the compiled step once it is built."""
    from tfl_mav.control.spin.cone import (
        CONE_START,
        ConeInputs,
        ConeLaw,
        ConeState,
        cone_params,
        cone_step,
    )
    sc = load_scenario("paper")
    rng = random.Random(23)
    for rotor in (1, 2, 3, 4):
        params = cone_params(sc.vehicle, rotor, sc.run.control_dt_s)
        compiled = native.build_function(cone_step, (params, CONE_START, ConeInputs(
            *(((0.0,) * 3,) * 2), (1.0, 0.0, 0.0, 0.0), (0.0,) * 3, 0.0, *(((0.0,) * 3,) * 3))))
        held = ConeLaw(params)      # made now: it finds the build in the cache
        assert held.compiled
        state, clipped = CONE_START, 0
        for trial in range(1500):
            q = [rng.gauss(0, 0.4) + (1.0 if k == 0 else 0.0) for k in range(4)]
            n = math.sqrt(sum(c * c for c in q))
            u = ConeInputs(tuple(rng.uniform(-3, 3) for _ in range(3)),
                           tuple(rng.gauss(0, 2) for _ in range(3)), tuple(c / n for c in q),
                           (rng.gauss(0, 5), rng.gauss(0, 5), rng.uniform(-40, 40)),
                           rng.uniform(0.0, 1.2 * params.thrust_max_n),
                           tuple(rng.uniform(-3, 3) for _ in range(3)),
                           tuple(rng.gauss(0, 1) for _ in range(3)),
                           tuple(rng.gauss(0, 1) for _ in range(3)))
            if trial % 11 == 0:
                state = ConeState(rng.uniform(-4.0, 4.0),
                                  tuple(rng.uniform(-2, 2) for _ in range(3)))
            a, b = compiled(params, state, u), cone_step(params, state, u)
            assert repr(a) == repr(b), (rotor, trial)
            assert repr(held.step(state, u)) == repr(b), (rotor, trial)
            state = b[0]
            clipped += b[1].clipped
        assert 0 < clipped < 1500   # both sides of the allocation's limits were flown
    # no attitude measured at all (a zero quaternion): read as it is, the same bits
    u = ConeInputs((0.0,) * 3, (0.0,) * 3, (0.0, 0.0, 0.0, 0.0), (0.0,) * 3, 4.0,
                   (0.0,) * 3, (0.0,) * 3, (0.0,) * 3)
    assert repr(compiled(params, CONE_START, u)) == repr(cone_step(params, CONE_START, u))


@pytest.mark.parametrize("held", [False, True])
def test_safe_law_attacked_tick_compiled_is_the_python_tick(held, monkeypatch):
    """RecoveryLaw's attacked tick (safe_step.safe_tick on the paper path's σ: projection,
    outer loop, three-rotor step, anti-windup) compiled against the same law flying its
    Python step, tick by tick from random states (half of them near the target, where the
    integral learns), every rotor attacked: the same outputs and the same state (λ, the
    integral, the held point, the drift filter), bit for bit."""
    from tfl_mav.controller.flight_computer import FlightComputer

    def law(mode):
        monkeypatch.setenv("TFL_MAV_NATIVE", mode)
        return FlightComputer(load_scenario("paper")).recovery

    py, c = law("off"), law("sync")
    assert py.core == "python" and c.core == "compiled"
    rng = random.Random(3)
    # A start every 600 ticks: the integral learns only once the law has flown SETTLE_TAU_S
    # (0.5 s, 500 ticks at 1 kHz) since it started.
    for trial in range(1800):
        if trial % 600 == 0:
            hold = [rng.uniform(-3, 3), 0.0, 4.0]
            for lw in (py, c):      # λ from a global search; then the point to hold
                lw.follow_path(search=True)
                if held:
                    lw.hold(hold)
        q = [rng.gauss(0, 0.1) + (1.0 if k == 0 else 0.0) for k in range(4)]
        if trial % 2:     # anywhere
            y = [rng.uniform(-4, 4), rng.uniform(-1, 1), rng.uniform(2, 8)]
        else:             # within the integral's band of the target, where it learns
            x = rng.uniform(-3, 3)
            y = (list(hold) if held else [x, math.cos(x), 8.0 - 4.0 * math.cos(x)])
            y = [c + rng.uniform(-0.02, 0.02) for c in y]
        s = State(position_m=np.array(y),
                  velocity_mps=np.array([rng.gauss(0, 1) for _ in range(3)]),
                  quaternion_wxyz=np.array(q),
                  body_rates_radps=np.array([rng.gauss(0, 2), rng.gauss(0, 2),
                                             rng.uniform(-70, 70)]))
        rotor, attack = 1 + trial % 4, rng.choice([0.0, 0.5, 2.0, 7.0])
        a, b = py.update(s, rotor, attack), c.update(s, rotor, attack)
        assert repr(a) == repr(b), trial
        assert repr((py.integral_mps2, py.hold_m, py.path_lam, py.drift_mps,
                     py.drift_age_s, py.attack_lp_n)) == \
            repr((c.integral_mps2, c.hold_m, c.path_lam, c.drift_mps, c.drift_age_s,
                  c.attack_lp_n)), trial
    assert any(x != 0.0 for x in py.integral_mps2)


def test_a_compiler_is_there_where_one_is_expected():
    """On Linux the compiled cores are part of the product: no compiler is a failure."""
    if native.compiler_expected():
        assert native.compiler() is not None, \
            "no C compiler (cc or $CC) with Python's headers: install gcc and python3-dev"
