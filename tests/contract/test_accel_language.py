"""The seam's language beyond floats: booleans, IntEnum codes, NamedTuples returned as
themselves, an index known only at run time, several returns, ``and``/``or`` that call a
function. Compiled, a function returns what Python returns — the same bits *and* the same
types (an int stays an int, a bool a bool, a NamedTuple its class) — or None where Python
raises."""

from __future__ import annotations

import math
import random
import struct
from collections.abc import Callable
from enum import IntEnum
from typing import NamedTuple

import pytest

from tfl_mav.accel import native
from tfl_mav.accel.lowering_values import INTRINSICS

pytestmark = pytest.mark.skipif(native.compiler() is None and not native.compiler_expected(),
                                reason="no C compiler, and none expected on this platform")


class Code(IntEnum):
    CALM = 0
    HIGH = 3
    LOW = 7


class Memory(NamedTuple):
    code: int
    armed: bool
    count: int
    level: float


class Reading(NamedTuple):
    rotor: int                  # 1-4, 0: none
    values: tuple[float, float, float, float]
    valid: bool


def _judge(m: Memory, x: float) -> tuple[Memory, int]:
    """Several returns, an IntEnum's code, a bool kept."""
    if x != x:
        return m._replace(armed=False), int(Code.CALM)
    if x > 2.0:
        if m.armed:
            return m._replace(code=int(Code.HIGH), count=m.count + 1), int(Code.HIGH)
        return m._replace(armed=True), int(Code.CALM)
    if x < -2.0 and m.armed:
        return Memory(int(Code.LOW), False, m.count + 1, x), int(Code.LOW)
    return m, m.code


def _fall_through(x: float) -> tuple[float, int]:
    """A return on one path of a branch whose other path falls through to what follows."""
    y = x
    if x > 0.0:
        if x > 3.0:
            return y, 1
        y = y * 2.0
    y = y + 1.0
    if y > 2.5:
        return y, 2
    return y - 0.5, 3


def _root(x: float) -> float:
    return math.sqrt(x)


def language(m: Memory, r: Reading, x: float) -> tuple[Memory, tuple[int, float, bool]]:
    i = r.rotor - 1
    opposite = r.values[(i + 2) % 4]               # an index known when it runs
    first = r.values[i] if r.rotor else 0.0
    big = r.valid and opposite > 1.0
    either = r.rotor or x                           # Python's operand, not 0 or 1
    rooted = x >= 0.0 and _root(x) > 1.5            # a call on one path of the and
    m, code = _judge(m, x + opposite)
    flag = bool(first) and not big
    y, path = _fall_through(x)
    return m, (code + path, either + first + y, flag or rooted)


def _bits(v):
    if isinstance(v, tuple):
        return (type(v), tuple(_bits(x) for x in v))
    if isinstance(v, float):
        return (float, "nan" if v != v else struct.pack("<d", v))
    return (type(v), v)


def _python(*args):
    try:
        return language(*args)
    except (ValueError, ZeroDivisionError, OverflowError, IndexError):
        return None


@pytest.fixture(scope="module")
def compiled():
    return native.build_function(language, (Memory(0, False, 0, 0.0),
                                            Reading(1, (0.0,) * 4, True), 0.0))


def _x(rng: random.Random) -> float:
    return rng.choice((math.nan, math.inf, -math.inf, 0.0, -0.0, 2.0, -2.0, 2.25,
                       rng.uniform(-5.0, 5.0), rng.uniform(-5.0, 5.0)))


def test_the_compiled_function_returns_pythons_values_and_types(compiled):
    rng = random.Random(3)
    for _ in range(20000):
        m = Memory(rng.choice(list(Code)).value, rng.random() < 0.5, rng.randrange(300),
                   _x(rng))
        r = Reading(rng.randrange(-5, 6), tuple(_x(rng) for _ in range(4)), rng.random() < 0.5)
        x = _x(rng)
        want, got = _python(m, r, x), compiled(m, r, x)
        assert (got is None) if want is None else _bits(got) == _bits(want), (m, r, x)
        if want is not None:
            assert type(got[0]) is Memory and type(got[0].armed) is bool


def test_an_index_out_of_range_declines_as_python_raises(compiled):
    m, r = Memory(0, False, 0, 0.0), Reading(9, (1.0, 2.0, 3.0, 4.0), True)
    assert _python(m, r, 0.5) is None and compiled(m, r, 0.5) is None
    # an int field given a fraction: Python raises TypeError indexing; compiled declines
    assert compiled(m, r._replace(rotor=1.5), 0.5) is None


def test_the_lowered_source_runs_as_python_with_the_same_results():
    """The front end's output is Python (its annotations say the kinds and classes):
    run with the intrinsics it names, it is the function, before any C."""
    example = (Memory(0, False, 0, 0.0), Reading(1, (0.0,) * 4, True), 0.0)
    namespace = {name: fn for fn, name in INTRINSICS.items()} | {
        "_inf": math.inf, "_nan": math.nan, "_int": int,
        "_index": lambda k, *items: items[k]}
    exec(compile(native.lower(language, example), "<lowered>", "exec"), namespace)
    rng = random.Random(5)
    for _ in range(2000):
        m = Memory(rng.choice((0, 3, 7)), rng.random() < 0.5, rng.randrange(9), _x(rng))
        r = Reading(rng.randrange(0, 5), tuple(_x(rng) for _ in range(4)), rng.random() < 0.5)
        x = _x(rng)
        want = _python(m, r, x)
        if want is not None:
            got = namespace["language"](m, r, x)
            # the lowered code builds plain tuples; the values are the function's
            assert [_bits(v)[1:] for v in _leaves(got)] == [_bits(v)[1:] for v in _leaves(want)]


def _leaves(v):
    return [y for x in v for y in _leaves(x)] if isinstance(v, tuple) else [v]


def permuted(values: tuple[float, ...], order: tuple[int, ...], flags: tuple[bool, ...]
             ) -> tuple[tuple[float, ...], tuple[bool, ...]]:
    """A plain tuple of ints indexing another (a rotor permutation), and plain bools kept."""
    return tuple(values[k] for k in order), tuple(not b for b in flags)


def test_a_plain_tuples_ints_index_and_its_bools_stay_bools():
    """A plain tuple's items have no annotation: an int in the example indexes as Python
    indexes with it (an out-of-range one declines), a bool is returned a bool; the same
    function with float items is another lowering (indexing with a float raises)."""
    compiled = native.build_function(permuted, ((0.0,) * 4, (0, 1, 2, 3), (True, False)))
    rng = random.Random(7)
    for _ in range(2000):
        values = tuple(_x(rng) for _ in range(4))
        order = tuple(rng.randrange(-4, 4) for _ in range(4))
        flags = (rng.random() < 0.5, rng.random() < 0.5)
        assert _bits(compiled(values, order, flags)) == _bits(permuted(values, order, flags))
    assert compiled((1.0, 2.0, 3.0, 4.0), (0, 1, 2, 4), (True, True)) is None
    assert native.lowered(permuted, ((0.0,) * 4, (0, 1, 2, 3), (True, False))) != \
        native.lowered(permuted, ((0.0,) * 4, (0.0, 1.0, 2.0, 3.0), (True, False)))


class Pair(NamedTuple):
    scale: Callable[[float], float]
    shift: Callable[[float], float]


def _double(x: float) -> float:
    return 2.0 * x


def _halve(x: float) -> float:
    return 0.5 * x


def _plus_one(x: float) -> float:
    return x + 1.0


def on_kernels(x: float, k: Pair) -> tuple[float, float]:
    """Functions passed in a tuple argument (a path's kernels): called through its fields."""
    return k.scale(x), k.shift(k.scale(x))


def test_functions_passed_as_an_argument_are_bound_at_lowering():
    """An argument that is a tuple of functions is inlined where it is called: the compiled
    function computes with the functions of its example (it takes the argument, and does not
    read it), and other functions are another lowering, not the same source."""
    fast = native.build_function(on_kernels, (0.0, Pair(_double, _plus_one)))
    rng = random.Random(9)
    for _ in range(200):
        x = _x(rng)
        assert _bits(fast(x, Pair(_double, _plus_one))) == \
            _bits(on_kernels(x, Pair(_double, _plus_one)))
    first = native.lowered(on_kernels, (0.0, Pair(_double, _plus_one)))
    other = native.lowered(on_kernels, (0.0, Pair(_halve, _plus_one)))
    assert first != other and "0.5" in other and "2.0" in first
